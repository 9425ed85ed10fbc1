//! Image file formats: round trips, half-float overflow, malformed inputs.
//!
//! The malformed-file corpus lives in `tests/corpus/`; regenerate it with
//! `cargo test --test io_formats -- --ignored regenerate_corpus`.

use lumiprobe::error::Error;
use lumiprobe::image::io::{
    self, decode_hdr, decode_sdr, exr, ldr, pfm, rgbe, ExrCompression, ExrWriteOptions, Format,
    Limits, Overflow,
};
use lumiprobe::tonemap::Response;
use lumiprobe::{HdrImage, SdrImage};
use std::path::{Path, PathBuf};

#[path = "common/peak_alloc.rs"]
mod peak_alloc;
use peak_alloc::peak_alloc;

// ---------------------------------------------------------------------------
// Sample images and valid encodings.

/// A small HDR image with a wide dynamic range, smooth areas and noise.
fn hdr_sample(w: usize, h: usize) -> HdrImage {
    HdrImage::from_fn(w, h, |x, y| {
        let n = ((x * 7919 + y * 104_729) % 1000) as f32 / 1000.0;
        let base = if y == 0 {
            1.0
        } else {
            2f32.powi((x % 24) as i32 - 12)
        };
        [base * (0.5 + n), base * 0.75, base * (1.0 - 0.5 * n)]
    })
}

fn sdr_sample(w: usize, h: usize) -> SdrImage {
    let data = (0..w * h * 3).map(|i| (i * 31 % 251) as u8).collect();
    SdrImage::from_vec(w, h, data).unwrap()
}

fn valid_exr() -> Vec<u8> {
    // ZIP, named: the corpus of bad files is made from these bytes and must
    // not change with the writer's default.
    exr::encode(
        &hdr_sample(5, 3),
        Path::new("v.exr"),
        &ExrWriteOptions {
            compression: ExrCompression::Zip,
            ..Default::default()
        },
    )
    .unwrap()
}
fn valid_rgbe() -> Vec<u8> {
    rgbe::encode(&hdr_sample(12, 3))
}
fn valid_pfm(e: pfm::Endian) -> Vec<u8> {
    pfm::encode(&hdr_sample(3, 2), e)
}
fn valid_png() -> Vec<u8> {
    ldr::encode_png(&sdr_sample(5, 4), Path::new("v.png")).unwrap()
}
fn valid_jpeg() -> Vec<u8> {
    ldr::encode_jpeg(&sdr_sample(9, 7), Path::new("v.jpg"), 90).unwrap()
}

fn rel_err(a: f32, b: f32) -> f32 {
    (a - b).abs() / b.abs().max(1e-30)
}

// ---------------------------------------------------------------------------
// Round trips through real files.

#[test]
fn exr_float_round_trip_is_exact() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("probe.exr");
    let mut img = hdr_sample(33, 17);
    img.set(0, 0, [-1.5, 1e30, 1e-30]); // negative and extreme values survive in float
    io::write_hdr(&p, &img).unwrap();
    assert_eq!(io::read_hdr(&p).unwrap(), img);
}

#[test]
fn exr_half_round_trip_within_1e3_relative() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("half.exr");
    let img = hdr_sample(40, 9);
    let opts = ExrWriteOptions {
        half: true,
        ..Default::default()
    };
    exr::write(&p, &img, &opts).unwrap();
    let back = io::read_hdr(&p).unwrap();
    for (a, b) in back.data().iter().zip(img.data()) {
        assert!(rel_err(*a, *b) < 1e-3, "{a} vs {b}");
    }
    // Half files are smaller than float files.
    let pf = dir.path().join("float.exr");
    io::write_hdr(&pf, &img).unwrap();
    assert!(std::fs::metadata(&p).unwrap().len() < std::fs::metadata(&pf).unwrap().len());
}

#[test]
fn exr_half_overflow_is_an_error_or_an_explicit_clamp() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("sun.exr");
    let mut img = hdr_sample(8, 8);
    img.set(3, 3, [1e6, 7e4, 65504.0]);
    let opts = ExrWriteOptions {
        half: true,
        on_overflow: Overflow::Error,
        ..Default::default()
    };
    let msg = exr::write(&p, &img, &opts).unwrap_err().to_string();
    assert!(msg.contains("sun.exr"), "{msg}");
    assert!(msg.contains("2 samples"), "{msg}");
    assert!(msg.contains("1000000"), "{msg}");
    assert!(!p.exists(), "nothing may be written on error");

    let opts = ExrWriteOptions {
        half: true,
        on_overflow: Overflow::Clamp,
        ..Default::default()
    };
    exr::write(&p, &img, &opts).unwrap();
    assert_eq!(io::read_hdr(&p).unwrap().get(3, 3), [65504.0; 3]);
    // Float output keeps the sun.
    io::write_hdr(&p, &img).unwrap();
    assert_eq!(io::read_hdr(&p).unwrap().get(3, 3), [1e6, 7e4, 65504.0]);
}

