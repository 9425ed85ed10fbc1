//! Writes the seed corpus of every fuzz target: small valid inputs made with the
//! crate's own writers (and, for variants it cannot write, the `exr` and `image`
//! crates it reads them with), plus hand-written text formats.
//!
//!     cargo +nightly run --manifest-path fuzz/Cargo.toml --example make_seeds -- fuzz/corpus
//!
//! Deterministic: the same files every time. scripts/fuzz.sh runs it.

use lumiprobe::capture::debevec::ResponseCurve;
use lumiprobe::image::io::{exr, ldr, pfm, rgbe, ExrWriteOptions};
use lumiprobe::{HdrImage, SdrImage};
use std::path::{Path, PathBuf};

fn hdr(w: usize, h: usize) -> HdrImage {
    HdrImage::from_fn(w, h, |x, y| {
        let n = ((x * 7919 + y * 104_729) % 1000) as f32 / 1000.0;
        let base = 2f32.powi((x % 24) as i32 - 12);
        [base * (0.5 + n), base * 0.75, base * (1.0 - 0.5 * n)]
    })
}

fn sdr(w: usize, h: usize) -> SdrImage {
    SdrImage::from_vec(w, h, (0..w * h * 3).map(|i| (i * 31 % 251) as u8).collect()).unwrap()
}

/// EXR variants the crate reads but does not write: other compressions, half
/// RGBA, luminance only, u32 samples, tiles.
fn exr_variants() -> Vec<Vec<u8>> {
    use ::exr::prelude::*;
    let (w, h) = (7usize, 5usize);
    let val = |x: usize, y: usize| (x as f32 + 0.5) * (y as f32 + 1.0) * 0.25;
    let write = |img: &dyn Fn(&mut std::io::Cursor<Vec<u8>>)| {
        let mut buf = std::io::Cursor::new(Vec::new());
        img(&mut buf);
        buf.into_inner()
    };
    let mut out = Vec::new();
    for compression in [
        Compression::Uncompressed,
        Compression::RLE,
        Compression::ZIP1,
        Compression::PIZ,
        Compression::PXR24,
        Compression::B44,
    ] {
        let enc = Encoding {
            compression,
            ..Encoding::FAST_LOSSLESS
        };
        out.push(write(&|b| {
            let ch = SpecificChannels::rgba(|p: Vec2<usize>| {
                let v = f16::from_f32(val(p.x(), p.y()));
                (v, v, v, f16::from_f32(0.5))
            });
            Image::from_layer(Layer::new((w, h), LayerAttributes::default(), enc, ch))
                .write()
                .to_buffered(b)
                .unwrap();
        }));
    }
    out.push(write(&|b| {
        let y = AnyChannel::new(
            "Y",
            FlatSamples::F32((0..w * h).map(|i| val(i % w, i / w)).collect()),
        );
        let layer = Layer::new(
            (w, h),
            LayerAttributes::default(),
            Encoding::FAST_LOSSLESS,
            AnyChannels::sort(SmallVec::from_vec(vec![y])),
        );
        Image::from_layer(layer).write().to_buffered(b).unwrap();
    }));
    out.push(write(&|b| {
        let ch = SpecificChannels::rgb(|p: Vec2<usize>| (p.x() as u32, p.y() as u32, 7u32));
        Image::from_layer(Layer::new(
            (w, h),
            LayerAttributes::default(),
            Encoding::default(),
            ch,
        ))
        .write()
        .to_buffered(b)
        .unwrap();
    }));
    out.push(write(&|b| {
        let ch = SpecificChannels::rgb(|p: Vec2<usize>| (val(p.x(), p.y()), 1.0f32, 0.25f32));
        let enc = Encoding {
            compression: Compression::ZIP16,
            blocks: Blocks::Tiles(Vec2(4, 4)),
            line_order: LineOrder::Increasing,
        };
        Image::from_layer(Layer::new((w, h), LayerAttributes::default(), enc, ch))
            .write()
            .to_buffered(b)
            .unwrap();
    }));
    out
}

