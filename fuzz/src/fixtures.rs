//! Inputs the fuzz targets and their replay test (`tests/fuzz_regressions.rs`,
//! which includes this file by path) set up the same way: the folders a manifest
//! and a glTF model resolve their files in, and how the 8-bit target picks its
//! decoder. Depends only on `lumiprobe`, so both crates can compile it.

use lumiprobe::image::io::Format;
use lumiprobe::SdrImage;
use std::path::{Path, PathBuf};

/// `<root>/capture` with probes/p0.exr, probes/p1/{a,b}.jpg,
/// path/frame_000{0,1}.jpg, walk.mp4, poses.json and curve.json (contents do not
/// matter: the manifest parser only checks that they exist).
pub fn capture_dir(root: &Path) -> PathBuf {
    let d = root.join("capture");
    for f in [
        "probes/p0.exr",
        "probes/p1/a.jpg",
        "probes/p1/b.jpg",
        "path/frame_0000.jpg",
        "path/frame_0001.jpg",
        "walk.mp4",
        "poses.json",
        "curve.json",
    ] {
        let p = d.join(f);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(&p, b"x").unwrap();
    }
    d
}

/// `<root>/model` with `buf.bin` (48 bytes: a triangle's positions, then its
/// indices) and `tex.png` (a 2x2 RGB PNG), for glTF files' relative URIs.
pub fn model_dir(root: &Path) -> PathBuf {
    let d = root.join("model");
    std::fs::create_dir_all(&d).unwrap();
    let mut buf = Vec::new();
    for v in [0f32, 0., 0., 1., 0., 0., 0., 1., 0.] {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    for i in [0u16, 1, 2, 0, 0, 0] {
        buf.extend_from_slice(&i.to_le_bytes());
    }
    std::fs::write(d.join("buf.bin"), &buf).unwrap();
    let tex = SdrImage::from_vec(2, 2, (0..12).map(|i| i * 20).collect()).unwrap();
    lumiprobe::image::io::write_sdr(&d.join("tex.png"), &tex).unwrap();
    d
}

/// The 8-bit decoder for `data` and the file name it is reported under: the
/// magic picks it as in `decode_sdr`, else the first byte does.
pub fn ldr_format(data: &[u8]) -> (Format, &'static Path) {
    let format = match Format::sniff(data) {
        Some(f @ (Format::Png | Format::Jpeg)) => f,
        _ if data.first().is_some_and(|b| b & 1 == 1) => Format::Jpeg,
        _ => Format::Png,
    };
    let name = Path::new(if format == Format::Png {
        "fuzz.png"
    } else {
        "fuzz.jpg"
    });
    (format, name)
}
