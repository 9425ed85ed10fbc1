//! A manifest run end to end on a synthetic capture: probes given only as
//! brackets, the response recovered, the gain calibrated; the second run does no
//! work; touching one input recomputes only what depends on it.

use lumiprobe::pipeline::plan::{prepare, StageState};
use lumiprobe::pipeline::{pending_frames, run, Method, RunParams};
use lumiprobe::scene::manifest::Manifest;
use lumiprobe::synth::{synthesize, SynthParams};
use std::path::Path;

fn states(plan: &lumiprobe::pipeline::plan::Plan) -> Vec<(String, StageState)> {
    plan.stages
        .iter()
        .map(|s| (s.name.clone(), s.state))
        .collect()
}

fn touch(p: &Path) {
    let f = std::fs::OpenOptions::new().append(true).open(p).unwrap();
    let t = std::fs::metadata(p).unwrap().modified().unwrap() + std::time::Duration::from_secs(5);
    f.set_modified(t).unwrap();
}

#[test]
fn a_bracket_only_manifest_runs_caches_and_recomputes_only_what_changed() {
    let tmp = tempfile::tempdir().unwrap();
    let mf = bracket_capture(tmp.path(), 128, 5, 3);
    write_draft(&mf, "warp");
    let text = std::fs::read_to_string(&mf).unwrap();
    assert!(text.contains("brackets = "), "{text}");
    let m = Manifest::load(&mf).unwrap();

    let params = RunParams {
        method: Method::Warp,
        ..Default::default()
    };
    let (scene, plan) = prepare(&m, false).unwrap();
    let scene = scene.expect("scene");
    let st = states(&plan);
    assert!(
        st.contains(&("recover response".into(), StageState::Computed)),
        "{st:?}"
    );
    assert_eq!(
        st.iter()
            .filter(|(n, s)| n.starts_with("merge") && *s == StageState::Computed)
            .count(),
        2
    );
    assert!((scene.path_gain / 1.0).is_finite() && scene.path_gain > 0.0);
    let rep = run(&scene, &m.output.folder, &params, &|_, _| {}).unwrap();
    assert_eq!(rep.frames.len(), 3);
    assert!(rep.resumed.is_empty());

    // Second time: everything cached, no frame to compute.
    let (scene2, plan2) = prepare(&m, false).unwrap();
    let scene2 = scene2.unwrap();
    for (name, s) in states(&plan2) {
        if name.starts_with("merge") || name == "recover response" {
            assert_eq!(s, StageState::Cached, "{name}");
        }
    }
    assert!(pending_frames(&scene2, &m.output.folder, &params)
        .unwrap()
        .is_empty());
    let rep2 = run(&scene2, &m.output.folder, &params, &|_, _| {}).unwrap();
    assert_eq!(rep2.resumed.len(), 3);

    // Touch one bracket of the probe that is not the response's source: only
    // that probe is merged again, and only frames that use it are recomputed.
    let source = plan2
        .stages
        .iter()
        .find(|s| s.name == "recover response")
        .unwrap();
    assert_eq!(source.state, StageState::Cached);
    // The source is the probe with most brackets (the last on ties): touch another.
    let other = m
        .probes
        .iter()
        .find(|p| p.id != m.probes.last().unwrap().id)
        .unwrap();
    touch(&other.brackets[0]);
    let (scene3, plan3) = prepare(&m, false).unwrap();
    let scene3 = scene3.unwrap();
    for (name, s) in states(&plan3) {
        if name == format!("merge {}", other.id) {
            assert_eq!(s, StageState::Computed, "{name}");
        } else if name.starts_with("merge") || name == "recover response" {
            assert_eq!(s, StageState::Cached, "{name}");
        }
    }
    let pending = pending_frames(&scene3, &m.output.folder, &params).unwrap();
    let users: Vec<String> = scene3
        .frames
        .iter()
        .filter(|f| scene3.probes[scene3.nearest_probe(f.pose.position)].id == other.id)
        .map(|f| f.id.clone())
        .collect();
    // A new gain moves every frame; with the same gain only the users change.
    if (scene3.path_gain - scene2.path_gain).abs() < 1e-7 {
        assert_eq!(pending, users);
    } else {
        assert_eq!(pending.len(), 3);
    }
}