fn png_variants() -> Vec<Vec<u8>> {
    use image::{DynamicImage, ImageFormat};
    let enc = |img: DynamicImage, f: ImageFormat| {
        let mut c = std::io::Cursor::new(Vec::new());
        img.write_to(&mut c, f).unwrap();
        c.into_inner()
    };
    let gray = image::GrayImage::from_fn(5, 3, |x, y| image::Luma([(x * 40 + y * 7) as u8]));
    let la =
        image::GrayAlphaImage::from_fn(3, 3, |x, y| image::LumaA([(x * 80) as u8, (y * 90) as u8]));
    let rgba = image::RgbaImage::from_fn(4, 2, |x, y| {
        image::Rgba([x as u8 * 60, y as u8 * 100, 7, 200])
    });
    let rgb16 = image::ImageBuffer::<image::Rgb<u16>, Vec<u16>>::from_fn(3, 2, |x, y| {
        image::Rgb([x as u16 * 20000, y as u16 * 30000, 1234])
    });
    vec![
        enc(DynamicImage::ImageLuma8(gray.clone()), ImageFormat::Png),
        enc(DynamicImage::ImageLumaA8(la), ImageFormat::Png),
        enc(DynamicImage::ImageRgba8(rgba), ImageFormat::Png),
        enc(DynamicImage::ImageRgb16(rgb16), ImageFormat::Png),
        enc(DynamicImage::ImageLuma8(gray), ImageFormat::Jpeg),
    ]
}

/// A TIFF (Exif payload) with ExposureTime, FNumber and ISO, in IFD0 or behind
/// an ExifIFD pointer, in either byte order; wrapped in a JPEG APP1 segment in
/// front of a real (tiny) JPEG.
fn jpeg_with_exif(little: bool, in_ifd0: bool) -> Vec<u8> {
    let u16b = |v: u16| {
        if little {
            v.to_le_bytes()
        } else {
            v.to_be_bytes()
        }
    };
    let u32b = |v: u32| {
        if little {
            v.to_le_bytes()
        } else {
            v.to_be_bytes()
        }
    };
    let mut t: Vec<u8> = if little {
        b"II".to_vec()
    } else {
        b"MM".to_vec()
    };
    t.extend_from_slice(&u16b(42));
    t.extend_from_slice(&u32b(8));
    let entry = |t: &mut Vec<u8>, tag: u16, kind: u16, count: u32, field: u32| {
        t.extend_from_slice(&u16b(tag));
        t.extend_from_slice(&u16b(kind));
        t.extend_from_slice(&u32b(count));
        t.extend_from_slice(&u32b(field));
    };
    let tags = |t: &mut Vec<u8>, data_at: u32| {
        t.extend_from_slice(&u16b(3));
        entry(t, 0x829a, 5, 1, data_at);
        entry(t, 0x829d, 5, 1, data_at + 8);
        let iso = if little { 100u32 } else { 100u32 << 16 };
        entry(t, 0x8827, 3, 1, iso);
        t.extend_from_slice(&u32b(0));
    };
    let rationals = |t: &mut Vec<u8>| {
        for v in [1u32, 60, 22, 10] {
            t.extend_from_slice(&u32b(v));
        }
    };
    if in_ifd0 {
        // IFD0 at 8: 2 + 3 * 12 + 4 = 42 bytes, data at 50.
        tags(&mut t, 50);
        rationals(&mut t);
    } else {
        // IFD0 at 8 with one entry (ExifIFD -> 26), ExifIFD at 26, data at 68.
        t.extend_from_slice(&u16b(1));
        entry(&mut t, 0x8769, 4, 1, 26);
        t.extend_from_slice(&u32b(0));
        tags(&mut t, 68);
        rationals(&mut t);
    }
    let mut app1 = b"Exif\0\0".to_vec();
    app1.extend_from_slice(&t);
    let jpeg = ldr::encode_jpeg(&sdr(8, 8), Path::new("e.jpg"), 80).unwrap();
    let mut out = vec![0xff, 0xd8, 0xff, 0xe1];
    out.extend_from_slice(&((app1.len() + 2) as u16).to_be_bytes());
    out.extend_from_slice(&app1);
    out.extend_from_slice(&jpeg[2..]);
    out
}

