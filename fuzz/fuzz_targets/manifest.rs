//! The scene manifest (`lumiprobe.toml`) parser on arbitrary text, against a
//! capture folder holding one file of each kind a manifest can point at.
#![no_main]
use libfuzzer_sys::fuzz_target;
use lumiprobe::scene::manifest::{Manifest, ResponseChoice};
use lumiprobe_fuzz::{assert_names_file, fixtures, scratch};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The capture folder of [`fixtures::capture_dir`], made once.
fn capture() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| fixtures::capture_dir(scratch()))
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
