//! OpenEXR via the `exr` crate.
//!
//! Reading takes the first layer with `R`, `G`, `B` channels (any of half, float
//! or u32; alpha and other channels are dropped), or else the first with a `Y`
//! (luminance) channel, replicated to RGB. The header is parsed and the data
//! window checked against [`Limits`] before any pixel is decoded, and so is the
//! size of every layer's blocks (tiles or scan-line groups), which the decoder
//! allocates as declared. Decoding is single-threaded so that a fault in the
//! decoder stays catchable.
//!
//! Writing stores float32 RGB with lossless ZIP compression unless
//! [`ExrWriteOptions`] ask for half floats.

use super::{check_dims, check_finite, check_nonempty, guard_panic, Limits};
use crate::error::{Error, Result};
use crate::image::HdrImage;
use ::exr::prelude::traits::*;
use ::exr::prelude::{f16, Vec2};
use std::io::Cursor;
use std::path::Path;

/// Largest finite half-float value.
pub const HALF_MAX: f32 = 65504.0;

/// What to do with samples beyond [`HALF_MAX`] when writing half floats.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Overflow {
    /// Fail, naming the file, the largest value and how many samples overflow.
    #[default]
    Error,
    /// Clamp to ±65504 (an explicit, lossy choice).
    Clamp,
}

/// Lossless compression of a written EXR file. Measured on a fusion output of
/// kitchen at 7776x3888 (363 MB raw, 2 threads): ZIP 94 MB in 2.8 s, PIZ 117 MB
/// in 0.8 s (but 3.7 s to read with the `exr` crate against ZIP's 1.2 s), none in
/// a fraction of a second. A noisy path-traced panorama compresses far less (ZIP
/// 92% of raw, PIZ 71%).
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
pub enum ExrCompression {
    /// PIZ for panoramas under 4096 pixels wide, ZIP from there: at 512x256
    /// PIZ writes a kitchen fusion run's 20 frames in 1.35 s against 1.63-1.78
    /// s and 20 MB against 25 MB; at 7776x3888 ZIP files are the smaller (PIZ
    /// 1.2 times) (docs/speed.md). Uncompressed when a trial band across the
    /// middle of the image does not shrink below 85% (float data resampled
    /// from float data; half floats are always compressed).
    #[default]
    Auto,
    /// Deflate over 16 scanlines (OpenEXR's ZIP): smallest for smooth images.
    Zip,
    /// Wavelet + Huffman (OpenEXR's PIZ): smaller and faster to write than ZIP for
    /// large noisy panoramas, slower to read with the `exr` crate.
    Piz,
    /// Uncompressed: the fastest to write and read.
    None,
}

/// Width from which [`ExrCompression::Auto`] writes ZIP rather than PIZ.
const AUTO_ZIP_WIDTH: usize = 4096;

/// How to write an EXR file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ExrWriteOptions {
    /// Store 16-bit half floats instead of 32-bit floats.
    pub half: bool,
    /// Policy for values that do not fit in a half float (only with `half`).
    pub on_overflow: Overflow,
    /// Lossless compression.
    pub compression: ExrCompression,
    /// Compress on the exr crate's own pool of threads (`Some(true)`) or on the
    /// caller's (`Some(false)`). `None`: on the pool for images of a million
    /// pixels or more written outside a rayon worker, else on the caller's
    /// thread (a worker's siblings are busy with frames of their own).
    pub parallel: Option<bool>,
}

/// Which channels of the chosen layer become RGB.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Rgb,
    Luminance,
}

/// Pixel buffer that ignores out-of-range writes instead of panicking.
struct Pixels {
    width: usize,
    height: usize,
    data: Vec<f32>,
}

impl Pixels {
    fn new(size: Vec2<usize>, limits: &Limits) -> Self {
        let (w, h) = (size.width(), size.height());
        let fits = (w as u64)
            .checked_mul(h as u64)
            .is_some_and(|p| p <= limits.max_pixels);
        if !fits {
            // Unreachable after the header check; never allocate regardless.
            return Pixels {
                width: 0,
                height: 0,
                data: Vec::new(),
            };
        }
        Pixels {
            width: w,
            height: h,
            data: vec![0.0; w * h * 3],
        }
    }

