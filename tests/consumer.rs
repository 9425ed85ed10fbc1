//! Consumer 360° video (issue 20): a walk re-made as a camera with
//! auto-exposure, drifting white balance and H.264 records it
//! (`scripts/consumer_variant.py`), and each frame's exposure recovered by
//! `lumiprobe calibrate --per-frame` against the variant's true gains.

#[path = "common/data.rs"]
#[allow(dead_code)]
mod data;

use std::ffi::OsString;
use std::path::Path;
use std::process::Command;

fn python() -> &'static str {
    if Path::new("/usr/bin/python3").exists() {
        "/usr/bin/python3"
    } else {
        "python3"
    }
}

/// Runs `lumiprobe` with `args`, asserts that it succeeds and returns its
/// stdout.
fn lumiprobe(args: &[OsString]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "lumiprobe {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn json(path: &Path) -> serde_json::Value {
    let text = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_slice(&text).unwrap()
}

/// Makes a consumer-camera variant of `scene` in `out` with
/// `scripts/consumer_variant.py` and `args`, asserting that it succeeds.
fn make_variant(scene: &Path, out: &Path, args: &[&str]) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/consumer_variant.py");
    let run = Command::new(python())
        .arg(&script)
        .arg(scene)
        .arg(out)
        .args(args)
        .output()
        .expect("python3 runs the variant maker");
    assert!(
        run.status.success(),
        "consumer_variant.py failed (needs python3-opencv and ffmpeg): {}",
        String::from_utf8_lossy(&run.stderr)
    );
}

#[test]
fn each_frames_exposure_is_recovered_from_an_auto_exposed_h264_walk() {
    let scene = data::shared_file("scenes/kitchen");
    let tmp = tempfile::tempdir().unwrap();
    let variant = tmp.path().join("variant");
    make_variant(
        &scene,
        &variant,
        &["--vignette", "0", "--hunt", "0.7", "--seed", "3"],
    );
    assert!(variant.join("walk.mp4").metadata().unwrap().len() > 0);
    let truth = json(&variant.join("variant.json"));
    let frames = truth["frames"].as_array().unwrap();
    let evs: Vec<f64> = frames.iter().map(|f| f["ev"].as_f64().unwrap()).collect();
    let swing =
        evs.iter().cloned().fold(f64::MIN, f64::max) - evs.iter().cloned().fold(f64::MAX, f64::min);
    assert!(swing > 0.5, "the variant's exposure must move: {evs:?}");

    let gains = tmp.path().join("gains.json");
    let stdout = lumiprobe(&[
        "calibrate".into(),
        "--per-frame".into(),
        "--json".into(),
        gains.clone().into(),
        variant.clone().into(),
    ]);
    assert!(stdout.contains("it moved along the walk"), "{stdout}");
    let got = json(&gains);
    assert_eq!(got["varies"], true);
    let rows = got["frames"].as_array().unwrap();
    assert_eq!(rows.len(), frames.len());
    let lum = |g: &serde_json::Value| {
        0.2126 * g[0].as_f64().unwrap()
            + 0.7152 * g[1].as_f64().unwrap()
            + 0.0722 * g[2].as_f64().unwrap()
    };
    let mut err: Vec<f64> = rows
        .iter()
        .zip(frames)
        .map(|(r, t)| {
            assert_eq!(r["id"], t["id"]);
            (lum(&r["gain"]) / lum(&t["gain"])).log2().abs()
        })
        .collect();
    err.sort_by(f64::total_cmp);
    let (median, worst) = (err[err.len() / 2], err[err.len() - 1]);
    // Measured at commit time: median 0.05, worst 0.13 EV (kitchen, 512x256,
    // 20 frames; docs/consumer-video.md). The issue asks 0.05 / 0.2.
    assert!(
        median <= 0.08 && worst <= 0.2,
        "EV error median {median:.3}, worst {worst:.3}: {err:?}"
    );

    // Fusion run as a user would (`--calibrate`), with one gain for the walk
    // and with each frame's own: the frames' own gains bring the irradiance
    // error under the 6% and keep every frame under 15%.
    let mut irr = Vec::new();
    for mode in ["off", "on"] {
        let pred = tmp.path().join(format!("fusion_{mode}"));
        lumiprobe(&[
            "run".into(),
            "--method".into(),
            "fusion".into(),
            "--calibrate".into(),
            "-q".into(),
            "--frame-exposure".into(),
            mode.into(),
            "--out".into(),
            pred.clone().into(),
            variant.clone().into(),
        ]);
        let stdout = lumiprobe(&[
            "eval".into(),
            "--json".into(),
            "--pred".into(),
            format!("fusion={}", pred.display()).into(),
            variant.clone().into(),
        ]);
        let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        let row = &v["table"]["rows"][0];
        assert_eq!(row["label"], "fusion");
        let mean = row["mean"]["irradiance_rel_err"].as_f64().unwrap();
        let worst = row["tail"]["metrics"]["irradiance_rel_err"]["worst"]
            .as_f64()
            .unwrap();
        irr.push((mean, worst));
    }
    let ((off, _), (on, on_worst)) = (irr[0], irr[1]);
    assert!(
        on < 0.06 && on_worst < 0.15 && on < off,
        "irradiance error: one gain {off:.4}, each frame's {on:.4} (worst {on_worst:.4})"
    );
}

