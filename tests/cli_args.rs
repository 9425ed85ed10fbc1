//! Numeric and size options are checked before any work: NaN, infinity and
//! sizes past the largest panorama are one-line errors naming the option.

use std::process::Command;

fn refused(args: &[&str], names: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args(args)
        .output()
        .expect("the lumiprobe binary runs");
    assert!(!out.status.success(), "{args:?} was accepted");
    let err = String::from_utf8_lossy(&out.stderr);
    for n in names {
        assert!(err.contains(n), "{args:?}: {err:?} does not name {n:?}");
    }
    assert!(!err.contains("panicked"), "{args:?}: {err}");
}

#[test]
fn a_size_past_the_largest_panorama_is_refused_before_allocating() {
    refused(
        &[
            "run",
            "no-such-scene",
            "--out",
            "x",
            "--size",
            "65536x32768",
        ],
        &["--size", "16384x8192"],
    );
    refused(
        &["run", "s", "--out", "x", "--size", "64"],
        &["--size", "WxH"],
    );
}

#[test]
fn nan_and_infinite_numbers_are_refused() {
    refused(
        &["rotate", "a.exr", "b.exr", "--yaw", "nan"],
        &["--yaw", "finite"],
    );
    refused(
        &["tonemap", "a.exr", "b.png", "--ev", "inf"],
        &["--ev", "finite"],
    );
    refused(&["tonemap", "a.exr", "b.png", "--ev", "-inf"], &["--ev"]);
    refused(
        &["rotate", "a.exr", "b.exr", "--pitch", "x"],
        &["--pitch", "not a number"],
    );
}