const TRIANGLE_GLTF: &str = r#"{
  "asset": {"version": "2.0"},
  "scene": 0,
  "scenes": [{"nodes": [0]}],
  "nodes": [{"mesh": 0, "children": [1], "translation": [0, 1, 0]},
            {"mesh": 0, "matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 2,0,0,1]}],
  "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
  "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [1, 0.5, 0.2, 1], "metallicFactor": 0.2, "roughnessFactor": 0.7}}],
  "buffers": [{"byteLength": 48, "uri": "BUFFER"}],
  "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
                  {"buffer": 0, "byteOffset": 36, "byteLength": 12}],
  "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]},
                {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}]
}"#;

const TEXTURED_GLTF: &str = r#"{
  "asset": {"version": "2.0"},
  "scenes": [{"nodes": [0]}],
  "nodes": [{"mesh": 0, "scale": [2, 2, 2], "rotation": [0, 0.7071, 0, 0.7071]}],
  "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}, "material": 0}]}],
  "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicRoughnessTexture": {"index": 0}},
                 "normalTexture": {"index": 0, "scale": 0.5}, "occlusionTexture": {"index": 0},
                 "emissiveTexture": {"index": 0}, "emissiveFactor": [1, 1, 1], "alphaMode": "MASK"}],
  "textures": [{"source": 0, "sampler": 0}],
  "samplers": [{"wrapS": 33648, "wrapT": 33071}],
  "images": [{"uri": "tex.png"}],
  "buffers": [{"byteLength": 48, "uri": "buf.bin"}, {"byteLength": 60, "uri": "BUFFER2"}],
  "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
                  {"buffer": 1, "byteOffset": 0, "byteLength": 36},
                  {"buffer": 1, "byteOffset": 36, "byteLength": 24}],
  "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
                {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC3"},
                {"bufferView": 2, "componentType": 5126, "count": 3, "type": "VEC2",
                 "sparse": {"count": 1, "indices": {"bufferView": 2, "componentType": 5121},
                            "values": {"bufferView": 2, "byteOffset": 4}}}]
}"#;

fn base64(data: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in data.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(n >> (18 - 6 * k)) as usize & 63] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

