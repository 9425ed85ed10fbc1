//! Inputs the fuzz targets in `fuzz/` found (see `scripts/fuzz.sh`), replayed
//! through the same public API as their target. They live in
//! `tests/fuzz_regressions/<target>/`; add a file there and it is replayed.
//!
//! Each input must come back as a value or as an error naming the file, without
//! a panic anywhere. Files named `dep-panic-*` made a dependency panic (inside
//! the catch that `guard_panic` puts around third-party decoders) in builds with
//! overflow checks, as the test profile has; for those only a panic in
//! lumiprobe's own code fails the test. Image inputs must also stay within the
//! memory their limits allow.

use lumiprobe::capture::debevec::ResponseCurve;
use lumiprobe::capture::exif::parse;
use lumiprobe::capture::localize::parse_images_txt;
use lumiprobe::image::io::{decode_hdr, decode_sdr, exr, ldr, pfm, rgbe, Limits};
use lumiprobe::render::model::{LoadLimits, Model};
use lumiprobe::scene::manifest::Manifest;
use lumiprobe::scene::Scene;
use lumiprobe::tonemap::Response;
use lumiprobe::Error;
use std::cell::RefCell;
use std::path::{Path, PathBuf};

/// The limits the single-format image targets decode with.
const IMAGE_LIMITS: Limits = Limits {
    max_pixels: 1 << 20,
};
/// The limits of the format-sniffing target `image_any`.
const ANY_LIMITS: Limits = Limits {
    max_pixels: 1 << 24,
};

#[path = "common/peak_alloc.rs"]
mod peak_alloc;
use peak_alloc::peak_alloc;

/// Largest single allocation an image target may make for an input of `len`
/// bytes (the fuzz targets check the same bound on the total, see
/// `image_memory_bound` in fuzz/src/lib.rs).
fn image_allocation_bound(limits: &Limits, len: usize) -> usize {
    let px = limits.max_pixels as usize;
    let block = (16 * px).max(16 << 20);
    12 * px + (12 * px).max(2 * block) + 4 * len + (8 << 20)
}

thread_local! {
    /// Where this thread's panics happened while replaying.
    static PANICS: RefCell<Vec<String>> = const { RefCell::new(Vec::new()) };
}

/// Records every panic's location for the thread it happens on (and keeps
/// printing it as usual).
fn install_hook() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let at = info
                .location()
                .map(|l| l.file().to_string())
                .unwrap_or_default();
            let _ = PANICS.try_with(|p| p.borrow_mut().push(at));
            default(info);
        }));
    });
}

/// Whether a panic location is inside a dependency rather than lumiprobe.
fn in_dependency(file: &str) -> bool {
    file.contains("/registry/src/") || file.contains("/.cargo/") || file.starts_with("/rustc/")
}

fn check_err(e: &Error, shown: &str, input: &Path) -> Result<(), String> {
    let msg = e.to_string();
    if msg.contains(shown) {
        Ok(())
    } else {
        Err(format!(
            "{}: error does not name {shown}: {msg}",
            input.display()
        ))
    }
}

fn expect_named<T>(r: lumiprobe::Result<T>, name: &Path, input: &Path) -> Result<(), String> {
    match r {
        Ok(_) => Ok(()),
        Err(e) => check_err(&e, &name.to_string_lossy(), input),
    }
}

#[path = "../fuzz/src/fixtures.rs"]
mod fixtures;
use fixtures::{capture_dir, ldr_format, model_dir};