#[test]
fn non_finite_samples_are_never_written() {
    let dir = tempfile::tempdir().unwrap();
    let mut img = hdr_sample(4, 4);
    img.set(1, 1, [f32::NAN, 1.0, f32::NEG_INFINITY]);
    for name in ["a.exr", "a.hdr", "a.pfm"] {
        let p = dir.path().join(name);
        let msg = io::write_hdr(&p, &img).unwrap_err().to_string();
        assert!(
            msg.contains(name) && msg.contains("2 NaN or infinite"),
            "{msg}"
        );
        assert!(!p.exists());
    }
}

#[test]
fn exr_reads_other_sample_types_channels_and_compressions() {
    use ::exr::prelude::*;
    let (w, h) = (19usize, 21usize);
    let val = |x: usize, y: usize| (x as f32 + 0.5) * (y as f32 + 1.0) * 0.25;
    let comps = [
        Compression::Uncompressed,
        Compression::RLE,
        Compression::ZIP1,
        Compression::ZIP16,
        Compression::PIZ,
        Compression::PXR24,
        Compression::B44,
    ];
    for compression in comps {
        let enc = Encoding {
            compression,
            ..Encoding::FAST_LOSSLESS
        };
        let name = format!("{compression:?}");
        // RGBA half with alpha: alpha is dropped.
        let ch = SpecificChannels::rgba(|p: Vec2<usize>| {
            let v = f16::from_f32(val(p.x(), p.y()));
            (v, v, v, f16::from_f32(0.5))
        });
        let mut buf = std::io::Cursor::new(Vec::new());
        Image::from_layer(Layer::new((w, h), LayerAttributes::default(), enc, ch))
            .write()
            .to_buffered(&mut buf)
            .unwrap();
        let img = decode_hdr(buf.get_ref(), Path::new("rgba.exr"), &Limits::default())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!((img.width(), img.height()), (w, h));
        let tol = if matches!(compression, Compression::B44) {
            0.05
        } else {
            1e-3
        };
        assert!(rel_err(img.get(7, 9)[1], val(7, 9)) < tol, "{name}");

        // Luminance-only float: replicated to RGB.
        let y = AnyChannel::new(
            "Y",
            FlatSamples::F32((0..w * h).map(|i| val(i % w, i / w)).collect()),
        );
        let layer = Layer::new(
            (w, h),
            LayerAttributes::default(),
            enc,
            AnyChannels::sort(SmallVec::from_vec(vec![y])),
        );
        let mut buf = std::io::Cursor::new(Vec::new());
        Image::from_layer(layer)
            .write()
            .to_buffered(&mut buf)
            .unwrap();
        let img = decode_hdr(buf.get_ref(), Path::new("y.exr"), &Limits::default())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let p = img.get(4, 5);
        assert!(
            p[0] == p[1] && p[1] == p[2] && rel_err(p[0], val(4, 5)) < 1e-3,
            "{name}"
        );
    }
    // u32 channels.
    let ch = SpecificChannels::rgb(|p: Vec2<usize>| (p.x() as u32, p.y() as u32, 7u32));
    let mut buf = std::io::Cursor::new(Vec::new());
    Image::from_layer(Layer::new(
        (w, h),
        LayerAttributes::default(),
        Encoding::default(),
        ch,
    ))
    .write()
    .to_buffered(&mut buf)
    .unwrap();
    let img = decode_hdr(buf.get_ref(), Path::new("u32.exr"), &Limits::default()).unwrap();
    assert_eq!(img.get(3, 4), [3.0, 4.0, 7.0]);
}

#[test]
fn rgbe_round_trip_within_1_percent() {
    let dir = tempfile::tempdir().unwrap();
    // Widths exercising flat (< 8) and RLE scanlines.
    for w in [1usize, 7, 8, 64, 300] {
        let p = dir.path().join(format!("probe{w}.hdr"));
        let img = hdr_sample(w, 5);
        io::write_hdr(&p, &img).unwrap();
        let back = io::read_hdr(&p).unwrap();
        assert_eq!((back.width(), back.height()), (w, 5));
        for (a, b) in back.pixels().zip(img.pixels()) {
            let m = b[0].max(b[1]).max(b[2]);
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() <= 0.01 * m, "{a:?} vs {b:?}");
            }
        }
    }
    // Uniform rows compress.
    let flat = HdrImage::from_fn(256, 4, |_, _| [1.0, 2.0, 3.0]);
    assert!(rgbe::encode(&flat).len() < 256 * 4 * 4 / 10);
}

#[test]
fn pfm_round_trip_exact_both_endiannesses() {
    let dir = tempfile::tempdir().unwrap();
    let mut img = hdr_sample(7, 4);
    img.set(2, 2, [-3.0, 1e38, 1e-38]);
    let p = dir.path().join("le.pfm");
    io::write_hdr(&p, &img).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    assert!(
        bytes.starts_with(b"PF\n7 4\n-1"),
        "little endian by default"
    );
    assert_eq!(io::read_hdr(&p).unwrap(), img);
    let p = dir.path().join("be.pfm");
    std::fs::write(&p, pfm::encode(&img, pfm::Endian::Big)).unwrap();
    assert_eq!(io::read_hdr(&p).unwrap(), img);
}

