//! `lumiprobe corpus` end to end on a tiny corpus made on the spot from the
//! synthesizer: rows, totals, agreement with `lumiprobe eval`, resume, failures.

use lumiprobe::synth::{synthesize, SynthParams};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn exe() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_lumiprobe"))
}

fn lumiprobe(args: &[&str]) -> Output {
    Command::new(exe())
        .arg("-q")
        .args(["--threads", "2"])
        .args(args)
        .output()
        .expect("the lumiprobe binary runs")
}

fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "lumiprobe failed: {}\n{}",
        String::from_utf8_lossy(&out.stderr),
        String::from_utf8_lossy(&out.stdout)
    );
    String::from_utf8(out.stdout.clone()).unwrap()
}

/// A synthetic scene in `dir`, with a `summary.json` beside it that flags
/// `flagged` as unanswerable (among keys the command does not read).
fn scene(dir: &Path, seed: u64, flagged: &[&str]) {
    let p = SynthParams {
        width: 256,
        n_frames: 4,
        n_probes: 2,
        seed,
        name: format!("room{seed}"),
        brackets: false,
        ..Default::default()
    };
    synthesize(&p).write(dir).unwrap();
    std::fs::write(
        dir.join("summary.json"),
        format!(
            r#"{{"unanswerable_frames": [{}], "anything": {{"else": 1}}}}"#,
            flagged
                .iter()
                .map(|f| format!(r#"{{"id": "{f}", "unseen_share": 0.5}}"#))
                .collect::<Vec<_>>()
                .join(", ")
        ),
    )
    .unwrap();
}

/// A corpus of two scenes, `room_a` (dev) and `room_b` (val).
fn corpus(root: &Path) {
    scene(&root.join("scenes/room_a"), 11, &["frame_001"]);
    scene(&root.join("scenes/room_b"), 12, &[]);
    std::fs::write(
        root.join("corpus.json"),
        r#"{"generator_version": "test-1", "scenes": [
            {"name": "room_a", "seed": 11, "split": "dev", "dir": "scenes/room_a"},
            {"name": "room_b", "seed": 12, "split": "val", "dir": "scenes/room_b"}]}"#,
    )
    .unwrap();
}

fn read_json(p: &Path) -> Value {
    let text = std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    serde_json::from_str(&text).unwrap()
}

fn num(v: &Value) -> f64 {
    v.as_f64()
        .unwrap_or_else(|| panic!("{v} is not a finite number"))
}

use lumiprobe::eval::METRIC_NAMES as METRICS;

const LABELS: [&str; 4] = ["warp", "fusion", "baseline:nearest-probe", "baseline:sdr"];