/// Feeds `data` to the reader of fuzz target `target`, as the target does.
fn replay(target: &str, data: &[u8], input: &Path, scratch: &Path) -> Result<(), String> {
    let text = || std::str::from_utf8(data).ok();
    match target {
        "exr" | "rgbe" | "pfm" => {
            let name = Path::new(match target {
                "exr" => "fuzz.exr",
                "rgbe" => "fuzz.hdr",
                _ => "fuzz.pfm",
            });
            let r = match target {
                "exr" => exr::decode(data, name, &IMAGE_LIMITS),
                "rgbe" => rgbe::decode(data, name, &IMAGE_LIMITS),
                _ => pfm::decode(data, name, &IMAGE_LIMITS),
            };
            expect_named(r, name, input)
        }
        "ldr" => {
            let (format, name) = ldr_format(data);
            expect_named(ldr::decode(data, name, format, &IMAGE_LIMITS), name, input)
        }
        "image_any" => {
            const NAMES: [&str; 8] = [
                "fuzz.exr", "fuzz.hdr", "fuzz.pfm", "fuzz.png", "fuzz.jpg", "fuzz.PIC", "fuzz",
                "fuzz.txt",
            ];
            let Some((&k, bytes)) = data.split_first() else {
                return Ok(());
            };
            let name = Path::new(NAMES[k as usize % NAMES.len()]);
            expect_named(decode_hdr(bytes, name, &ANY_LIMITS), name, input)?;
            expect_named(decode_sdr(bytes, name, &ANY_LIMITS), name, input)
        }
        "manifest" => {
            let Some(t) = text() else { return Ok(()) };
            let root = capture_dir(scratch);
            let file = root.join("lumiprobe.toml");
            expect_named(Manifest::parse(t, &root, &file), &file, input)
        }
        "scene_poses" => {
            let Some(t) = text() else { return Ok(()) };
            let root = Path::new("/nonexistent-fuzz-scene");
            let file = root.join("poses.json");
            expect_named(Scene::parse(t, root, &file), &file, input)
        }
        "colmap_images" => {
            let Some(t) = text() else { return Ok(()) };
            let file = Path::new("model/images.txt");
            expect_named(parse_images_txt(t, file), file, input)
        }
        "exif" => {
            let name = Path::new("fuzz.jpg");
            expect_named(parse(data, name), name, input)
        }
        "response" => {
            let Some((&k, rest)) = data.split_first() else {
                return Ok(());
            };
            if k & 1 == 0 {
                let Some(t) = std::str::from_utf8(rest).ok() else {
                    return Ok(());
                };
                match Response::parse(t).map(|r| r.validate()) {
                    Some(Err(e)) => Err(format!(
                        "{}: Response::parse accepted an invalid curve: {e}",
                        input.display()
                    )),
                    _ => Ok(()),
                }
            } else {
                let path = scratch.join("curve.json");
                std::fs::write(&path, rest).unwrap();
                expect_named(ResponseCurve::load(&path), &path, input)
            }
        }
        "gltf" => {
            let base = model_dir(scratch);
            let name = base.join("fuzz.glb");
            match Model::from_slice(data, Some(&base), &name, &LoadLimits::default()) {
                Ok(_) => Ok(()),
                Err(e) => check_err(&e, &base.to_string_lossy(), input),
            }
        }
        other => Err(format!(
            "tests/fuzz_regressions/{other}: no fuzz target of that name"
        )),
    }
}

#[test]
fn fuzz_regressions_are_rejected_cleanly() {
    install_hook();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz_regressions");
    let scratch = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    let mut n = 0;
    let mut targets: Vec<PathBuf> = std::fs::read_dir(&root)
        .expect("tests/fuzz_regressions exists")
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_dir())
        .collect();
    targets.sort();
    for dir in targets {
        let target = dir.file_name().unwrap().to_string_lossy().into_owned();
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        for input in files {
            let data = std::fs::read(&input).unwrap();
            let dep_panic_allowed = input
                .file_name()
                .is_some_and(|f| f.to_string_lossy().starts_with("dep-panic-"));
            PANICS.with(|p| p.borrow_mut().clear());
            let (r, peak) = peak_alloc(|| {
                std::panic::catch_unwind(|| replay(&target, &data, &input, scratch.path()))
            });
            let panics = PANICS.with(|p| p.borrow_mut().split_off(0));
            let limits = match target.as_str() {
                "exr" | "rgbe" | "pfm" | "ldr" => Some(IMAGE_LIMITS),
                "image_any" => Some(ANY_LIMITS),
                _ => None,
            };
            if let Some(l) = limits {
                let bound = image_allocation_bound(&l, data.len());
                if peak > bound {
                    failures.push(format!(
                        "{}: allocated {peak} bytes at once, bound {bound}",
                        input.display()
                    ));
                }
            }
            match r {
                Err(_) => failures.push(format!("{}: panicked", input.display())),
                Ok(Err(msg)) => failures.push(msg),
                Ok(Ok(())) => {}
            }
            for at in panics {
                if !(dep_panic_allowed && in_dependency(&at)) {
                    failures.push(format!("{}: panic at {at}", input.display()));
                }
            }
            n += 1;
        }
    }
    assert!(n > 0, "no inputs under {}", root.display());
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