fn triangle_buffer() -> Vec<u8> {
    let mut buf = Vec::new();
    for v in [0f32, 0., 0., 1., 0., 0., 0., 1., 0.] {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    for i in [0u16, 1, 2, 0, 0, 0] {
        buf.extend_from_slice(&i.to_le_bytes());
    }
    buf
}

fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut j = json.as_bytes().to_vec();
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let mut b = bin.to_vec();
    while !b.len().is_multiple_of(4) {
        b.push(0);
    }
    let total = 12 + 8 + j.len() + 8 + b.len();
    let mut out = b"glTF".to_vec();
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(j.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&j);
    out.extend_from_slice(&(b.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&b);
    out
}

fn gltf_seeds() -> Vec<Vec<u8>> {
    let data_uri = format!(
        "data:application/octet-stream;base64,{}",
        base64(&triangle_buffer())
    );
    let mut normals_uv = Vec::new();
    for v in [
        0f32, 0., 1., 0., 0., 1., 0., 0., 1., 0., 0., 1., 0., 0., 1., 0.5,
    ] {
        normals_uv.extend_from_slice(&v.to_le_bytes());
    }
    normals_uv.extend_from_slice(&[0; 4]);
    let data_uri2 = format!(
        "data:application/octet-stream;base64,{}",
        base64(&normals_uv)
    );
    let embedded = TRIANGLE_GLTF.replace("BUFFER", &data_uri);
    let external = TRIANGLE_GLTF.replace("BUFFER", "buf.bin");
    let textured = TEXTURED_GLTF.replace("BUFFER2", &data_uri2);
    let bin_json = TRIANGLE_GLTF.replace(r#", "uri": "BUFFER""#, "");
    vec![
        embedded.into_bytes(),
        external.into_bytes(),
        textured.into_bytes(),
        glb(&bin_json, &triangle_buffer()),
    ]
}

const MANIFESTS: [&str; 4] = [
    r#"name = "kitchen"

[camera]
response = "recover"
gain = "auto"

[[probe]]
id = "probe_00"
brackets = "probes/p1"
times = [0.001, 0.004]

[[probe]]
id = "probe_01"
hdr = "probes/p0.exr"

[frames]
folder = "path"
pattern = "frame_*.jpg"

[poses]
file = "poses.json"

[output]
folder = "out"
method = "fusion"
size = "512x256"
"#,
    r#"[camera]
response = "gamma 2.2"
gain = 0.5

[[probe]]
id = "a"
brackets = ["probes/p1/a.jpg", "probes/p1/b.jpg"]

[frames]
video = "walk.mp4"
fps = 2.0
"#,
    r#"[camera]
response = "f(x) = min(1, 1.08 * x^(1/2.2) / (1 + 0.08 * x^(1/2.2)))"
gain = 2

[[probe]]
id = "p"
hdr = "probes/p0.exr"

[frames]
folder = "path"

[output]
method = "warp"
size = "64X32"
"#,
    r#"[camera]
response = "curve.json"

[[probe]]
id = "p"
hdr = "probes/p0.exr"

[frames]
folder = "path"
"#,
];

const POSES: [&str; 2] = [
    r#"{"scene":"t","probes":[{"id":"p0","position":[0,0,1.5],"world_from_camera":[[1,0,0],[0,0,-1],[0,1,0]],"hdr":"probes/p0.exr","brackets":[{"file":"probes/p0/ev+0.jpg","ev":0,"exposure_time_s":0.0166}],"brackets_wide":[{"file":"probes/p0/wide/ev-2.jpg","ev":-2}]},
{"id":"p1","position":[2,0,1.5],"world_from_camera":[[1,0,0],[0,0,-1],[0,1,0]],"hdr":"/abs/p1.exr"}],
"frames":[{"id":"f0","position":[1.5,0,1.5],"world_from_camera":[[1.01,0,0],[0,0,-1],[0,1,0]],"sdr":"path/f0.jpg","ground_truth":"path/f0_gt.exr"},
{"id":"f1","position":[1.6,0.1,1.5],"world_from_camera":[[0,-1,0],[0,0,-1],[1,0,0]],"sdr":"path/f1.jpg"}],
"camera":{"response":"f(x) = min(1, 1.08 * x^(1/2.2) / (1 + 0.08 * x^(1/2.2)))","path_gain":0.5}}"#,
    r#"{"probes":[{"id":"p","position":[0,0,0],"world_from_camera":[[1,0,0],[0,1,0],[0,0,1]]}],"frames":[],"camera":{"response":"gamma 2.2"}}"#,
];

const IMAGES_TXT: &str = "# Image list with two lines of data per image:
#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME
#   POINTS2D[] as (X, Y, POINT3D_ID)
# Number of images: 2, mean observations per image: 1
1 0.851773 0.0165051 0.503764 -0.142941 -0.737434 1.02973 3.74354 1 frame_000_v0.png
2362.39 248.498 58396 1784.7 268.254 59027 1784.7 268.254 -1
2 1 0 0 0 0 0 0 1 probe 00 v3.png

";