#[test]
fn a_manifest_without_poses_plans_localization() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("capture");
    let p = SynthParams {
        width: 64,
        n_frames: 2,
        n_probes: 2,
        seed: 6,
        name: "m".into(),
        brackets: false,
        ..Default::default()
    };
    synthesize(&p).write(&dir).unwrap();
    let text = Manifest::draft(&dir)
        .unwrap()
        .replace("[poses]\nfile = \"poses.json\"", "");
    let mf = dir.join("lumiprobe.toml");
    std::fs::write(&mf, text).unwrap();
    let m = Manifest::load(&mf).unwrap();
    // Without poses the plan localizes (COLMAP); a dry run only says so.
    let (scene, plan) = prepare(&m, true).unwrap();
    assert!(scene.is_none());
    let st = plan.stages.iter().find(|s| s.name == "localize").unwrap();
    assert_eq!(st.state, StageState::Computed);
    assert!(
        !m.output.folder.join("cache").exists(),
        "a dry run writes nothing"
    );
}

/// Runs the lumiprobe binary, returning its stdout; fails on a non-zero exit.
fn cli(args: &[&str]) -> String {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args(args)
        .output()
        .expect("the lumiprobe binary runs");
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A synthetic capture (HDR probes and their brackets); returns the path its
/// manifest is to have.
fn capture(root: &Path, width: usize, seed: u64, n_frames: usize) -> std::path::PathBuf {
    let dir = root.join("capture");
    let p = SynthParams {
        width,
        n_frames,
        n_probes: 2,
        seed,
        name: "m".into(),
        ..Default::default()
    };
    synthesize(&p).write(&dir).unwrap();
    dir.join("lumiprobe.toml")
}

/// A synthetic capture as a camera gives it (the probes' HDR files removed:
/// brackets only); returns the path its manifest is to have.
fn bracket_capture(root: &Path, width: usize, seed: u64, n_frames: usize) -> std::path::PathBuf {
    let mf = capture(root, width, seed, n_frames);
    for e in std::fs::read_dir(mf.parent().unwrap().join("probes")).unwrap() {
        let path = e.unwrap().path();
        if path.extension().is_some_and(|x| x == "exr") {
            std::fs::remove_file(path).unwrap();
        }
    }
    mf
}

/// The bracket folder of the capture's first probe (by name).
fn first_bracket(mf: &Path) -> std::path::PathBuf {
    std::fs::read_dir(mf.parent().unwrap().join("probes"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_dir())
        .min()
        .unwrap()
}

/// The photos of a bracket folder, sorted by name.
fn photos_in(folder: &Path) -> Vec<std::path::PathBuf> {
    let mut photos: Vec<_> = std::fs::read_dir(folder)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .collect();
    photos.sort();
    photos
}

/// Drafts the capture's manifest with `method`.
fn write_draft(mf: &Path, method: &str) {
    let dir = mf.parent().unwrap();
    let text = Manifest::draft(dir)
        .unwrap()
        .replace("method = \"fusion\"", &format!("method = \"{method}\""));
    std::fs::write(mf, text).unwrap();
}

#[test]
fn a_dry_run_quiet_run_and_resumed_rerun_say_what_happened() {
    let tmp = tempfile::tempdir().unwrap();
    let mf = bracket_capture(tmp.path(), 64, 7, 3);
    write_draft(&mf, "warp");
    let mf = mf.to_str().unwrap();
    // Merges pending: the dry run still says how many frames are to compute.
    let dry = cli(&["run", mf, "--dry-run"]);
    assert!(dry.contains("once the probes are merged"), "{dry}");
    assert!(dry.contains("all 3"), "{dry}");
    // Quiet: no plan, no summary.
    let quiet = cli(&["-q", "run", mf]);
    assert!(quiet.trim().is_empty(), "{quiet}");
    // Everything resumed: no time per frame is claimed.
    let again = cli(&["run", mf]);
    assert!(again.contains("3 resumed, all up to date"), "{again}");
    assert!(!again.contains("ms per frame"), "{again}");
    // The other commands that take a scene take the manifest alike (its merged
    // probes from the cache, its gain).
    let m = Manifest::load(std::path::Path::new(mf)).unwrap();
    let pred = m.output.folder.to_str().unwrap().to_string();
    // A capture has no ground truth: eval reads the manifest and says so.
    let ev = std::process::Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args(["-q", "eval", mf, "--pred", &pred])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&ev.stderr);
    assert!(
        !ev.status.success() && err.contains("no frame with ground truth"),
        "{err}"
    );
    let bench = cli(&[
        "-q",
        "bench",
        mf,
        "--repeats",
        "1",
        "--method",
        "warp",
        "--json",
    ]);
    assert!(!bench.trim().is_empty());
    cli(&["-q", "calibrate", mf]);
}

#[test]
fn a_probe_of_one_exposure_is_warned_about() {
    let tmp = tempfile::tempdir().unwrap();
    let mf = bracket_capture(tmp.path(), 64, 8, 2);
    // The first probe keeps one photo of its bracket.
    let first = first_bracket(&mf);
    // (its photos, and the wide bracket beside them when there is one)
    for folder in [first.clone(), first.join("wide")] {
        if !folder.is_dir() {
            continue;
        }
        let photos = photos_in(&folder);
        assert!(photos.len() > 1);
        for ph in &photos[1..] {
            std::fs::remove_file(ph).unwrap();
        }
    }
    write_draft(&mf, "warp");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args(["-q", "run", mf.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let id = first.file_name().unwrap().to_string_lossy();
    assert!(err.contains(&format!("probe {id}: one exposure")), "{err}");
}

#[test]
fn a_drafted_manifest_for_hdr_probes_with_brackets_beside_them_runs() {
    // The probes' HDR files are kept: their brackets are commented out in the
    // draft, so the response cannot be recovered from them.
    let tmp = tempfile::tempdir().unwrap();
    let mf = capture(tmp.path(), 64, 9, 2);
    let text = Manifest::draft(mf.parent().unwrap()).unwrap();
    assert!(text.contains("# brackets = "), "{text}");
    assert!(!text.contains("response = \"recover\""), "{text}");
    std::fs::write(&mf, text).unwrap();
    let m = Manifest::load(&mf).unwrap();
    let (scene, _) = prepare(&m, false).unwrap();
    assert_eq!(scene.unwrap().probes.len(), 2);
}

#[test]
fn the_gain_is_cached_and_cache_gc_removes_only_what_the_manifest_no_longer_uses() {
    let tmp = tempfile::tempdir().unwrap();
    let mf = bracket_capture(tmp.path(), 64, 9, 2);
    write_draft(&mf, "warp");
    let m = Manifest::load(&mf).unwrap();
    let (scene, first) = prepare(&m, false).unwrap();
    let gain = scene.unwrap().path_gain;
    let state = |plan: &lumiprobe::pipeline::plan::Plan, name: &str| {
        plan.stages
            .iter()
            .find(|s| s.name == name)
            .unwrap_or_else(|| panic!("no stage {name}: {}", plan.to_text()))
            .state
    };
    assert_eq!(state(&first, "calibrate gain"), StageState::Computed);
    // The second preparation reads the gain instead of calibrating again.
    let (scene, second) = prepare(&m, false).unwrap();
    assert_eq!(state(&second, "calibrate gain"), StageState::Cached);
    assert_eq!(scene.unwrap().path_gain, gain);
    // Stale entries: an old merge, an old response, an old localization, an
    // interrupted write. What the plan uses stays.
    let cache = m.output.folder.join("cache");
    let merged = std::fs::read_dir(cache.join("probes"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .next()
        .unwrap();
    let stale = [
        cache.join("probes").join("probe_00-0123456789abcdef.exr"),
        cache.join("response-0123456789abcdef.json"),
        cache.join("localize-0123456789abcdef"),
        cache.join("gain-0123456789abcdef.json.tmp"),
    ];
    std::fs::copy(&merged, &stale[0]).unwrap();
    std::fs::write(&stale[1], "{}").unwrap();
    std::fs::create_dir_all(&stale[2]).unwrap();
    std::fs::write(stale[2].join("poses.json"), "[]").unwrap();
    std::fs::write(&stale[3], "{").unwrap();
    let mf_s = mf.to_str().unwrap();
    // A dry run lists them and removes nothing.
    let listed = std::process::Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args(["cache", "gc", mf_s, "--dry-run"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&listed.stderr);
    assert!(listed.status.success(), "{err}");
    assert!(err.contains("would remove 4 entries"), "{err}");
    assert!(stale.iter().all(|p| p.exists()));
    let before: Vec<_> = first.live.clone();
    cli(&["-q", "cache", "gc", mf_s]);
    assert!(stale.iter().all(|p| !p.exists()));
    // Nothing the plan uses was touched: the next preparation computes nothing.
    assert!(
        before.iter().filter(|p| p.exists()).count() >= 3,
        "{before:?}"
    );
    let (_, after) = prepare(&m, true).unwrap();
    assert!(
        after.stages.iter().all(|s| s.state != StageState::Computed),
        "{}",
        after.to_text()
    );
}

#[test]
fn exposure_times_out_of_the_files_order_are_refused_with_the_order_shown() {
    let tmp = tempfile::tempdir().unwrap();
    let mf = bracket_capture(tmp.path(), 64, 10, 1);
    let photos = photos_in(&first_bracket(&mf));
    assert!(photos.len() >= 3);
    // Times that follow each photo's brightness are right; reversed, wrong.
    let mean = |p: &std::path::Path| {
        let img = lumiprobe::image::io::read_sdr(p).unwrap();
        img.data().iter().map(|&v| v as f64).sum::<f64>() / img.data().len() as f64
    };
    let means: Vec<f64> = photos.iter().map(|p| mean(p)).collect();
    let mut rank: Vec<usize> = (0..photos.len()).collect();
    rank.sort_by(|&a, &b| means[a].total_cmp(&means[b]));
    let mut right = vec![0.0; photos.len()];
    for (k, &i) in rank.iter().enumerate() {
        right[i] = 0.001 * 2f64.powi(k as i32);
    }
    let wrong: Vec<f64> = rank.iter().rev().map(|&i| right[i]).collect();
    let merge = |times: &[f64]| {
        let list: Vec<String> = times.iter().map(|t| t.to_string()).collect();
        let mut args: Vec<String> = vec!["merge".into()];
        args.extend(photos.iter().map(|p| p.to_string_lossy().into_owned()));
        args.extend(["--times".into(), list.join(","), "--out".into()]);
        args.push(tmp.path().join("m.exr").to_string_lossy().into_owned());
        std::process::Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
            .args(&args)
            .output()
            .unwrap()
    };
    let bad = merge(&wrong);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success(), "{err}");
    assert!(
        err.contains("must follow the files sorted by name"),
        "{err}"
    );
    assert!(!err.contains("panicked"));
    let good = merge(&right);
    assert!(
        good.status.success(),
        "{}",
        String::from_utf8_lossy(&good.stderr)
    );
}

#[path = "common/data.rs"]
mod data;

/// Kitchen as a camera gives it (bracket JPEGs of two probes, ten SDR
/// frames, the poses), run from a manifest with the `camera` settings given.
/// Returns the true probes' scale over the merged ones' (median luminance ratio), the
/// run's stated unit and the plan's text.
fn kitchen_from_brackets(root: &Path, response: &str, gain: &str) -> (f64, String, String) {
    let k = data::shared_file("scenes/kitchen");
    let mut text =
        format!("name = \"kitchen\"\n[camera]\nresponse = \"{response}\"\ngain = {gain}\n");
    for id in ["probe_00", "probe_01"] {
        text += &format!(
            "[[probe]]\nid = \"{id}\"\nbrackets = \"{}\"\n",
            k.join("probes").join(id).join("wide").display()
        );
    }
    text += &format!(
        "[frames]\nfolder = \"{}\"\npattern = \"frame_00*.jpg\"\n[poses]\nfile = \"{}\"\n\
         [output]\nfolder = \"{}\"\nmethod = \"warp\"\nsize = \"128x64\"\n",
        k.join("path").display(),
        k.join("poses.json").display(),
        root.join("out").display()
    );
    let mf = root.join("lumiprobe.toml");
    std::fs::write(&mf, text).unwrap();
    let m = Manifest::load(&mf).unwrap();
    let (scene, plan) = prepare(&m, false).unwrap();
    let scene = scene.expect("scene");
    let rep = run(&scene, &m.output.folder, &RunParams::default(), &|_, _| {}).unwrap();
    assert_eq!(rep.frames.len(), 10);
    // The merged probes against the true ones (the dataset's probe files, which
    // the manifest does not name): the median over pixels of the luminance
    // ratio, robust to the lamps the brackets clip.
    let truth = lumiprobe::scene::Scene::load(&k).unwrap();
    let mut ratios = Vec::new();
    for p in &scene.probes {
        let merged = lumiprobe::image::io::read_hdr(p.hdr.as_ref().unwrap()).unwrap();
        let t = truth.probes.iter().find(|q| q.id == p.id).unwrap();
        let want = lumiprobe::image::io::read_hdr(t.hdr.as_ref().unwrap()).unwrap();
        assert_eq!(
            (merged.width(), merged.height()),
            (want.width(), want.height())
        );
        for (a, b) in merged
            .data()
            .chunks_exact(3)
            .zip(want.data().chunks_exact(3))
        {
            let (la, lb) = (
                lumiprobe::image::luminance([a[0], a[1], a[2]]),
                lumiprobe::image::luminance([b[0], b[1], b[2]]),
            );
            if lb > 1e-3 && la > 0.0 {
                ratios.push(lb as f64 / la as f64);
            }
        }
    }
    ratios.sort_by(f64::total_cmp);
    let scale = ratios[ratios.len() / 2];
    let plan_text = plan.to_text();
    (scale, rep.probe_unit, plan_text)
}

#[test]
fn bracket_jpegs_come_out_at_the_documented_cameras_scale_or_in_candela() {
    // The documented response and gain (`camera` of poses.json): the probes are
    // tied to the frames' unit, which is the truth's.
    let tmp = tempfile::tempdir().unwrap();
    let (scale, unit, plan) =
        kitchen_from_brackets(tmp.path(), "documented", "0.33219081679437007");
    eprintln!("documented camera: true probes over merged {scale:.4}");
    assert!(
        (scale - 1.0).abs() < 0.1,
        "truth over output {scale}\n{plan}"
    );
    assert!(unit.contains("frames' unit"), "{unit}");
    // Gain left to calibration: luminance from the brackets' Exif (f/2.2,
    // ISO 100) by the meter equation. The documented camera exposes radiance
    // E to x = 0.332 E at 1/60 s, and the meter equation reads x as
    // 120 x 2.2² / (100 / 60) cd/m²: 115.7 cd/m² per unit of the truth.
    let tmp = tempfile::tempdir().unwrap();
    let (scale, unit, plan) = kitchen_from_brackets(tmp.path(), "documented", "\"auto\"");
    assert!(
        unit.contains("cd/m²") && unit.contains("f/2.2") && unit.contains("ISO 100"),
        "{unit}"
    );
    assert!(plan.contains("cd/m²"), "{plan}");
    let per_unit = 1.0 / scale;
    eprintln!("Exif: {per_unit:.2} cd/m² per truth unit");
    let want = 120.0 * 2.2 * 2.2 * 60.0 / 100.0 * 0.33219081679437007;
    assert!(
        (per_unit / want - 1.0).abs() < 0.1,
        "{per_unit} cd/m² per truth unit, want {want}\n{plan}"
    );
}
