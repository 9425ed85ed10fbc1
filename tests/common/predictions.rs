//! A synthetic scene whose ground truth stands in for a run's predictions, for
//! the tests of commands that read a run's outputs (`export`, `view`).

use lumiprobe::scene::Scene;
use lumiprobe::synth::{synthesize, SynthParams};
use std::path::{Path, PathBuf};

/// Writes a three-frame synthetic scene under `root` and a run folder holding
/// its ground truth as the predictions; returns both folders.
pub fn scene_with_predictions(root: &Path) -> (PathBuf, PathBuf) {
    let dir = root.join("scene");
    let p = SynthParams {
        width: 128,
        n_frames: 3,
        n_probes: 2,
        seed: 5,
        name: "x".into(),
        ..Default::default()
    };
    synthesize(&p).write(&dir).unwrap();
    let pred = root.join("run");
    std::fs::create_dir_all(&pred).unwrap();
    let scene = Scene::load(&dir).unwrap();
    for f in &scene.frames {
        std::fs::copy(
            f.ground_truth.as_ref().unwrap(),
            pred.join(format!("{}.exr", f.id)),
        )
        .unwrap();
    }
    (dir, pred)
}