    #[inline]
    fn set(&mut self, pos: Vec2<usize>, v: [f32; 3]) {
        let (x, y) = (pos.x(), pos.y());
        if x < self.width && y < self.height {
            let i = 3 * (y * self.width + x);
            if let Some(d) = self.data.get_mut(i..i + 3) {
                d.copy_from_slice(&v);
            }
        }
    }
}

/// Decodes an OpenEXR file held in memory.
pub fn decode(bytes: &[u8], name: &Path, limits: &Limits) -> Result<HdrImage> {
    guard_panic(name, "OpenEXR", || decode_inner(bytes, name, limits))
}

/// The data window `(x_min, y_min, x_max, y_max)` a single-part header
/// declares, read from the bytes (the decoder swaps a reversed window into a
/// non-empty one, so an empty image would be read as a few pixels that are not
/// in the file).
fn declared_data_window(bytes: &[u8]) -> Option<[i32; 4]> {
    const KEY: &[u8] = b"dataWindow\0box2i\0";
    let at = bytes
        .windows(KEY.len())
        .take(1 << 16)
        .position(|w| w == KEY)?
        + KEY.len();
    let size = i32::from_le_bytes(bytes.get(at..at + 4)?.try_into().ok()?);
    if size != 16 {
        return None;
    }
    let v = |k: usize| -> Option<i32> {
        Some(i32::from_le_bytes(
            bytes.get(at + 4 + 4 * k..at + 8 + 4 * k)?.try_into().ok()?,
        ))
    };
    Some([v(0)?, v(1)?, v(2)?, v(3)?])
}

/// The size a single-part header declares, from the file's first bytes
/// (`None` when the header is not among them or declares no pixels).
pub fn declared_size(head: &[u8]) -> Option<(usize, usize)> {
    let [x0, y0, x1, y1] = declared_data_window(head)?;
    let w = usize::try_from(i64::from(x1) - i64::from(x0) + 1).ok()?;
    let h = usize::try_from(i64::from(y1) - i64::from(y0) + 1).ok()?;
    (w > 0 && h > 0).then_some((w, h))
}

fn decode_inner(bytes: &[u8], name: &Path, limits: &Limits) -> Result<HdrImage> {
    if let Some([x0, y0, x1, y1]) = declared_data_window(bytes) {
        if x1 < x0 || y1 < y0 {
            return Err(Error::format(
                name,
                format!(
                    "OpenEXR image has no pixels: its data window (x {x0} to {x1}, y {y0} to {y1}) is empty"
                ),
            ));
        }
    }
    let meta = ::exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
        .map_err(|e| exr_error(name, "bad header", e))?;

    let channel_names = |h: &::exr::meta::header::Header| -> Vec<String> {
        h.channels.list.iter().map(|c| c.name.to_string()).collect()
    };
    let has = |names: &[String], n: &str| names.iter().any(|c| c == n);
    for kind in [Kind::Rgb, Kind::Luminance] {
        let Some(h) = meta.headers.iter().find(|h| {
            let names = channel_names(h);
            !h.deep
                && match kind {
                    Kind::Rgb => has(&names, "R") && has(&names, "G") && has(&names, "B"),
                    Kind::Luminance => has(&names, "Y"),
                }
        }) else {
            continue;
        };
        let names = channel_names(h);
        if kind == Kind::Luminance && (has(&names, "RY") || has(&names, "BY")) {
            return Err(Error::unsupported(
                Some(name),
                "luminance/chroma (Y, RY, BY) OpenEXR is not supported; convert it to RGB",
            ));
        }
        let size = h.layer_size;
        check_dims(name, size.width() as u64, size.height() as u64, limits)?;
        check_block_sizes(&meta, name, limits)?;
        let (w, h) = (size.width(), size.height());
        let img = match kind {
            Kind::Rgb => read_rgb(bytes, name, limits)?,
            Kind::Luminance => read_luminance(bytes, name, limits)?,
        };
        if img.width != w || img.height != h || img.data.len() != w * h * 3 {
            return Err(Error::format(
                name,
                format!(
                    "OpenEXR layer decoded as {}x{}, header declares {w}x{h}",
                    img.width, img.height
                ),
            ));
        }
        return HdrImage::from_vec(w, h, img.data);
    }
    let layers: Vec<String> = meta
        .headers
        .iter()
        .map(|h| format!("[{}]", channel_names(h).join(", ")))
        .collect();
    Err(Error::format(
        name,
        format!(
            "no OpenEXR layer has R, G, B or Y channels (found channels {})",
            if layers.is_empty() {
                "none".to_string()
            } else {
                layers.join(" ")
            }
        ),
    ))
}

