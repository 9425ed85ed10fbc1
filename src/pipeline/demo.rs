//! `lumiprobe demo`: the whole job on a scene made on the spot, so a new user sees
//! lumiprobe work with no data: synthesize, run each method, score them together.

use super::evaluate::{evaluate, SceneEval};
use super::{run, Method, RunParams};
use crate::error::Result;
use crate::scene::Scene;
use crate::synth::{synthesize, SynthParams};
use std::path::{Path, PathBuf};

/// Writes a synthetic scene to `dir/scene`, predicts every frame with each of
/// `methods` into `dir/<method>` and returns the evaluation of all of them against
/// the scene's ground truth and both baselines.
pub fn demo(
    dir: &Path,
    synth: &SynthParams,
    methods: &[Method],
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<SceneEval> {
    let scene_dir = dir.join("scene");
    synthesize(synth).write(&scene_dir)?;
    let scene = Scene::load(&scene_dir)?;
    let mut outs: Vec<(String, PathBuf)> = Vec::new();
    for &m in methods {
        let name = format!("{m:?}").to_lowercase();
        let out = dir.join(&name);
        run(
            &scene,
            &out,
            &RunParams {
                method: m,
                ..RunParams::default()
            },
            progress,
        )?;
        outs.push((name, out));
    }
    let refs: Vec<(String, &Path)> = outs.iter().map(|(l, d)| (l.clone(), d.as_path())).collect();
    evaluate(&scene, &refs)
}