#[test]
fn png_round_trip_exact_and_jpeg_close() {
    let dir = tempfile::tempdir().unwrap();
    let img = sdr_sample(23, 11);
    let p = dir.path().join("frame.png");
    io::write_sdr(&p, &img).unwrap();
    assert_eq!(io::read_sdr(&p).unwrap(), img);

    let smooth = SdrImage::from_vec(
        32,
        16,
        (0..32 * 16 * 3).map(|i| ((i / 3) % 32 * 4) as u8).collect(),
    )
    .unwrap();
    let p = dir.path().join("frame.JPEG");
    io::write_sdr(&p, &smooth).unwrap();
    let back = io::read_sdr(&p).unwrap();
    let mean_err: f64 = back
        .data()
        .iter()
        .zip(smooth.data())
        .map(|(a, b)| (*a as f64 - *b as f64).abs())
        .sum::<f64>()
        / smooth.data().len() as f64;
    assert!(mean_err < 4.0, "{mean_err}");
}

#[test]
fn gray_and_rgba_pngs_become_rgb() {
    use image::ImageEncoder;
    let mut gray = Vec::new();
    image::codecs::png::PngEncoder::new(&mut gray)
        .write_image(&[10, 200], 2, 1, image::ExtendedColorType::L8)
        .unwrap();
    let img = decode_sdr(&gray, Path::new("g.png"), &Limits::default()).unwrap();
    assert_eq!(img.data(), &[10, 10, 10, 200, 200, 200]);
    let mut rgba = Vec::new();
    image::codecs::png::PngEncoder::new(&mut rgba)
        .write_image(
            &[1, 2, 3, 4, 5, 6, 7, 8],
            2,
            1,
            image::ExtendedColorType::Rgba8,
        )
        .unwrap();
    let img = decode_sdr(&rgba, Path::new("a.png"), &Limits::default()).unwrap();
    assert_eq!(img.data(), &[1, 2, 3, 5, 6, 7]);
}

#[test]
fn format_is_chosen_by_magic_not_extension() {
    let l = Limits::default();
    // An EXR named .hdr and a Radiance file named .exr still read correctly.
    let img = decode_hdr(&valid_exr(), Path::new("really_exr.hdr"), &l).unwrap();
    assert_eq!(img, hdr_sample(5, 3));
    let img = decode_hdr(&valid_rgbe(), Path::new("really_rgbe.exr"), &l).unwrap();
    assert_eq!(img.width(), 12);
    let img = decode_sdr(&valid_png(), Path::new("really_png.jpg"), &l).unwrap();
    assert_eq!(img, sdr_sample(5, 4));
    // Asking for the wrong kind of image is a clear error.
    let msg = decode_hdr(&valid_png(), Path::new("frame.png"), &l)
        .unwrap_err()
        .to_string();
    assert!(msg.contains("frame.png") && msg.contains("8-bit"), "{msg}");
    let msg = decode_sdr(&valid_exr(), Path::new("probe.exr"), &l)
        .unwrap_err()
        .to_string();
    assert!(msg.contains("probe.exr") && msg.contains("HDR"), "{msg}");
    let msg = decode_hdr(b"hello", Path::new("notes.txt"), &l)
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("notes.txt") && msg.contains("unrecognised"),
        "{msg}"
    );
}

#[test]
fn write_dispatch_by_extension() {
    let dir = tempfile::tempdir().unwrap();
    let img = hdr_sample(9, 2);
    for (name, fmt) in [
        ("a.exr", Format::Exr),
        ("a.hdr", Format::Rgbe),
        ("a.pic", Format::Rgbe),
        ("a.pfm", Format::Pfm),
    ] {
        let p = dir.path().join(name);
        io::write_hdr(&p, &img).unwrap();
        assert_eq!(
            Format::sniff(&std::fs::read(&p).unwrap()),
            Some(fmt),
            "{name}"
        );
    }
    for name in ["a.png", "a.tif", "noext"] {
        let msg = io::write_hdr(&dir.path().join(name), &img)
            .unwrap_err()
            .to_string();
        assert!(msg.contains(name), "{msg}");
    }
    let s = sdr_sample(4, 4);
    for (name, fmt) in [
        ("b.png", Format::Png),
        ("b.jpg", Format::Jpeg),
        ("b.jpeg", Format::Jpeg),
    ] {
        let p = dir.path().join(name);
        io::write_sdr(&p, &s).unwrap();
        assert_eq!(
            Format::sniff(&std::fs::read(&p).unwrap()),
            Some(fmt),
            "{name}"
        );
    }
    for name in ["b.exr", "b.gif"] {
        let msg = io::write_sdr(&dir.path().join(name), &s)
            .unwrap_err()
            .to_string();
        assert!(msg.contains(name), "{msg}");
    }
    // Empty images cannot be written.
    assert!(io::write_hdr(&dir.path().join("e.exr"), &HdrImage::new(0, 0)).is_err());
    // No temporary files are left behind.
    let leftovers: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty());
}