/// Bytes per pixel of the limit one block may take (four float channels).
const MAX_BLOCK_BYTES_PER_PIXEL: u64 = 16;
/// Block size always allowed, so that small limits still admit the 16- to
/// 256-line blocks of small images.
const MIN_BLOCK_BYTES_LIMIT: u64 = 16 << 20;

/// The decoder allocates a buffer for a whole block (a tile, or a group of scan
/// lines) as its header declares it, before reading the block, and a tile size
/// is not bounded by the image size. So every layer's blocks are held to the
/// pixel limit too: at most [`MAX_BLOCK_BYTES_PER_PIXEL`]` * limits.max_pixels`
/// bytes (and at least [`MIN_BLOCK_BYTES_LIMIT`]).
fn check_block_sizes(meta: &::exr::meta::MetaData, name: &Path, limits: &Limits) -> Result<()> {
    use ::exr::meta::BlockDescription;
    let max = limits
        .max_pixels
        .saturating_mul(MAX_BLOCK_BYTES_PER_PIXEL)
        .max(MIN_BLOCK_BYTES_LIMIT);
    for (i, h) in meta.headers.iter().enumerate() {
        let (bw, bh, kind) = match h.blocks {
            BlockDescription::Tiles(t) => (t.tile_size.width(), t.tile_size.height(), "tiles"),
            BlockDescription::ScanLines => (
                h.layer_size.width(),
                h.compression.scan_lines_per_block(),
                "scan-line blocks",
            ),
        };
        let bytes = (bw as u64)
            .saturating_mul(bh as u64)
            .saturating_mul(h.channels.bytes_per_pixel as u64);
        if bytes > max {
            return Err(Error::format(
                name,
                format!(
                    "OpenEXR layer {i} has {kind} of {bw}x{bh} pixels at {} bytes each, more \
                     than the limit of {max} bytes per block",
                    h.channels.bytes_per_pixel
                ),
            ));
        }
    }
    Ok(())
}

fn read_rgb(bytes: &[u8], name: &Path, limits: &Limits) -> Result<Pixels> {
    let image = ::exr::image::read::read()
        .no_deep_data()
        .largest_resolution_level()
        .rgb_channels(
            |size, _| Pixels::new(size, limits),
            |px: &mut Pixels, pos, (r, g, b): (f32, f32, f32)| px.set(pos, [r, g, b]),
        )
        .first_valid_layer()
        .all_attributes()
        .non_parallel()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| exr_error(name, "cannot decode", e))?;
    Ok(image.layer_data.channel_data.pixels)
}

fn read_luminance(bytes: &[u8], name: &Path, limits: &Limits) -> Result<Pixels> {
    let image = ::exr::image::read::read()
        .no_deep_data()
        .largest_resolution_level()
        .specific_channels()
        .required("Y")
        .collect_pixels(
            |size, _| Pixels::new(size, limits),
            |px: &mut Pixels, pos, (y,): (f32,)| px.set(pos, [y, y, y]),
        )
        .first_valid_layer()
        .all_attributes()
        .non_parallel()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| exr_error(name, "cannot decode", e))?;
    Ok(image.layer_data.channel_data.pixels)
}

