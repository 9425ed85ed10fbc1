//! The scene manifest (`lumiprobe.toml`) parser on arbitrary text, against a
//! capture folder holding one file of each kind a manifest can point at.
#![no_main]
use libfuzzer_sys::fuzz_target;
use lumiprobe::scene::manifest::{Manifest, ResponseChoice};
use lumiprobe_fuzz::{assert_names_file, scratch};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// `<scratch>/capture` with probes/p0.exr, probes/p1/{a,b}.jpg,
/// path/frame_000{0,1}.jpg, walk.mp4, poses.json and curve.json (contents do
/// not matter: the parser only checks that they exist).
fn capture() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = scratch().join("capture");
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
    })
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let root = capture();
    let file = root.join("lumiprobe.toml");
    match Manifest::parse(text, root, &file) {
        Ok(m) => {
            assert!(!m.probes.is_empty());
            if let ResponseChoice::Known(r) = &m.response {
                r.validate().expect("a manifest's response is usable");
            }
            if let Some((w, h)) = m.output.size {
                assert!((8..=16384).contains(&w) && (4..=8192).contains(&h));
            }
        }
        Err(e) => assert_names_file(&e, &file),
    }
});
