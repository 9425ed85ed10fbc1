//! Pinned figures: each method on the three shared scenes and on the corpus
//! scene CI renders, scored against ground truth. A figure that worsens beyond
//! its tolerance fails the test; missing data fails it too.
//!
//! The pins live in `tests/pinned.json`, one entry per `scene/method`. After a
//! change that improves a figure (or that is accepted to cost one, said in its
//! commit), rewrite them with
//! `LUMIPROBE_PIN_UPDATE=1 cargo test --release --test pinned` and commit the
//! file with the change.

#[path = "common/data.rs"]
mod data;

use lumiprobe::pipeline::evaluate::evaluate;
use lumiprobe::pipeline::{run, Method, RunParams};
use lumiprobe::scene::Scene;
use serde_json::{json, Map, Value};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

const PINS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/pinned.json");

/// What a figure may lose before the test fails: `absolute + relative * |pin|`.
struct Tolerance {
    name: &'static str,
    higher_is_better: bool,
    absolute: f64,
    relative: f64,
}

const TOLERANCES: [Tolerance; 5] = [
    Tolerance {
        name: "psnr_tm",
        higher_is_better: true,
        absolute: 0.05,
        relative: 0.0,
    },
    Tolerance {
        name: "log_lum_rmse",
        higher_is_better: false,
        absolute: 1e-4,
        relative: 0.01,
    },
    Tolerance {
        name: "irradiance_mean",
        higher_is_better: false,
        absolute: 0.002,
        relative: 0.05,
    },
    Tolerance {
        name: "irradiance_worst",
        higher_is_better: false,
        absolute: 0.005,
        relative: 0.10,
    },
    Tolerance {
        name: "dominant_dir_mean_deg",
        higher_is_better: false,
        absolute: 0.2,
        relative: 0.05,
    },
];

static PIN_FILE: Mutex<()> = Mutex::new(());

/// The scenes each method is pinned on: (key, folder, frame step).
fn scenes() -> Vec<(String, PathBuf, usize)> {
    let data = data::shared_data();
    let mut v: Vec<(String, PathBuf, usize)> = ["kitchen", "flat", "outdoor"]
        .iter()
        .map(|n| (n.to_string(), data.join("scenes").join(n), 2))
        .collect();
    v.push(("ci-corpus".into(), data::smoke_scene(), 1));
    v
}

fn measure(dir: &Path, step: usize, method: Method) -> Map<String, Value> {
    let mut scene = Scene::load(dir).unwrap();
    scene.frames = scene.frames.into_iter().step_by(step).collect();
    let tmp = tempfile::tempdir().unwrap();
    let params = RunParams {
        method,
        ..RunParams::default()
    };
    run(&scene, tmp.path(), &params, &|_, _| {}).unwrap();
    let ev = evaluate(&scene, &[("m".into(), tmp.path())]).unwrap();
    let of = |f: &lumiprobe::pipeline::evaluate::FrameScores| {
        f.scores.iter().find(|s| s.0 == "m").unwrap().1
    };
    let n = ev.frames.len() as f64;
    assert!(n > 0.0, "{}: no frame scored", dir.display());
    let mean = |g: &dyn Fn(&lumiprobe::eval::Metrics) -> f64| {
        ev.frames.iter().map(|f| g(&of(f))).sum::<f64>() / n
    };
    let worst = ev
        .frames
        .iter()
        .map(|f| of(f).irradiance_rel_err)
        .fold(0.0, f64::max);
    let mut m = Map::new();
    m.insert("psnr_tm".into(), json!(mean(&|x| x.psnr_tm)));
    m.insert("log_lum_rmse".into(), json!(mean(&|x| x.log_lum_rmse)));
    m.insert(
        "irradiance_mean".into(),
        json!(mean(&|x| x.irradiance_rel_err)),
    );
    m.insert("irradiance_worst".into(), json!(worst));
    m.insert(
        "dominant_dir_mean_deg".into(),
        json!(mean(&|x| x.dominant_dir_err_deg)),
    );
    for (k, v) in &m {
        assert!(
            v.as_f64().unwrap().is_finite(),
            "{}: {k} is not finite",
            dir.display()
        );
    }
    m
}

fn check_method(method: Method, name: &str) {
    let update = std::env::var_os("LUMIPROBE_PIN_UPDATE").is_some();
    let mut failures = Vec::new();
    for (scene, dir, step) in scenes() {
        let key = format!("{scene}/{name}");
        let got = measure(&dir, step, method);
        println!("{key}: {}", Value::Object(got.clone()));
        let _guard = PIN_FILE.lock().unwrap_or_else(|e| e.into_inner());
        let text = std::fs::read_to_string(PINS).unwrap_or_else(|e| panic!("{PINS}: {e}"));
        let mut pins: Map<String, Value> = serde_json::from_str(&text)
            .unwrap_or_else(|e| panic!("{PINS}: not a JSON object of pins: {e}"));
        if update {
            pins.insert(key, Value::Object(got));
            let mut s = serde_json::to_string_pretty(&pins).unwrap();
            s.push('\n');
            std::fs::write(PINS, s).unwrap();
            continue;
        }
        let Some(pin) = pins.get(&key).and_then(Value::as_object) else {
            failures.push(format!(
                "{key}: no pin in tests/pinned.json (measured {})",
                Value::Object(got)
            ));
            continue;
        };
        for t in &TOLERANCES {
            let (g, p) = (got[t.name].as_f64().unwrap(), pin[t.name].as_f64().unwrap());
            let slack = t.absolute + t.relative * p.abs();
            let worse = if t.higher_is_better {
                g < p - slack
            } else {
                g > p + slack
            };
            if worse {
                failures.push(format!(
                    "{key}: {} worsened from {p:.5} to {g:.5} (tolerance {slack:.5})",
                    t.name
                ));
            } else if (g - p).abs() > slack {
                println!(
                    "{key}: {} improved from {p:.5} to {g:.5}: consider updating the pin",
                    t.name
                );
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn warp_figures_hold() {
    check_method(Method::Warp, "warp");
}

#[test]
fn flow_figures_hold() {
    check_method(Method::Flow, "flow");
}

#[test]
fn hybrid_figures_hold() {
    check_method(Method::Hybrid, "hybrid");
}

#[test]
fn fusion_figures_hold() {
    check_method(Method::Fusion, "fusion");
}