#[test]
fn corpus_rows_and_totals_match_eval_and_a_rerun_resumes() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("corpus");
    let out = tmp.path().join("out");
    corpus(&root);
    let args = [
        "corpus",
        root.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--methods",
        "warp,fusion",
        "--size",
        "128x64",
    ];
    let text = ok(&lumiprobe(&args));
    for f in [
        "corpus.txt",
        "corpus.csv",
        "corpus.json",
        "corpus_worst_irradiance.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    assert_eq!(
        std::fs::read_to_string(out.join("corpus.txt")).unwrap(),
        text
    );
    assert!(
        text.contains("irr_worst") && text.contains("flicker_worst"),
        "{text}"
    );
    let png = lumiprobe::image::io::read_sdr(&out.join("corpus_worst_irradiance.png")).unwrap();
    assert!(png.width() >= 640);

    let report = read_json(&out.join("corpus.json"));
    assert_eq!(report["roots"][0]["generator_version"], "test-1");
    let rows = report["rows"].as_array().unwrap();
    // Every row, and every row again over the answerable frames.
    assert_eq!(rows.len(), 2 * 2 * LABELS.len());
    let totals = report["totals"].as_array().unwrap();
    assert_eq!(totals.len(), 2 * 2 * LABELS.len());

    let csv = std::fs::read_to_string(out.join("corpus.csv")).unwrap();
    let mut lines = csv.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| head.iter().position(|h| *h == name).unwrap();
    let csv_rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(csv_rows.len(), rows.len() + totals.len());

    for (scene, split) in [("room_a", "dev"), ("room_b", "val")] {
        let scene_dir = root.join("scenes").join(scene);
        let warp = format!("warp={}", out.join(scene).join("warp").display());
        let fusion = format!("fusion={}", out.join(scene).join("fusion").display());
        // `eval` of both outputs, with `extra` arguments.
        let eval = |extra: &[&str]| {
            let mut args = vec!["eval", scene_dir.to_str().unwrap(), "--pred", &warp];
            args.extend_from_slice(&["--pred", &fusion]);
            args.extend_from_slice(extra);
            ok(&lumiprobe(&args))
        };
        let ev: Value = serde_json::from_str(&eval(&["--json"])).unwrap();
        let eval_rows = ev["table"]["rows"].as_array().unwrap();
        // The one-page report: the table's rows, the plot, and a contact
        // sheet of the truth and both predictions per frame, as PNGs that
        // exist and are not blank.
        let rep = out.join(format!("report_{scene}"));
        eval(&["--report", rep.to_str().unwrap()]);
        let html = std::fs::read_to_string(rep.join("report.html")).unwrap();
        for label in ["warp", "fusion", "baseline:sdr", "error_vs_distance.png"] {
            assert!(html.contains(label), "{label} missing from report.html");
        }
        assert!(rep.join("error_vs_distance.png").is_file());
        let thumbs: Vec<&str> = html
            .split("src=\"contact/")
            .skip(1)
            .map(|t| t.split('"').next().unwrap())
            .collect();
        assert_eq!(thumbs.len(), 4 * 3, "4 frames x (truth, warp, fusion)");
        for t in &thumbs {
            let img = lumiprobe::image::io::read_sdr(&rep.join("contact").join(t)).unwrap();
            let (lo, hi) = img
                .data()
                .iter()
                .fold((255u8, 0u8), |(a, b), &v| (a.min(v), b.max(v)));
            assert!(hi > lo + 20, "{t} is blank");
        }
        for label in LABELS {
            let row = rows
                .iter()
                .find(|r| r["scene"] == scene && r["method"] == label)
                .unwrap_or_else(|| panic!("no row {scene} {label}"));
            assert_eq!(row["split"], split);
            assert!(row["error"].is_null(), "{row}");
            assert_eq!(row["frames"], 4);
            let tail = &row["tail"];
            let want = &eval_rows.iter().find(|r| r["label"] == label).unwrap()["tail"];
            // The same numbers as a separate `eval` of the same outputs.
            assert_eq!(tail, want, "{scene} {label}");
            for m in METRICS {
                for s in ["mean", "p95", "worst"] {
                    assert!(
                        num(&tail["metrics"][m][s]).is_finite(),
                        "{scene} {label} {m} {s}"
                    );
                }
                assert!(tail["metrics"][m]["worst_frame"].is_string());
            }
            assert!(num(&tail["flicker"]["mean"]) >= 0.0);
            assert_eq!(tail["flicker"]["pairs"], 3);
            let over = tail["frames_over_sdr_irr"].as_u64().unwrap();
            assert!(over <= 4 && tail["frames_over_sdr_irr_margin"].as_u64().unwrap() <= over);
            if label == "baseline:sdr" {
                assert_eq!(over, 0);
            }
            // The CSV holds the same numbers.
            let line = csv_rows
                .iter()
                .find(|l| l[0] == "scene" && l[2] == scene && l[3] == label)
                .unwrap();
            assert_eq!(line[col("status")], "ok");
            let cell: f64 = line[col("irradiance_rel_err_worst")].parse().unwrap();
            assert_eq!(cell, num(&tail["metrics"]["irradiance_rel_err"]["worst"]));
            let cell: f64 = line[col("psnr_tm_p95")].parse().unwrap();
            assert_eq!(cell, num(&tail["metrics"]["psnr_tm"]["p95"]));
            // One scene per split: the totals are that scene's figures.
            let total = totals
                .iter()
                .find(|t| t["split"] == split && t["method"] == label)
                .unwrap();
            assert_eq!(total["scenes"], 1);
            assert_eq!(total["failed"], 0);
            let (tm, sm) = (
                &total["tail"]["metrics"]["irradiance_rel_err"],
                &tail["metrics"]["irradiance_rel_err"],
            );
            assert_eq!(num(&tm["mean"]), num(&sm["mean"]));
            assert_eq!(num(&tm["p95"]), num(&sm["p95"]));
            assert_eq!(
                tm["worst_frame"].as_str().unwrap(),
                format!("{scene}/{}", sm["worst_frame"].as_str().unwrap())
            );
            let line = csv_rows
                .iter()
                .find(|l| l[0] == "total" && l[1] == split && l[3] == label)
                .unwrap();
            assert_eq!(line[col("scenes")], "1");
            // The same row over the frames the summary does not flag: room_a's
            // frame_001 left out, room_b's row unchanged.
            let apart = format!("{label}@answerable");
            let row_a = rows
                .iter()
                .find(|r| r["scene"] == scene && r["method"] == apart.as_str())
                .unwrap_or_else(|| panic!("no row {scene} {apart}"));
            let irr: Vec<f64> = ev["frames"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|f| scene == "room_b" || f["id"] != "frame_001")
                .map(|f| {
                    let s = f["scores"].as_array().unwrap();
                    let m = s.iter().find(|x| x[0] == label).unwrap();
                    num(&m[1]["irradiance_rel_err"])
                })
                .collect();
            assert_eq!(row_a["frames"], irr.len());
            let mean = irr.iter().sum::<f64>() / irr.len() as f64;
            let got = num(&row_a["tail"]["metrics"]["irradiance_rel_err"]["mean"]);
            assert!(
                (got - mean).abs() < 1e-9,
                "{scene} {apart}: {got} vs {mean}"
            );
            if scene == "room_b" {
                assert_eq!(row_a["tail"], *tail);
            } else {
                assert_eq!(row_a["tail"]["flicker"]["pairs"], 2);
                for m in METRICS {
                    assert_ne!(row_a["tail"]["metrics"][m]["worst_frame"], "frame_001");
                }
            }
        }
    }

    // A rerun keeps every frame and reports the same rows.
    ok(&lumiprobe(&args));
    for scene in ["room_a", "room_b"] {
        for m in ["warp", "fusion"] {
            let r = read_json(&out.join(scene).join(m).join("report.json"));
            assert_eq!(r["resumed"].as_array().unwrap().len(), 4, "{scene} {m}");
        }
    }
    assert_eq!(read_json(&out.join("corpus.json"))["rows"], report["rows"]);
}