#[test]
fn a_walk_with_nothing_well_exposed_is_refused_with_the_scene_named() {
    let scene = data::smoke_scene();
    let tmp = tempfile::tempdir().unwrap();
    // The scene's poses with every frame replaced by a white (clipped) image.
    let dir = tmp.path().join("white");
    std::fs::create_dir_all(dir.join("path")).unwrap();
    let mut poses = json(&scene.join("poses.json"));
    for f in poses["frames"].as_array_mut().unwrap() {
        let id = f["id"].as_str().unwrap().to_string();
        let img = lumiprobe::image::SdrImage::from_vec(128, 64, vec![255; 128 * 64 * 3]).unwrap();
        let p = dir.join("path").join(format!("{id}.png"));
        lumiprobe::image::io::write_sdr(&p, &img).unwrap();
        f["sdr"] = serde_json::json!(format!("path/{id}.png"));
    }
    std::os::unix::fs::symlink(scene.join("probes"), dir.join("probes")).unwrap();
    std::fs::write(dir.join("poses.json"), poses.to_string()).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args(["calibrate", "--per-frame"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(&dir.display().to_string()) && err.contains("well-exposed"),
        "{err}"
    );
    // Run from the scene's folder on the bare file name: the message still
    // names where (the folder `.`) and which scene.
    let out = Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args(["calibrate", "--per-frame", "poses.json"])
        .current_dir(&dir)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("invalid input: . (scene ") && err.contains("well-exposed"),
        "{err}"
    );
}

#[test]
fn a_dual_fisheye_mp4_is_read_at_its_rate_stitched_and_fused_from_its_manifest() {
    // Kitchen as a two-lens camera records it: both fisheye circles side by side
    // in one H.264 video at 10 fps, auto-exposed. Its manifest (written by the
    // variant maker) reads the video, stitches each frame and fuses it.
    let scene = data::shared_file("scenes/kitchen");
    let tmp = tempfile::tempdir().unwrap();
    let variant = tmp.path().join("variant");
    make_variant(
        &scene,
        &variant,
        &["--vignette", "0", "--seed", "0", "--dual-fisheye", "195"],
    );
    let pred = tmp.path().join("out");
    let manifest = variant.join("scene.toml");
    lumiprobe(&[
        "run".into(),
        "--method".into(),
        "fusion".into(),
        "--calibrate".into(),
        "--frame-exposure".into(),
        "on".into(),
        "-q".into(),
        "--out".into(),
        pred.clone().into(),
        manifest.into(),
    ]);
    // Every frame of the video, with its time in it (in the manifest's cache,
    // under its own output folder).
    let cache: Vec<_> = std::fs::read_dir(variant.join("out/cache"))
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("times.json").exists())
        .collect();
    assert_eq!(cache.len(), 1, "one extraction folder with times.json");
    let times = json(&cache[0].join("times.json"));
    let times = times.as_array().unwrap();
    assert_eq!(times.len(), 20);
    for (k, t) in times.iter().enumerate() {
        assert_eq!(t[0], format!("frame_{:05}", k + 1));
        let s = t[1].as_f64().unwrap();
        assert!((s - k as f64 / 10.0).abs() < 1e-3, "frame {k} at {s} s");
    }
    let stdout = lumiprobe(&[
        "eval".into(),
        "--json".into(),
        "--pred".into(),
        format!("fusion={}", pred.display()).into(),
        variant.join("poses_video.json").into(),
    ]);
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let row = &v["table"]["rows"][0];
    assert_eq!(row["label"], "fusion");
    assert_eq!(row["frames"], 20, "{row}");
    let mean = row["mean"]["irradiance_rel_err"].as_f64().unwrap();
    let worst = row["tail"]["metrics"]["irradiance_rel_err"]["worst"]
        .as_f64()
        .unwrap();
    // Measured at commit time: 0.0222 mean (the same walk as equirect frames:
    // 0.0226; docs/consumer-video.md).
    assert!(
        mean < 0.05 && worst < 0.15,
        "irradiance error from the dual-fisheye video: mean {mean:.4}, worst {worst:.4}"
    );
}