fn exr_error(name: &Path, what: &str, e: ::exr::error::Error) -> Error {
    let detail = match e {
        ::exr::error::Error::Io(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            "file is truncated".to_string()
        }
        other => {
            let msg = other.to_string();
            if msg.contains("missing bytes") {
                format!("truncated or corrupt ({msg})")
            } else {
                msg
            }
        }
    };
    Error::format(name, format!("OpenEXR {what}: {detail}"))
}

/// Encodes an image as OpenEXR bytes (`name` is used in error messages).
/// Refuses NaN/Inf samples and, for half output, values above 65504 unless
/// [`Overflow::Clamp`] is chosen.
pub fn encode(img: &HdrImage, name: &Path, opts: &ExrWriteOptions) -> Result<Vec<u8>> {
    let mut out = Cursor::new(Vec::new());
    encode_to(img, name, opts, &mut out)?;
    Ok(out.into_inner())
}

/// Whether `codec` shrinks `img` enough to be worth its time: a band of
/// [`TRIAL_ROWS`] rows across the middle (the horizon, where panoramas are
/// busiest) is compressed in memory and must come out under
/// [`TRIAL_RATIO`] of its raw size. Float panoramas resampled from float data
/// (the warp and flow methods' outputs) fill every mantissa bit and barely
/// compress: a warp run's 20 kitchen frames are 28.5 MB as PIZ against 31.7 MB
/// raw, and PIZ took half of the run's time. Frames that keep the SDR frame's
/// values (fusion's) compress to 60%.
fn pays(img: &HdrImage, name: &Path, codec: ExrCompression) -> bool {
    let (w, h) = (img.width(), img.height());
    let rows = TRIAL_ROWS.min(h);
    let y0 = (h - rows) / 2;
    let band = HdrImage::from_fn(w, rows, |x, y| img.get(x, y0 + y));
    let opts = ExrWriteOptions {
        compression: codec,
        parallel: Some(false),
        ..Default::default()
    };
    let mut buf = std::io::Cursor::new(Vec::new());
    if encode_to(&band, name, &opts, &mut buf).is_err() {
        return true;
    }
    (buf.get_ref().len() as f64) < TRIAL_RATIO * (w * rows * 12) as f64
}

/// Rows of [`pays`]'s trial band (PIZ and ZIP work on blocks of 32 and 16).
const TRIAL_ROWS: usize = 32;

/// Largest compressed share of the raw size at which [`ExrCompression::Auto`]
/// still compresses.
const TRIAL_RATIO: f64 = 0.85;