#[test]
fn a_failing_scene_is_a_failed_row_and_bad_roots_are_one_line_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("corpus");
    let out = tmp.path().join("out");
    corpus(&root);
    // room_b's second frame is not an image: its run and evaluation fail.
    let broken = root.join("scenes/room_b/path/frame_001.jpg");
    assert!(broken.is_file(), "{} missing", broken.display());
    std::fs::write(&broken, b"not a jpeg").unwrap();
    let r = lumiprobe(&[
        "corpus",
        root.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--methods",
        "warp",
        "--size",
        "128x64",
    ]);
    assert!(!r.status.success(), "a failed scene must fail the command");
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("rows failed"), "{err}");
    let report = read_json(&out.join("corpus.json"));
    let rows = report["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 12);
    for row in rows {
        let failed = row["scene"] == "room_b";
        assert_eq!(row["error"].is_string(), failed, "{row}");
        if failed {
            let e = row["error"].as_str().unwrap();
            assert!(e.contains("frame_001.jpg"), "{e}");
        } else {
            assert!(num(&row["tail"]["metrics"]["irradiance_rel_err"]["worst"]).is_finite());
        }
    }
    let text = std::fs::read_to_string(out.join("corpus.txt")).unwrap();
    assert!(text.contains("failed: room_b warp: run:"), "{text}");
    let val_warp = report["totals"]
        .as_array()
        .unwrap()
        .iter()
        .find(|t| t["split"] == "val" && t["method"] == "warp")
        .unwrap();
    assert_eq!(
        (val_warp["scenes"].as_u64(), val_warp["failed"].as_u64()),
        (Some(0), Some(1))
    );

    // A folder with neither a corpus.json nor scene folders.
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let r = lumiprobe(&[
        "corpus",
        empty.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("empty") && err.contains("no corpus.json"),
        "{err}"
    );
    // A scene folder whose poses.json is invalid: nothing runs.
    let scenes = tmp.path().join("scenes");
    std::fs::create_dir_all(scenes.join("bad")).unwrap();
    std::fs::write(scenes.join("bad/poses.json"), "{\"probes\": 3}").unwrap();
    let out2 = tmp.path().join("out2");
    let r = lumiprobe(&[
        "corpus",
        scenes.to_str().unwrap(),
        "--out",
        out2.to_str().unwrap(),
    ]);
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("bad/poses.json"), "{err}");
    assert!(
        !out2.exists(),
        "nothing is written for a bad scene description"
    );
    // A scene summary that does not say which frames are unanswerable in the
    // form the generator writes: nothing runs.
    std::fs::write(
        root.join("scenes/room_a/summary.json"),
        r#"{"unanswerable_frames": [true]}"#,
    )
    .unwrap();
    let out3 = tmp.path().join("out3");
    let r = lumiprobe(&[
        "corpus",
        root.to_str().unwrap(),
        "--out",
        out3.to_str().unwrap(),
    ]);
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("room_a/summary.json"), "{err}");
    assert!(!out3.exists(), "nothing is written for a bad scene summary");
}