#[test]
fn sdr_linear_bridge() {
    let r = Response::Gamma { gamma: 2.2 };
    let s = sdr_sample(6, 5);
    let lin = io::sdr_to_linear(&s, &r, 4.0);
    let c = s.data()[5] as f32 / 255.0;
    assert!((lin.data()[5] - c.powf(2.2) / 4.0).abs() < 1e-6);
    assert_eq!(io::linear_to_sdr(&lin, &r, 4.0), s);
    // Radiance above the white point clips to 255.
    let bright = HdrImage::from_fn(1, 1, |_, _| [10.0, 0.0, 0.1]);
    let sdr = io::linear_to_sdr(&bright, &Response::Srgb, 1.0);
    assert_eq!(sdr.data()[..2], [255, 0]);
}

// ---------------------------------------------------------------------------
// Malformed input: no reader may panic, every error names the file.

type Reader = (&'static str, fn(&[u8], &Path) -> Result<(), Error>);

fn readers() -> Vec<Reader> {
    vec![
        ("decode_hdr", |b, n| {
            decode_hdr(b, n, &Limits::default()).map(drop)
        }),
        ("decode_sdr", |b, n| {
            decode_sdr(b, n, &Limits::default()).map(drop)
        }),
        ("exr", |b, n| {
            exr::decode(b, n, &Limits::default()).map(drop)
        }),
        ("rgbe", |b, n| {
            rgbe::decode(b, n, &Limits::default()).map(drop)
        }),
        ("pfm", |b, n| {
            pfm::decode(b, n, &Limits::default()).map(drop)
        }),
        ("png", |b, n| {
            ldr::decode(b, n, Format::Png, &Limits::default()).map(drop)
        }),
        ("jpeg", |b, n| {
            ldr::decode(b, n, Format::Jpeg, &Limits::default()).map(drop)
        }),
    ]
}

/// Every reader must return an error mentioning `name`, without panicking.
fn assert_all_reject(bytes: &[u8], name: &Path, what: &str) {
    let file = name.file_name().unwrap().to_string_lossy().into_owned();
    for (reader, f) in readers() {
        let r = std::panic::catch_unwind(|| f(bytes, name));
        match r {
            Err(_) => panic!("{reader} panicked on {what}"),
            Ok(Ok(())) => panic!("{reader} accepted {what}"),
            Ok(Err(e)) => {
                let msg = e.to_string();
                assert!(
                    msg.contains(&file),
                    "{reader} on {what}: message lacks file name: {msg}"
                );
            }
        }
    }
}

#[test]
fn every_truncation_of_every_format_is_rejected() {
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("cut.exr", valid_exr()),
        ("cut.hdr", valid_rgbe()),
        ("cut.pfm", valid_pfm(pfm::Endian::Little)),
        ("cut_be.pfm", valid_pfm(pfm::Endian::Big)),
        ("cut.png", valid_png()),
        ("cut.jpg", valid_jpeg()),
    ];
    for (name, bytes) in cases {
        // The full file is accepted by the matching reader.
        let n = Path::new(name);
        let fmt = Format::from_extension(n).unwrap();
        if fmt.is_hdr() {
            decode_hdr(&bytes, n, &Limits::default()).unwrap();
        } else {
            decode_sdr(&bytes, n, &Limits::default()).unwrap();
        }
        for k in 0..bytes.len() {
            assert_all_reject(
                &bytes[..k],
                n,
                &format!("{name} cut to {k} of {} bytes", bytes.len()),
            );
        }
    }
}

fn corpus_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus")
}

#[test]
fn every_corpus_file_is_rejected_by_every_reader() {
    let mut n = 0;
    for entry in std::fs::read_dir(corpus_dir()).expect("tests/corpus exists") {
        let path = entry.unwrap().path();
        if !path.is_file() || path.extension().is_some_and(|e| e == "md") {
            continue;
        }
        let bytes = std::fs::read(&path).unwrap();
        assert_all_reject(&bytes, &path, &path.display().to_string());
        // Through the file API as well.
        let file = path.file_name().unwrap().to_string_lossy().into_owned();
        for r in [io::read_hdr(&path).map(drop), io::read_sdr(&path).map(drop)] {
            let msg = r.unwrap_err().to_string();
            assert!(msg.contains(&file), "{msg}");
        }
        // Files named huge_* declare more pixels than allowed.
        if file.starts_with("huge_") {
            let hdr = Format::from_extension(&path).unwrap().is_hdr();
            let e = if hdr {
                io::read_hdr(&path).map(drop)
            } else {
                io::read_sdr(&path).map(drop)
            };
            assert!(matches!(e, Err(Error::Limit { .. })), "{file}: {e:?}");
        }
        n += 1;
    }
    assert!(n >= 30, "corpus has only {n} files; regenerate it");
}

