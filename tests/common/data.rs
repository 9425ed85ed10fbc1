//! Where the tests find the data they need; missing data fails the test (with
//! what to do), it never passes silently.

use std::path::PathBuf;

/// The shared evaluation data (`../shared/data`, or `LUMIPROBE_DATA`).
pub fn shared_data() -> PathBuf {
    let candidates = [
        std::env::var_os("LUMIPROBE_DATA").map(PathBuf::from),
        Some(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data")),
    ];
    candidates
        .into_iter()
        .flatten()
        .find(|p| p.join("scenes").is_dir())
        .unwrap_or_else(|| {
            panic!(
                "the evaluation data is missing: expected ../shared/data/scenes beside the \
                 repository, or a folder named by LUMIPROBE_DATA"
            )
        })
}

/// A file or folder of the shared data, which must exist.
#[allow(dead_code)]
pub fn shared_file(rel: &str) -> PathBuf {
    let p = shared_data().join(rel);
    assert!(
        p.exists(),
        "{} is missing from the evaluation data",
        p.display()
    );
    p
}

/// The corpus scene CI renders (`scripts/test.sh` builds it with Blender and
/// names it in `LUMIPROBE_SMOKE_SCENE`).
#[allow(dead_code)]
pub fn smoke_scene() -> PathBuf {
    let p = std::env::var_os("LUMIPROBE_SMOKE_SCENE")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/ci-corpus/s0001_128x64")
        });
    assert!(
        p.join("poses.json").is_file(),
        "the CI corpus scene {} is missing: `bash scripts/test.sh` renders it with Blender \
         (scripts/corpus/build.py), or set LUMIPROBE_SMOKE_SCENE",
        p.display()
    );
    p
}