fn main() {
    let out = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "fuzz/corpus".into()),
    );
    let mut n = 0;
    let mut put = |target: &str, name: &str, bytes: &[u8]| {
        let dir = out.join(target);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join(format!("seed-{name}")), bytes).unwrap();
        n += 1;
    };

    // HDR images.
    let f32_opts = ExrWriteOptions::default();
    let half_opts = ExrWriteOptions {
        half: true,
        ..Default::default()
    };
    let p = Path::new("s.exr");
    let mut exrs = vec![
        exr::encode(&hdr(4, 3), p, &f32_opts).unwrap(),
        exr::encode(&hdr(1, 1), p, &f32_opts).unwrap(),
        exr::encode(&hdr(17, 19), p, &half_opts).unwrap(),
    ];
    exrs.extend(exr_variants());
    let mut rgbes = vec![rgbe::encode(&hdr(4, 3)), rgbe::encode(&hdr(12, 3))];
    let mut old = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=2\n\n-Y 2 +X 6\n".to_vec();
    for _ in 0..2 {
        old.extend_from_slice(&[200, 100, 50, 130, 1, 1, 1, 2, 9, 9, 9, 128, 1, 1, 1, 2]);
    }
    rgbes.push(old);
    let mut cols = b"#?RGBE\n\n+X 2 -Y 1\n".to_vec();
    cols.extend_from_slice(&[128, 0, 0, 129, 0, 128, 0, 129]);
    rgbes.push(cols);
    let mut pfms = vec![
        pfm::encode(&hdr(3, 2), pfm::Endian::Little),
        pfm::encode(&hdr(2, 3), pfm::Endian::Big),
    ];
    let mut gray = b"Pf\n2 1\n-1\n".to_vec();
    gray.extend_from_slice(&2.5f32.to_le_bytes());
    gray.extend_from_slice(&7.0f32.to_le_bytes());
    pfms.push(gray);
    let mut ldrs = vec![
        ldr::encode_png(&sdr(5, 4), Path::new("s.png")).unwrap(),
        ldr::encode_jpeg(&sdr(9, 7), Path::new("s.jpg"), 90).unwrap(),
        ldr::encode_jpeg(&sdr(16, 16), Path::new("s.jpg"), 30).unwrap(),
    ];
    ldrs.extend(png_variants());

    for (target, files) in [
        ("exr", &mut exrs),
        ("rgbe", &mut rgbes),
        ("pfm", &mut pfms),
        ("ldr", &mut ldrs),
    ] {
        for (i, b) in files.iter().enumerate() {
            put(target, &format!("{i}"), b);
        }
    }
    // The sniffing reader: every image with each first byte that picks an
    // extension (0 .exr, 1 .hdr, 2 .pfm, 3 .png, 4 .jpg, 6 none).
    for (k, files) in [(0u8, &exrs), (1, &rgbes), (2, &pfms), (3, &ldrs)] {
        for (i, b) in files.iter().enumerate() {
            let mut v = vec![k];
            v.extend_from_slice(b);
            put("image_any", &format!("{k}-{i}"), &v);
            let mut v = vec![6u8];
            v.extend_from_slice(b);
            put("image_any", &format!("6-{k}-{i}"), &v);
        }
    }

    for (i, m) in MANIFESTS.iter().enumerate() {
        put("manifest", &format!("{i}"), m.as_bytes());
    }
    for (i, s) in POSES.iter().enumerate() {
        put("scene_poses", &format!("{i}"), s.as_bytes());
    }
    put("colmap_images", "0", IMAGES_TXT.as_bytes());
    for (i, g) in gltf_seeds().iter().enumerate() {
        put("gltf", &format!("{i}"), g);
    }
    for (i, (little, ifd0)) in [(true, true), (false, false), (true, false)]
        .into_iter()
        .enumerate()
    {
        put("exif", &format!("{i}"), &jpeg_with_exif(little, ifd0));
    }
    put(
        "exif",
        "plain",
        &ldr::encode_jpeg(&sdr(8, 8), Path::new("e.jpg"), 80).unwrap(),
    );

    for (i, t) in [
        "srgb",
        "gamma 2.2",
        "f(x) = min(1, 1.08 * x^(1/2.2) / (1 + 0.08 * x^(1/2.2)))",
    ]
    .iter()
    .enumerate()
    {
        put(
            "response",
            &format!("text-{i}"),
            format!("\0{t}").as_bytes(),
        );
    }
    let tmp = std::env::temp_dir().join(format!("lumiprobe-seeds-{}.json", std::process::id()));
    ResponseCurve::documented().save(&tmp).unwrap();
    let mut curve = vec![1u8];
    curve.extend_from_slice(&std::fs::read(&tmp).unwrap());
    std::fs::remove_file(&tmp).unwrap();
    put("response", "curve", &curve);

    // The C ABI harness decodes its input with `arbitrary`; its seeds are the
    // image files above, which decode to short call sequences.
    for (i, b) in exrs.iter().chain(&rgbes).chain(&pfms).take(6).enumerate() {
        put("capi", &format!("{i}"), b);
    }
    println!("wrote {n} seed files under {}", out.display());
}
