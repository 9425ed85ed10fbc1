//! End-to-end: a synthetic scene through `run`, resume and `eval`.

use lumiprobe::pipeline::evaluate::{evaluate, BASELINE_PROBE};
use lumiprobe::pipeline::{run, RunParams};
use lumiprobe::scene::Scene;
use lumiprobe::synth::{synthesize, SynthParams};
use std::path::Path;

fn scene(dir: &Path) -> Scene {
    let p = SynthParams {
        width: 256,
        n_frames: 4,
        n_probes: 2,
        seed: 5,
        name: "t".into(),
        ..Default::default()
    };
    synthesize(&p).write(dir).unwrap();
    Scene::load(dir).unwrap()
}

fn run_in_pool(threads: usize, scene: &Scene, out: &Path) -> lumiprobe::pipeline::RunReport {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| run(scene, out, &RunParams::default(), &|_, _| {}))
        .unwrap()
}

#[test]
fn outputs_are_identical_whatever_the_thread_count_and_rerun_resumes() {
    let tmp = tempfile::tempdir().unwrap();
    let s = scene(&tmp.path().join("scene"));
    let a = tmp.path().join("a");
    let b = tmp.path().join("b");
    let ra = run_in_pool(1, &s, &a);
    run_in_pool(2, &s, &b);
    assert!(ra.resumed.is_empty());
    for f in &s.frames {
        let fa = std::fs::read(a.join(format!("{}.exr", f.id))).unwrap();
        let fb = std::fs::read(b.join(format!("{}.exr", f.id))).unwrap();
        assert!(fa == fb, "{} differs between 1 and 2 threads", f.id);
    }
    // A rerun does no work; deleting one output recomputes only that frame.
    let again = run_in_pool(2, &s, &a);
    assert_eq!(again.resumed.len(), s.frames.len());
    let victim = a.join(format!("{}.exr", s.frames[1].id));
    let before = std::fs::read(&victim).unwrap();
    std::fs::remove_file(&victim).unwrap();
    let third = run_in_pool(2, &s, &a);
    assert_eq!(third.resumed.len(), s.frames.len() - 1);
    assert_eq!(std::fs::read(&victim).unwrap(), before);
    // No temporary files are left behind.
    for e in std::fs::read_dir(&a).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!name.ends_with(".tmp"), "left {name}");
    }
}

#[test]
fn warp_beats_the_nearest_probe_on_a_synthetic_walk() {
    let tmp = tempfile::tempdir().unwrap();
    let p = SynthParams {
        width: 512,
        n_frames: 4,
        n_probes: 3,
        seed: 2,
        name: "t".into(),
        ..Default::default()
    };
    let dir = tmp.path().join("scene");
    synthesize(&p).write(&dir).unwrap();
    let s = Scene::load(&dir).unwrap();
    let out = tmp.path().join("warp");
    let rep = run(&s, &out, &RunParams::default(), &|_, _| {}).unwrap();
    let used: usize = rep
        .frames
        .iter()
        .filter_map(|f| f.warp.as_ref())
        .map(|w| w.faces.iter().filter(|x| x.source == "homography").count())
        .sum();
    assert!(used > 0, "no face used a homography");
    let ev = evaluate(&s, &[("warp".into(), out.as_path())]).unwrap();
    let row = |l: &str| {
        ev.table
            .rows
            .iter()
            .find(|r| r.label == l)
            .unwrap()
            .mean
            .unwrap()
    };
    let (w, b) = (row("warp"), row(BASELINE_PROBE));
    assert!(w.psnr_tm > b.psnr_tm, "psnr {} vs {}", w.psnr_tm, b.psnr_tm);
    assert!(
        w.log_lum_rmse < b.log_lum_rmse,
        "rmse {} vs {}",
        w.log_lum_rmse,
        b.log_lum_rmse
    );
    assert_eq!(w.invalid_pixels, 0);
}

#[test]
fn missing_inputs_are_named_in_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("scene");
    let s = scene(&dir);
    std::fs::remove_file(&s.frames[0].sdr).unwrap();
    let err = run(&s, &tmp.path().join("o"), &RunParams::default(), &|_, _| {})
        .unwrap_err()
        .to_string();
    assert!(
        err.contains(&s.frames[0].sdr.display().to_string()),
        "{err}"
    );
    let err = Scene::load(&tmp.path().join("nowhere"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("poses.json"), "{err}");
}

#[test]
fn probes_are_resampled_down_to_a_working_size_but_never_up() {
    let tmp = tempfile::tempdir().unwrap();
    let s = scene(&tmp.path().join("scene"));
    let (native, _) = lumiprobe::pipeline::load_probe(&s, 0, None).unwrap();
    let (w, h) = (native.width(), native.height());
    // A working size larger than the probe keeps the probe's own pixels.
    let (up, _) = lumiprobe::pipeline::load_probe(&s, 0, Some((4 * w, 4 * h))).unwrap();
    assert_eq!((up.width(), up.height()), (w, h));
    assert_eq!(up.data(), native.data());
    // A smaller one resamples it down.
    let (down, _) = lumiprobe::pipeline::load_probe(&s, 0, Some((w / 2, h / 2))).unwrap();
    assert_eq!((down.width(), down.height()), (w / 2, h / 2));
    // A run at twice the probes' size reads them at their own size, writes
    // every frame at the size asked for, and has nothing to note about sizes.
    let out = tmp.path().join("big");
    let params = RunParams {
        method: lumiprobe::pipeline::Method::Fusion,
        size: Some((2 * w, 2 * h)),
        ..RunParams::default()
    };
    let rep = run(&s, &out, &params, &|_, _| {}).unwrap();
    assert_eq!(rep.frames.len(), s.frames.len());
    assert!(
        !rep.warnings.iter().any(|w| w.contains("its probe is")),
        "{:?}",
        rep.warnings
    );
    for f in &s.frames {
        let img = lumiprobe::image::io::read_hdr(&out.join(format!("{}.exr", f.id))).unwrap();
        assert_eq!((img.width(), img.height()), (2 * w, 2 * h));
        assert_eq!(img.count_invalid(), 0);
    }
}

#[test]
fn a_memory_limit_runs_fewer_frames_at_once_with_the_same_outputs() {
    let tmp = tempfile::tempdir().unwrap();
    let s = scene(&tmp.path().join("scene"));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let with = |limit: Option<u64>, out: &Path| {
        let params = RunParams {
            method: lumiprobe::pipeline::Method::Fusion,
            memory_limit: limit,
            ..RunParams::default()
        };
        pool.install(|| run(&s, out, &params, &|_, _| {})).unwrap()
    };
    let (free, tight) = (tmp.path().join("free"), tmp.path().join("tight"));
    let r = with(Some(1 << 40), &free);
    assert!(
        !r.warnings.iter().any(|w| w.contains("memory limit")),
        "{:?}",
        r.warnings
    );
    // A limit no frame fits: one frame at a time, said in the report.
    let r = with(Some(1), &tight);
    assert!(
        r.warnings
            .iter()
            .any(|w| w.contains("memory limit") && w.contains("--size")),
        "{:?}",
        r.warnings
    );
    for f in &s.frames {
        let name = format!("{}.exr", f.id);
        let a = std::fs::read(free.join(&name)).unwrap();
        let b = std::fs::read(tight.join(&name)).unwrap();
        assert!(a == b, "{} differs under the memory limit", f.id);
    }
}