/// Runs `lumiprobe` with `args`, asserts that it fails and returns its stderr.
fn lumiprobe_fails(args: &[OsString]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args(args)
        .output()
        .unwrap();
    assert!(!out.status.success(), "lumiprobe {args:?} succeeded");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn bad_consumer_inputs_are_refused_naming_the_file_and_leave_earlier_outputs_alone() {
    let scene = data::smoke_scene();
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bad");
    std::fs::create_dir_all(&dir).unwrap();
    std::os::unix::fs::symlink(scene.join("probes"), dir.join("probes")).unwrap();
    std::fs::copy(scene.join("poses.json"), dir.join("poses.json")).unwrap();
    // An output folder holding an earlier run's frame, which no refused run
    // may touch.
    let out = tmp.path().join("earlier");
    std::fs::create_dir_all(&out).unwrap();
    let earlier = out.join("frame_000.exr");
    std::fs::write(&earlier, b"an earlier run's output").unwrap();
    let manifest = |name: &str, frames: &str| {
        let p = dir.join(name);
        std::fs::write(
            &p,
            format!(
                "name = \"bad\"\n[camera]\nresponse = \"srgb\"\ngain = 1.0\n\
                 [[probe]]\nid = \"probe_00\"\nhdr = \"probes/probe_00.exr\"\n\
                 [frames]\n{frames}\n[poses]\nfile = \"poses.json\"\n"
            ),
        )
        .unwrap();
        p
    };
    let run = |m: &Path| -> String {
        lumiprobe_fails(&[
            "run".into(),
            "--method".into(),
            "fusion".into(),
            "-q".into(),
            "--out".into(),
            out.clone().into(),
            m.into(),
        ])
    };

    // A video ffmpeg cannot read.
    std::fs::write(dir.join("walk.mp4"), b"not a video at all").unwrap();
    let err = run(&manifest("video.toml", "video = \"walk.mp4\"\nfps = 2.0"));
    assert!(
        err.contains("walk.mp4") && err.contains("ffmpeg could not read it"),
        "{err}"
    );

    // Equirect frames declared as two fisheye circles.
    let frames = dir.join("path");
    std::fs::create_dir_all(&frames).unwrap();
    let mut poses = json(&scene.join("poses.json"));
    let ids: Vec<String> = poses["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["id"].as_str().unwrap().to_string())
        .collect();
    for id in &ids {
        std::fs::copy(
            scene.join("path").join(format!("{id}.jpg")),
            frames.join(format!("{id}.jpg")),
        )
        .unwrap();
    }
    let err = run(&manifest(
        "layout.toml",
        "folder = \"path\"\npattern = \"frame_*.jpg\"\nlayout = \"dual-fisheye\"",
    ));
    assert!(
        err.contains(&format!("{}.jpg", ids[0]))
            && err.contains("frames.layout")
            && err.contains("outside both lens circles"),
        "{err}"
    );

    // One frame of another size: refused before any frame is computed, naming
    // it and the first frame; with --size every frame is resampled and it runs.
    let odd = frames.join(format!("{}.jpg", ids[2]));
    let img = lumiprobe::image::io::read_sdr(&odd).unwrap();
    let (w, h) = (img.width() / 2, img.height() / 2);
    let half = lumiprobe::image::SdrImage::from_vec(
        w,
        h,
        (0..w * h)
            .flat_map(|i| img.get(2 * (i % w), 2 * (i / w)))
            .collect(),
    )
    .unwrap();
    lumiprobe::image::io::write_sdr(&odd, &half).unwrap();
    for f in poses["frames"].as_array_mut().unwrap() {
        let id = f["id"].as_str().unwrap().to_string();
        f["sdr"] = serde_json::json!(format!("path/{id}.jpg"));
    }
    std::fs::write(dir.join("poses.json"), poses.to_string()).unwrap();
    let err = run(&dir.join("poses.json"));
    assert!(
        err.contains(&format!("{}.jpg", ids[2]))
            && err.contains(&format!("{}.jpg", ids[0]))
            && err.contains("--size"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(&earlier).unwrap(),
        b"an earlier run's output",
        "a refused run changed an earlier output"
    );
    let names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        names,
        vec!["frame_000.exr".to_string()],
        "a refused run wrote {names:?}"
    );
    let resized = dir.join("resized");
    lumiprobe(&[
        "run".into(),
        "--method".into(),
        "warp".into(),
        "-q".into(),
        "--size".into(),
        format!("{}x{}", img.width(), img.height()).into(),
        "--out".into(),
        resized.clone().into(),
        dir.join("poses.json").into(),
    ]);
    assert!(resized.join(format!("{}.exr", ids[2])).is_file());
}