/// [`encode`] into any seekable writer.
fn encode_to(
    img: &HdrImage,
    name: &Path,
    opts: &ExrWriteOptions,
    mut out: impl std::io::Write + std::io::Seek,
) -> Result<()> {
    let (w, h) = (img.width(), img.height());
    check_nonempty(name, w, h)?;
    check_finite(name, img)?;
    // Auto: the codec for the width, if a trial band shows it pays.
    let auto = if w < AUTO_ZIP_WIDTH {
        ExrCompression::Piz
    } else {
        ExrCompression::Zip
    };
    let chosen = match opts.compression {
        ExrCompression::Auto if !opts.half && !pays(img, name, auto) => ExrCompression::None,
        ExrCompression::Auto => auto,
        c => c,
    };
    let encoding = ::exr::image::Encoding {
        compression: match chosen {
            ExrCompression::Zip | ExrCompression::Auto => ::exr::compression::Compression::ZIP16,
            ExrCompression::Piz => ::exr::compression::Compression::PIZ,
            ExrCompression::None => ::exr::compression::Compression::Uncompressed,
        },
        blocks: ::exr::image::Blocks::ScanLines,
        line_order: ::exr::meta::attribute::LineOrder::Increasing,
    };
    let attributes = ::exr::meta::header::LayerAttributes::default();
    // The exr crate compresses on a thread pool of its own, as many threads as
    // cores, built for each image. Inside a worker of ours (`run` writes each
    // frame on the worker that computed it, one frame per thread) that would
    // oversubscribe the cores and ignore `--threads`, and for a small image
    // building the pool costs more than it saves.
    let parallel = opts.parallel.unwrap_or_else(|| {
        rayon::current_thread_index().is_none()
            && rayon::current_num_threads() > 1
            && w * h >= 1 << 20
    });
    let result = if opts.half {
        let (count, max) = img
            .data()
            .iter()
            .filter(|v| v.abs() > HALF_MAX)
            .fold((0usize, 0f32), |(n, m), v| (n + 1, m.max(v.abs())));
        if count > 0 && opts.on_overflow == Overflow::Error {
            return Err(Error::Invalid(format!(
                "{}: {count} samples exceed the half-float maximum {HALF_MAX} (largest \
                 magnitude {max}); write float32 or choose Overflow::Clamp",
                name.display()
            )));
        }
        let half = |v: f32| f16::from_f32(v.clamp(-HALF_MAX, HALF_MAX));
        let channels = ::exr::image::SpecificChannels::rgb(|pos: Vec2<usize>| {
            let p = img.get(pos.x(), pos.y());
            (half(p[0]), half(p[1]), half(p[2]))
        });
        let image = ::exr::image::Image::from_layer(::exr::image::Layer::new(
            (w, h),
            attributes,
            encoding,
            channels,
        ));
        if parallel {
            image.write().to_buffered(&mut out)
        } else {
            image.write().non_parallel().to_buffered(&mut out)
        }
    } else {
        let channels = ::exr::image::SpecificChannels::rgb(|pos: Vec2<usize>| {
            let p = img.get(pos.x(), pos.y());
            (p[0], p[1], p[2])
        });
        let image = ::exr::image::Image::from_layer(::exr::image::Layer::new(
            (w, h),
            attributes,
            encoding,
            channels,
        ));
        if parallel {
            image.write().to_buffered(&mut out)
        } else {
            image.write().non_parallel().to_buffered(&mut out)
        }
    };
    result.map_err(|e| Error::Invalid(format!("{}: cannot encode OpenEXR: {e}", name.display())))
}