#[test]
fn corpus_is_up_to_date() {
    for (name, bytes) in corpus() {
        let on_disk = std::fs::read(corpus_dir().join(name)).unwrap_or_default();
        assert!(
            on_disk == bytes,
            "tests/corpus/{name} is stale; run the ignored regenerate_corpus test"
        );
    }
}

#[test]
fn huge_declared_sizes_are_rejected_before_allocating() {
    let small = Limits { max_pixels: 1000 };
    let big = HdrImage::from_fn(2000, 1000, |_, _| [1.0, 1.0, 1.0]);
    let cases: Vec<(&str, Vec<u8>)> = vec![
        (
            "big.exr",
            exr::encode(&big, Path::new("big.exr"), &ExrWriteOptions::default()).unwrap(),
        ),
        ("big.hdr", rgbe::encode(&big)),
        ("big.pfm", b"PF\n2000 1000\n-1\n".to_vec()),
        (
            "big.png",
            ldr::encode_png(&SdrImage::new(2000, 1000), Path::new("big.png")).unwrap(),
        ),
        (
            "big.jpg",
            ldr::encode_jpeg(&SdrImage::new(2000, 1000), Path::new("big.jpg"), 50).unwrap(),
        ),
    ];
    for (name, bytes) in &cases {
        let n = Path::new(name);
        let hdr = Format::from_extension(n).unwrap().is_hdr();
        let (r, peak) = peak_alloc(|| {
            if hdr {
                decode_hdr(bytes, n, &small).map(drop)
            } else {
                decode_sdr(bytes, n, &small).map(drop)
            }
        });
        match r {
            Err(ref e @ Error::Limit { ref path, .. }) => {
                assert_eq!(path.as_deref(), Some(n));
                assert!(e.to_string().contains("2000x1000"), "{e}");
            }
            other => panic!("{name}: {other:?}"),
        }
        // The image itself would need 24 MB; nothing close may be allocated.
        assert!(
            peak < 1 << 20,
            "{name}: allocated {peak} bytes before rejecting"
        );
    }
    // With default limits, 100000 x 100000 corpus files fail the same way.
    for (name, bytes) in corpus().into_iter().filter(|(n, _)| n.starts_with("huge_")) {
        let n = Path::new(name);
        let (r, peak) = peak_alloc(|| {
            decode_hdr(&bytes, n, &Limits::default())
                .map(drop)
                .or_else(|e| {
                    if matches!(e, Error::Limit { .. }) {
                        Err(e)
                    } else {
                        decode_sdr(&bytes, n, &Limits::default()).map(drop)
                    }
                })
        });
        assert!(matches!(r, Err(Error::Limit { .. })), "{name}: {r:?}");
        assert!(
            peak < 1 << 20,
            "{name}: allocated {peak} bytes before rejecting"
        );
    }
}

// ---------------------------------------------------------------------------
// The corpus: small hand-made malformed files, one problem each.

/// Replaces `len` bytes at the first occurrence of `needle` + `skip`.
fn patch(mut b: Vec<u8>, needle: &[u8], skip: usize, with: &[u8]) -> Vec<u8> {
    let at = b
        .windows(needle.len())
        .position(|w| w == needle)
        .expect("needle")
        + needle.len()
        + skip;
    b[at..at + with.len()].copy_from_slice(with);
    b
}

