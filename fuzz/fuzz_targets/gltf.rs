//! The glTF 2.0 / GLB loader (`Model::from_slice`, what `Model::load` calls
//! after reading the file) on arbitrary bytes, with the crate's default limits.
//! Relative URIs resolve in a folder holding `buf.bin` (48 bytes: a triangle's
//! positions, then its indices) and `tex.png` (a 2x2 RGB PNG).
#![no_main]
use libfuzzer_sys::fuzz_target;
use lumiprobe::render::model::{LoadLimits, Model};
use lumiprobe_fuzz::{fixtures, scratch};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

fn model_dir() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| fixtures::model_dir(scratch()))
}

fuzz_target!(|data: &[u8]| {
    let base = model_dir();
    let name = base.join("fuzz.glb");
    let limits = LoadLimits::default();
    match Model::from_slice(data, Some(base), &name, &limits) {
        Ok(m) => {
            assert!(m.triangle_count() <= limits.max_triangles);
            let texels: u64 = m
                .textures
                .iter()
                .map(|t| {
                    assert!(t.width() <= limits.max_texture_side);
                    assert!(t.height() <= limits.max_texture_side);
                    (t.width() * t.height()) as u64
                })
                .sum();
            assert!(texels <= limits.max_total_texels);
            let _ = m.bounds();
        }
        Err(e) => {
            // Errors about an external file name that file instead.
            let msg = e.to_string();
            assert!(
                msg.contains(&*name.to_string_lossy()) || msg.contains(&*base.to_string_lossy()),
                "error names neither the model nor a file beside it: {msg}"
            );
        }
    }
});
