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

#[test]
fn an_output_folder_that_is_a_file_is_named_as_such() {
    let tmp = tempfile::tempdir().unwrap();
    let p = lumiprobe::synth::SynthParams {
        width: 64,
        n_frames: 2,
        n_probes: 2,
        seed: 2,
        name: "f".into(),
        ..Default::default()
    };
    let scene = tmp.path().join("scene");
    lumiprobe::synth::synthesize(&p).write(&scene).unwrap();
    let file = tmp.path().join("afile");
    std::fs::write(&file, b"keep me").unwrap();
    refused(
        &[
            "run",
            scene.to_str().unwrap(),
            "--out",
            file.to_str().unwrap(),
        ],
        &["afile", "is a file where a folder is needed"],
    );
    assert_eq!(std::fs::read(&file).unwrap(), b"keep me");
}

#[test]
fn convert_repairs_nan_with_a_warning_that_counts_them() {
    let tmp = tempfile::tempdir().unwrap();
    // A 2x1 colour PFM (little-endian): one pixel NaN in red, one infinite.
    let mut bytes = b"PF\n2 1\n-1.0\n".to_vec();
    for v in [f32::NAN, 0.5, 0.5, f32::INFINITY, 1.0, 2.0] {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    let src = tmp.path().join("bad.pfm");
    std::fs::write(&src, bytes).unwrap();
    let dst = tmp.path().join("good.exr");
    let out = Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args(["convert", src.to_str().unwrap(), dst.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("bad.pfm") && err.contains("2 NaN"), "{err}");
    assert!(!err.contains("::"), "a Rust path in a message: {err}");
    let img = lumiprobe::image::io::read_hdr(&dst).unwrap();
    assert_eq!(img.count_invalid(), 0);
    assert_eq!(img.get(1, 0), [2.0, 1.0, 2.0]);
}

#[test]
fn frames_that_are_not_2_to_1_or_not_the_probes_size_are_warned_about() {
    let tmp = tempfile::tempdir().unwrap();
    let p = lumiprobe::synth::SynthParams {
        width: 64,
        n_frames: 2,
        n_probes: 2,
        seed: 4,
        name: "w".into(),
        ..Default::default()
    };
    let dir = tmp.path().join("scene");
    lumiprobe::synth::synthesize(&p).write(&dir).unwrap();
    let scene = lumiprobe::scene::Scene::load(&dir).unwrap();
    // Every frame 64x40: neither 2:1 nor the probes' 64x32.
    for f in &scene.frames {
        let img = lumiprobe::image::SdrImage::from_vec(64, 40, vec![90u8; 64 * 40 * 3]).unwrap();
        lumiprobe::image::io::write_sdr(&f.sdr, &img).unwrap();
    }
    let out = Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args([
            "run",
            dir.to_str().unwrap(),
            "--out",
            tmp.path().join("o").to_str().unwrap(),
            "--method",
            "warp",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("64x40 is not a 2:1"), "{err}");
    assert!(err.contains("but its probe is 64x32"), "{err}");
    // Once each, not once per frame.
    assert_eq!(err.matches("not a 2:1").count(), 1, "{err}");
}

#[test]
fn run_help_fits_a_screen_and_help_all_shows_the_tuning_options() {
    let help = |flag: &str| {
        let out = Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
            .args(["run", flag])
            .output()
            .unwrap();
        assert!(out.status.success());
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let short = help("--help");
    assert!(
        short.lines().count() <= 60,
        "{} lines:\n{short}",
        short.lines().count()
    );
    assert!(
        short.contains("--help-all") && !short.contains("--yaw-steps"),
        "{short}"
    );
    let all = help("--help-all");
    for flag in [
        "--yaw-steps",
        "--flow-preset",
        "Warp method tuning",
        "Flow method tuning",
    ] {
        assert!(all.contains(flag), "--help-all lacks {flag}");
    }
    // Hidden from --help, still taken: the bad value is refused by the option's
    // own check, not as an unknown argument.
    refused(
        &["run", "no-such-scene", "--out", "x", "--yaw-steps", "x"],
        &["--yaw-steps"],
    );
}

#[test]
fn every_command_repairs_nan_inf_and_negative_samples_with_one_counted_warning() {
    let tmp = tempfile::tempdir().unwrap();
    let (w, h) = (32usize, 16usize);
    let mut samples = vec![0.5f32; w * h * 3];
    samples[7] = f32::NAN;
    samples[100] = f32::INFINITY;
    samples[200] = -2.0;
    let mut b = format!("PF\n{w} {h}\n-1.0\n").into_bytes();
    for v in &samples {
        b.extend_from_slice(&v.to_le_bytes());
    }
    let bad = tmp.path().join("bad.pfm");
    std::fs::write(&bad, b).unwrap();
    let p = |name: &str| tmp.path().join(name).to_string_lossy().into_owned();
    let bad_s = bad.to_string_lossy().into_owned();
    let commands: Vec<Vec<String>> = vec![
        vec!["tonemap".into(), bad_s.clone(), p("t.png")],
        vec!["convert".into(), bad_s.clone(), p("c.exr")],
        vec![
            "rotate".into(),
            bad_s.clone(),
            p("r.exr"),
            "--yaw".into(),
            "10".into(),
        ],
        vec!["cube".into(), bad_s.clone(), "--out".into(), p("cube")],
        vec![
            "prefilter".into(),
            bad_s.clone(),
            "--out".into(),
            p("pf"),
            "--face-size".into(),
            "8".into(),
            "--mips".into(),
            "2".into(),
            "--samples".into(),
            "8".into(),
        ],
    ];
    for args in commands {
        let out = Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{args:?}: {err}");
        let warnings: Vec<&str> = err.lines().filter(|l| l.starts_with("warning:")).collect();
        assert_eq!(warnings.len(), 1, "{args:?}: {err}");
        assert!(
            warnings[0].contains("bad.pfm")
                && warnings[0].contains("3 NaN, infinite or negative samples repaired"),
            "{args:?}: {err}"
        );
    }
}

#[test]
fn vignetting_without_each_frames_exposure_is_refused() {
    // The falloff is fitted with each frame's own gain: without it the flag
    // would be ignored.
    refused(
        &[
            "run",
            "no-such-scene",
            "--out",
            "x",
            "--calibrate",
            "--vignetting",
        ],
        &["--vignetting", "--frame-exposure"],
    );
}