fn crc32(data: &[u8]) -> u32 {
    let mut c = !0u32;
    for &byte in data {
        c ^= byte as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

fn png_chunk(kind: &[u8; 4], data: &[u8]) -> Vec<u8> {
    let mut v = (data.len() as u32).to_be_bytes().to_vec();
    v.extend_from_slice(kind);
    v.extend_from_slice(data);
    let mut crc_in = kind.to_vec();
    crc_in.extend_from_slice(data);
    v.extend_from_slice(&crc32(&crc_in).to_be_bytes());
    v
}

fn png_with_ihdr(w: u32, h: u32) -> Vec<u8> {
    let mut ihdr = w.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
    let mut v = b"\x89PNG\r\n\x1a\n".to_vec();
    v.extend(png_chunk(b"IHDR", &ihdr));
    v.extend(png_chunk(
        b"IDAT",
        &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
    ));
    v.extend(png_chunk(b"IEND", &[]));
    v
}

fn rgbe_file(header: &str, pixels: &[u8]) -> Vec<u8> {
    let mut v = header.as_bytes().to_vec();
    v.extend_from_slice(pixels);
    v
}

fn exr_box(xmin: i32, ymin: i32, xmax: i32, ymax: i32) -> Vec<u8> {
    [xmin, ymin, xmax, ymax]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect()
}

/// The corpus, as (file name, bytes).
fn corpus() -> Vec<(&'static str, Vec<u8>)> {
    let hdr16 = "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 16\n";
    let exr = valid_exr();
    let only_z = {
        use ::exr::prelude::*;
        let z = AnyChannel::new("Z", FlatSamples::F32(vec![1.0; 6]));
        let layer = Layer::new(
            (3, 2),
            LayerAttributes::default(),
            Encoding::default(),
            AnyChannels::sort(SmallVec::from_vec(vec![z])),
        );
        let mut buf = std::io::Cursor::new(Vec::new());
        Image::from_layer(layer)
            .write()
            .to_buffered(&mut buf)
            .unwrap();
        buf.into_inner()
    };
    let jpeg = valid_jpeg();
    let sof_dims = |b: Vec<u8>, h: u16, w: u16| {
        let mut d = h.to_be_bytes().to_vec();
        d.extend_from_slice(&w.to_be_bytes());
        patch(b, &[0xff, 0xc0], 3, &d)
    };
    // The single chunk's entry in the offset table points just past itself.
    let table = (0..exr.len() - 8)
        .find(|&i| u64::from_le_bytes(exr[i..i + 8].try_into().unwrap()) == i as u64 + 8)
        .expect("offset table");
    let mut bad_offset = exr.clone();
    bad_offset[table..table + 8].copy_from_slice(&(1u64 << 40).to_le_bytes());
    let mut bad_chunk_size = exr.clone();
    bad_chunk_size[table + 12..table + 16].copy_from_slice(&i32::MAX.to_le_bytes());
    vec![
        // Radiance RGBE
        (
            "rgbe_bad_magic.hdr",
            rgbe_file(
                "RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 1\n",
                &[1, 1, 1, 129],
            ),
        ),
        ("rgbe_empty.hdr", Vec::new()),
        (
            "rgbe_zero_size.hdr",
            rgbe_file("#?RADIANCE\n\n-Y 0 +X 0\n", &[]),
        ),
        (
            "huge_rgbe_100000x100000.hdr",
            rgbe_file("#?RADIANCE\n\n-Y 100000 +X 100000\n", &[2, 2, 0x86, 0xa0]),
        ),
        (
            "huge_rgbe_u64_overflow.hdr",
            rgbe_file(
                "#?RADIANCE\n\n-Y 18446744073709551615 +X 18446744073709551615\n",
                &[],
            ),
        ),
        (
            "rgbe_negative_size.hdr",
            rgbe_file("#?RADIANCE\n\n-Y -2 +X 16\n", &[0; 64]),
        ),
        (
            "rgbe_xyze.hdr",
            rgbe_file(
                "#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n",
                &[128, 128, 128, 129],
            ),
        ),
        (
            "rgbe_unknown_format.hdr",
            rgbe_file(
                "#?RADIANCE\nFORMAT=16-bit_rgb\n\n-Y 1 +X 1\n",
                &[128, 128, 128, 129],
            ),
        ),
        (
            "rgbe_header_unterminated.hdr",
            rgbe_file(
                "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n-Y 1 +X 1\n",
                &[128, 128, 128, 129],
            ),
        ),
        (
            "rgbe_bad_resolution.hdr",
            rgbe_file("#?RADIANCE\n\n-Y 1 -Y 1\n", &[128, 128, 128, 129]),
        ),
        (
            "rgbe_resolution_garbage.hdr",
            rgbe_file("#?RADIANCE\n\nwidth=1 height=1\n", &[128, 128, 128, 129]),
        ),
        (
            "rgbe_rle_run_overflow.hdr",
            rgbe_file(hdr16, &[2, 2, 0, 16, 128 + 100, 7]),
        ),
        (
            "rgbe_rle_literal128_overflow.hdr",
            rgbe_file(hdr16, &[&[2u8, 2, 0, 16, 128][..], &[7; 128]].concat()),
        ),
        (
            "rgbe_rle_zero_length.hdr",
            rgbe_file(hdr16, &[2, 2, 0, 16, 0, 128 + 16, 7]),
        ),
        (
            "rgbe_rle_literal_overflow.hdr",
            rgbe_file(hdr16, &[&[2u8, 2, 0, 16, 100][..], &[9; 100]].concat()),
        ),
        (
            "rgbe_rle_width_mismatch.hdr",
            rgbe_file(
                hdr16,
                &[&[2u8, 2, 0, 15][..], &[128 + 15, 1].repeat(8)].concat(),
            ),
        ),
        (
            "rgbe_rle_truncated_run.hdr",
            rgbe_file(hdr16, &[2, 2, 0, 16, 128 + 16]),
        ),
        (
            "rgbe_old_rle_no_previous.hdr",
            rgbe_file("#?RADIANCE\n\n-Y 1 +X 4\n", &[1, 1, 1, 4]),
        ),
        (
            "rgbe_old_rle_overflow.hdr",
            rgbe_file("#?RADIANCE\n\n-Y 1 +X 4\n", &[128, 0, 0, 129, 1, 1, 1, 200]),
        ),
        (
            "rgbe_old_rle_zero_run.hdr",
            rgbe_file("#?RADIANCE\n\n-Y 1 +X 4\n", &[128, 0, 0, 129, 1, 1, 1, 0]),
        ),
        (
            "rgbe_truncated_pixels.hdr",
            rgbe_file("#?RADIANCE\n\n-Y 2 +X 3\n", &[128; 17]),
        ),
        // PFM
        (
            "pfm_bad_magic.pfm",
            b"PX\n1 1\n-1\n\0\0\0\0\0\0\0\0\0\0\0\0".to_vec(),
        ),
        ("pfm_empty.pfm", Vec::new()),
        ("pfm_header_only.pfm", b"PF\n".to_vec()),
        (
            "pfm_scale_zero.pfm",
            b"PF\n1 1\n0\n\0\0\0\0\0\0\0\0\0\0\0\0".to_vec(),
        ),
        (
            "pfm_scale_nan.pfm",
            b"PF\n1 1\nnan\n\0\0\0\0\0\0\0\0\0\0\0\0".to_vec(),
        ),
        (
            "pfm_scale_text.pfm",
            b"PF\n1 1\nlittle\n\0\0\0\0\0\0\0\0\0\0\0\0".to_vec(),
        ),
        ("pfm_zero_size.pfm", b"PF\n0 0\n-1\n".to_vec()),
        (
            "huge_pfm_100000x100000.pfm",
            b"PF\n100000 100000\n-1\n\0\0\0\0".to_vec(),
        ),
        ("pfm_negative_width.pfm", b"Pf\n-1 1\n-1\n\0\0\0\0".to_vec()),
        (
            "pfm_truncated_data.pfm",
            b"PF\n2 2\n-1\n\0\0\0\0\0\0\0\0".to_vec(),
        ),
        (
            "pfm_gray_truncated.pfm",
            b"Pf\n2 2\n1.0\n\0\0\0\0\0\0\0\0\0\0\0\0".to_vec(),
        ),
        // OpenEXR
        ("exr_bad_magic.exr", {
            let mut b = exr.clone();
            b[0] = 0x77;
            b
        }),
        ("exr_bad_version.exr", {
            let mut b = exr.clone();
            b[4] = 99;
            b
        }),
        ("exr_truncated_header.exr", exr[..40].to_vec()),
        ("exr_only_z_channel.exr", only_z),
        (
            "huge_exr_100000x100000.exr",
            patch(
                exr.clone(),
                b"dataWindow\0box2i\0",
                4,
                &exr_box(0, 0, 99_999, 99_999),
            ),
        ),
        (
            "exr_window_mismatch.exr",
            patch(
                exr.clone(),
                b"dataWindow\0box2i\0",
                4,
                &exr_box(0, 0, 4, 200),
            ),
        ),
        ("exr_bad_offset.exr", bad_offset),
        ("exr_bad_chunk_size.exr", bad_chunk_size),
        // PNG
        ("png_bad_magic.png", {
            let mut b = valid_png();
            b[1] = b'Q';
            b
        }),
        ("png_zero_size.png", png_with_ihdr(0, 0)),
        (
            "huge_png_100000x100000.png",
            png_with_ihdr(100_000, 100_000),
        ),
        ("png_truncated.png", {
            let b = valid_png();
            b[..b.len() / 2].to_vec()
        }),
        ("png_bad_crc.png", {
            let mut b = valid_png();
            let n = b.len();
            b[n - 20] ^= 0xff;
            b
        }),
        (
            "png_no_ihdr.png",
            [&b"\x89PNG\r\n\x1a\n"[..], &png_chunk(b"IEND", &[])].concat(),
        ),
        // JPEG
        ("jpeg_bad_magic.jpg", {
            let mut b = jpeg.clone();
            b[1] = 0x00;
            b
        }),
        ("jpeg_truncated.jpg", jpeg[..jpeg.len() * 2 / 3].to_vec()),
        ("jpeg_zero_size.jpg", sof_dims(jpeg.clone(), 0, 0)),
        (
            "huge_jpeg_65535x65535.jpg",
            sof_dims(jpeg.clone(), 65535, 65535),
        ),
        ("jpeg_only_soi.jpg", vec![0xff, 0xd8, 0xff, 0xd9]),
    ]
}

#[test]
#[ignore = "writes tests/corpus; run explicitly after changing the corpus"]
fn regenerate_corpus() {
    let dir = corpus_dir();
    std::fs::create_dir_all(&dir).unwrap();
    for (name, bytes) in corpus() {
        std::fs::write(dir.join(name), bytes).unwrap();
    }
}

#[test]
fn corpus_errors_name_the_problem() {
    let expect = [
        ("rgbe_bad_magic.hdr", "not a Radiance"),
        ("rgbe_zero_size.hdr", "empty 0x0"),
        ("rgbe_xyze.hdr", "xyze"),
        ("rgbe_bad_resolution.hdr", "resolution line"),
        (
            "rgbe_rle_run_overflow.hdr",
            "run of 100 at pixel 0 overflows width 16",
        ),
        ("rgbe_rle_zero_length.hdr", "zero-length run"),
        ("rgbe_rle_width_mismatch.hdr", "declares width 15"),
        ("rgbe_old_rle_no_previous.hdr", "no previous pixel"),
        ("rgbe_truncated_pixels.hdr", "truncated"),
        ("pfm_bad_magic.pfm", "not a PFM"),
        ("pfm_scale_zero.pfm", "scale"),
        ("pfm_scale_text.pfm", "scale"),
        ("pfm_truncated_data.pfm", "need 48 bytes"),
        ("pfm_zero_size.pfm", "empty 0x0"),
        ("exr_bad_magic.exr", "OpenEXR"),
        ("exr_only_z_channel.exr", "found channels [Z]"),
        ("exr_bad_offset.exr", "truncated or corrupt"),
        ("png_truncated.png", "truncated PNG"),
        ("png_bad_crc.png", "CRC"),
        ("jpeg_truncated.jpg", "truncated JPEG"),
        ("jpeg_bad_magic.jpg", "not a JPEG"),
    ];
    let corpus = corpus();
    for (name, want) in expect {
        let bytes = &corpus.iter().find(|(n, _)| *n == name).expect(name).1;
        let n = Path::new(name);
        let e = if Format::from_extension(n).unwrap().is_hdr() {
            decode_hdr(bytes, n, &Limits::default()).map(drop)
        } else {
            decode_sdr(bytes, n, &Limits::default()).map(drop)
        };
        let msg = e.unwrap_err().to_string();
        assert!(msg.starts_with(name) && msg.contains(want), "{name}: {msg}");
    }
}

#[test]
fn ycc_exr_is_rejected_clearly() {
    use ::exr::prelude::*;
    let ch = |n: &str| AnyChannel::new(n, FlatSamples::F32(vec![0.5; 4]));
    let layer = Layer::new(
        (2, 2),
        LayerAttributes::default(),
        Encoding::default(),
        AnyChannels::sort(SmallVec::from_vec(vec![ch("Y"), ch("RY"), ch("BY")])),
    );
    let mut buf = std::io::Cursor::new(Vec::new());
    Image::from_layer(layer)
        .write()
        .to_buffered(&mut buf)
        .unwrap();
    let msg = decode_hdr(buf.get_ref(), Path::new("ycc.exr"), &Limits::default())
        .unwrap_err()
        .to_string();
    assert!(msg.contains("ycc.exr") && msg.contains("RY"), "{msg}");
}

/// Tiny deterministic PRNG for the mutation test.
struct XorShift(u64);
impl XorShift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

#[test]
fn random_mutations_never_panic() {
    let seeds: Vec<(&str, Vec<u8>)> = vec![
        ("m.exr", valid_exr()),
        ("m.hdr", valid_rgbe()),
        ("m.pfm", valid_pfm(pfm::Endian::Big)),
        ("m.png", valid_png()),
        ("m.jpg", valid_jpeg()),
        ("m_old.hdr", {
            let mut b = b"#?RADIANCE\n\n-Y 3 +X 6\n".to_vec();
            for _ in 0..3 {
                b.extend_from_slice(&[200, 100, 50, 130, 1, 1, 1, 2, 9, 9, 9, 128, 1, 1, 1, 2]);
            }
            b
        }),
    ];
    let mut rng = XorShift(0x9e37_79b9_7f4a_7c15);
    let small = Limits {
        max_pixels: 1 << 16,
    };
    // LUMIPROBE_MUTATIONS=100000 for a longer local fuzzing run.
    let iterations: usize = std::env::var("LUMIPROBE_MUTATIONS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1500);
    let (mut guarded, mut accepted) = (0, 0);
    for (name, seed) in &seeds {
        let n = Path::new(name);
        let valid = if Format::from_extension(n).unwrap().is_hdr() {
            decode_hdr(seed, n, &small).map(drop)
        } else {
            decode_sdr(seed, n, &small).map(drop)
        };
        assert!(valid.is_ok(), "seed {name}: {valid:?}");
        for _ in 0..iterations {
            let mut b = seed.clone();
            for _ in 0..1 + rng.below(4) {
                let i = rng.below(b.len());
                match rng.below(4) {
                    0 => b[i] ^= 1 << rng.below(8),
                    1 => b[i] = [0, 1, 2, 0x7f, 0x80, 0xff][rng.below(6)],
                    2 => b.truncate(i),
                    _ => b.insert(i, rng.next() as u8),
                }
                if b.is_empty() {
                    break;
                }
            }
            for r in [
                decode_hdr(&b, n, &small).map(drop),
                decode_sdr(&b, n, &small).map(drop),
            ] {
                accepted += r.is_ok() as usize;
                if let Err(e) = r {
                    let msg = e.to_string();
                    assert!(msg.contains(name), "{msg}");
                    guarded += msg.contains("decoder failed on malformed data") as usize;
                }
            }
        }
    }
    // Panics inside third-party decoders are caught; report how often it happened.
    println!("mutants accepted: {accepted}; third-party decoder panics caught: {guarded}");
}