/// Writes an OpenEXR file atomically with the given options, streaming it to disk
/// (a 7776 x 3888 float image is 360 MB; it is not assembled in memory first).
pub fn write(path: &Path, img: &HdrImage, opts: &ExrWriteOptions) -> Result<()> {
    crate::fsutil::write_atomic_seekable(path, |w| encode_to(img, path, opts, w))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> HdrImage {
        HdrImage::from_fn(5, 3, |x, y| {
            [x as f32 * 1.5, y as f32 + 0.25, 1e-3 * (x + y) as f32]
        })
    }

    #[test]
    fn an_empty_data_window_is_named_not_decoded_as_phantom_pixels() {
        let n = Path::new("empty.exr");
        let mut b = encode(&sample(), n, &ExrWriteOptions::default()).unwrap();
        assert_eq!(declared_data_window(&b), Some([0, 0, 4, 2]));
        // A 0x0 image: x_max = x_min - 1, y_max = y_min - 1.
        let key = b"dataWindow\0box2i\0";
        let at = b.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
        b[at + 8..at + 16].copy_from_slice(&[0xff; 8]);
        let e = decode(&b, n, &Limits::default()).unwrap_err().to_string();
        assert!(e.contains("empty.exr") && e.contains("no pixels"), "{e}");
        assert!(e.contains("x 0 to -1, y 0 to -1"), "{e}");
    }

    #[test]
    fn float_round_trip_is_exact() {
        let n = Path::new("f.exr");
        let b = encode(&sample(), n, &ExrWriteOptions::default()).unwrap();
        assert_eq!(decode(&b, n, &Limits::default()).unwrap(), sample());
    }

    #[test]
    fn every_compression_round_trips_exactly() {
        // Noisy mantissas, a sun far beyond half-float range, zeros and tiny values,
        // over more scanlines than one ZIP or PIZ block.
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let img = HdrImage::from_fn(37, 41, |x, y| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let noise = (state >> 40) as f32 / (1u64 << 24) as f32;
            match (x + 3 * y) % 7 {
                0 => [0.0, 1e-30, 0.0],
                1 => [1e6 * (1.0 + noise), 7e5, 2e5],
                _ => [noise, 0.5 * noise + 0.1, 3.0 * noise],
            }
        });
        for compression in [
            ExrCompression::Auto,
            ExrCompression::Zip,
            ExrCompression::Piz,
            ExrCompression::None,
        ] {
            let n = Path::new("c.exr");
            let opts = ExrWriteOptions {
                compression,
                ..Default::default()
            };
            let b = encode(&img, n, &opts).unwrap();
            assert_eq!(
                decode(&b, n, &Limits::default()).unwrap(),
                img,
                "{compression:?}"
            );
        }
    }

    #[test]
    fn auto_writes_piz_under_its_width_and_zip_from_it_and_nothing_that_does_not_shrink() {
        let written = |img: &HdrImage| {
            let b = encode(img, Path::new("a.exr"), &ExrWriteOptions::default()).unwrap();
            let meta =
                ::exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(&b), false).unwrap();
            assert_eq!(
                decode(&b, Path::new("a.exr"), &Limits::default()).unwrap(),
                *img
            );
            meta.headers[0].compression
        };
        // Few distinct values (as an SDR frame's LUT gives): compressed.
        let smooth = |w: usize| HdrImage::from_fn(w, 8, |x, y| [(x % 7) as f32, y as f32, 1.0]);
        use ::exr::compression::Compression;
        assert_eq!(written(&smooth(AUTO_ZIP_WIDTH - 1)), Compression::PIZ);
        assert_eq!(written(&smooth(AUTO_ZIP_WIDTH)), Compression::ZIP16);
        // Every mantissa bit in use (float resampled from float): raw.
        let mut state = 0x9e3779b97f4a7c15u64;
        let noisy = HdrImage::from_fn(512, 64, |_, _| {
            let mut next = || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                0.2 + (state >> 40) as f32 / (1u64 << 24) as f32
            };
            [next(), next(), next()]
        });
        assert_eq!(written(&noisy), Compression::Uncompressed);
    }

    #[test]
    fn half_overflow_errors_or_clamps() {
        let n = Path::new("big.exr");
        let mut img = sample();
        img.set(1, 1, [1e5, 2e5, 1.0]);
        let opts = ExrWriteOptions {
            half: true,
            on_overflow: Overflow::Error,
            ..Default::default()
        };
        let e = encode(&img, n, &opts).unwrap_err().to_string();
        assert!(
            e.contains("big.exr") && e.contains("200000") && e.contains("2 samples"),
            "{e}"
        );
        let opts = ExrWriteOptions {
            half: true,
            on_overflow: Overflow::Clamp,
            ..Default::default()
        };
        let back = decode(&encode(&img, n, &opts).unwrap(), n, &Limits::default()).unwrap();
        assert_eq!(back.get(1, 1), [HALF_MAX, HALF_MAX, 1.0]);
    }

    #[test]
    fn non_finite_samples_are_refused() {
        let mut img = sample();
        img.set(0, 0, [f32::NAN, f32::INFINITY, 0.0]);
        let e = encode(&img, Path::new("nan.exr"), &ExrWriteOptions::default()).unwrap_err();
        assert!(
            e.to_string().contains("nan.exr") && e.to_string().contains("2 NaN"),
            "{e}"
        );
    }

    #[test]
    fn header_size_is_checked_before_decoding() {
        let n = Path::new("lim.exr");
        let b = encode(&sample(), n, &ExrWriteOptions::default()).unwrap();
        let e = decode(&b, n, &Limits { max_pixels: 10 }).unwrap_err();
        assert!(matches!(e, Error::Limit { .. }), "{e}");
        assert_eq!(
            e.to_string(),
            "lim.exr: image of 5x3 pixels exceeds the limit of 10 pixels"
        );
    }
}
