//! Crash safety and sharding: a run killed at any moment leaves only complete
//! files and the rerun finishes byte-identical to an uninterrupted run; shards
//! writing into one folder give exactly the outputs of one run.

use lumiprobe::synth::{synthesize, SynthParams};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// Frames of the walk killed mid-run: enough that a run lasts well beyond the
/// polling interval.
const N: usize = 16;

fn scene(dir: &Path, frames: usize) -> PathBuf {
    let p = SynthParams {
        width: 256,
        n_frames: frames,
        n_probes: 3,
        seed: 11,
        name: "crash".into(),
        ..Default::default()
    };
    let d = dir.join("scene");
    synthesize(&p).write(&d).unwrap();
    d
}

fn lumiprobe(args: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_lumiprobe"));
    c.args(["-q", "--threads", "1"]).args(args);
    c
}

/// The frame outputs of a folder: name -> bytes (EXR probes only: sidecars hold
/// timings, which differ from run to run).
fn outputs(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "exr"))
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

#[test]
fn a_killed_run_leaves_complete_files_and_resumes_to_identical_results() {
    let tmp = tempfile::tempdir().unwrap();
    let sc = scene(tmp.path(), N);
    let (sc_s, full, cut) = (
        sc.to_str().unwrap(),
        tmp.path().join("full"),
        tmp.path().join("cut"),
    );
    let st = lumiprobe(&[
        "run",
        sc_s,
        "--out",
        full.to_str().unwrap(),
        "--method",
        "warp",
    ])
    .status()
    .unwrap();
    assert!(st.success());
    let want = outputs(&full);
    assert_eq!(want.len(), N);

    // Kill as soon as the first output appears (mid-run), a few times over.
    let mut killed_mid_run = false;
    for _attempt in 0..5 {
        let _ = std::fs::remove_dir_all(&cut);
        let mut child = lumiprobe(&[
            "run",
            sc_s,
            "--out",
            cut.to_str().unwrap(),
            "--method",
            "warp",
        ])
        .spawn()
        .unwrap();
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_secs(60) {
            if child.try_wait().unwrap().is_some() {
                break;
            }
            if cut.exists() && !outputs(&cut).is_empty() {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        let finished = child.try_wait().unwrap().is_some();
        let _ = child.kill();
        let _ = child.wait();
        if finished || !cut.exists() {
            continue;
        }
        // Whatever has a final name is complete: every EXR decodes to the same
        // bytes as the uninterrupted run's, every sidecar parses.
        for (name, bytes) in outputs(&cut) {
            let reference = &want.iter().find(|(n, _)| *n == name).unwrap().1;
            assert_eq!(&bytes, reference, "{name} is incomplete or different");
        }
        for e in std::fs::read_dir(&cut).unwrap().flatten() {
            let p = e.path();
            if p.extension().is_some_and(|x| x == "json") {
                let text = std::fs::read_to_string(&p).unwrap();
                serde_json::from_str::<serde_json::Value>(&text).unwrap();
            }
        }
        let done = outputs(&cut).len();
        killed_mid_run |= done < N;
        // The rerun resumes and ends identical, with no temporary file left.
        let st = lumiprobe(&[
            "run",
            sc_s,
            "--out",
            cut.to_str().unwrap(),
            "--method",
            "warp",
        ])
        .status()
        .unwrap();
        assert!(st.success());
        assert_eq!(outputs(&cut), want);
        let stray: Vec<String> = std::fs::read_dir(&cut)
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".tmp"))
            .collect();
        assert!(stray.is_empty(), "{stray:?}");
        if killed_mid_run {
            break;
        }
    }
    assert!(
        killed_mid_run,
        "no kill landed while frames were being written"
    );
}

#[test]
fn shards_into_one_folder_equal_one_run() {
    let tmp = tempfile::tempdir().unwrap();
    let sc = scene(tmp.path(), 5);
    let sc_s = sc.to_str().unwrap();
    let (one, sharded) = (tmp.path().join("one"), tmp.path().join("sharded"));
    assert!(lumiprobe(&[
        "run",
        sc_s,
        "--out",
        one.to_str().unwrap(),
        "--method",
        "warp"
    ])
    .status()
    .unwrap()
    .success());
    for s in ["0/2", "1/2"] {
        assert!(lumiprobe(&[
            "run",
            sc_s,
            "--out",
            sharded.to_str().unwrap(),
            "--method",
            "warp",
            "--shard",
            s
        ])
        .status()
        .unwrap()
        .success());
    }
    assert_eq!(outputs(&one), outputs(&sharded));
    assert!(sharded.join("report.shard-0-of-2.json").exists());
    assert!(sharded.join("report.shard-1-of-2.json").exists());
    let bad = lumiprobe(&["run", sc_s, "--out", "x", "--shard", "2/2"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("2/2"));
}

#[test]
fn shards_then_one_run_equal_one_run_with_the_walk_as_a_sequence() {
    let tmp = tempfile::tempdir().unwrap();
    let sc = scene(tmp.path(), 5);
    let sc_s = sc.to_str().unwrap();
    let (one, sharded) = (tmp.path().join("one"), tmp.path().join("sharded"));
    let walk = ["--method", "fusion", "--set", "fusion.walk.mode=two_sided"];
    let run = |out: &std::path::Path, extra: &[&str]| {
        let mut args = vec!["run", sc_s, "--out", out.to_str().unwrap()];
        args.extend_from_slice(&walk);
        args.extend_from_slice(extra);
        let o = lumiprobe(&args).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    run(&one, &[]);
    for s in ["0/2", "1/2"] {
        run(&sharded, &["--shard", s]);
    }
    let shard_report = std::fs::read_to_string(sharded.join("report.shard-0-of-2.json")).unwrap();
    assert!(shard_report.contains("without --shard"), "{shard_report}");
    run(&sharded, &[]);
    assert_eq!(outputs(&one), outputs(&sharded));
    // The final run fused nothing it did not hold.
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(sharded.join("report.json")).unwrap())
            .unwrap();
    let frames = report["frames"].as_array().unwrap();
    let held = frames
        .iter()
        .filter(|f| {
            f["fusion"]["ledger"]
                .as_array()
                .is_some_and(|l| l.iter().any(|e| e.get("walk").is_some()))
        })
        .count();
    assert_eq!(
        report["resumed"].as_array().unwrap().len() + held,
        frames.len()
    );
}

#[test]
fn a_rerun_resumes_however_the_scene_path_is_spelled() {
    let tmp = tempfile::tempdir().unwrap();
    let sc = scene(tmp.path(), 3);
    let rel = sc.strip_prefix(tmp.path()).unwrap().to_path_buf();
    let out = tmp.path().join("out");
    let run = |scene_arg: &Path, cwd: &Path| {
        let o = Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
            .current_dir(cwd)
            .args(["-q", "run"])
            .arg(scene_arg)
            .arg("--out")
            .arg(&out)
            .args(["--method", "warp"])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let r: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap())
                .unwrap();
        r["resumed"].as_array().unwrap().len()
    };
    assert_eq!(run(&rel, tmp.path()), 0);
    // Absolute, and relative from another folder: every frame resumed.
    assert_eq!(run(&sc, Path::new("/")), 3);
    let sub = tmp.path().join("elsewhere");
    std::fs::create_dir_all(&sub).unwrap();
    assert_eq!(run(&Path::new("..").join(&rel), &sub), 3);
}
