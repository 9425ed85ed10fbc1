//! `lumiprobe demo`: the whole job on a scene made on the spot, so a new user sees
//! lumiprobe work with no data: synthesize, run the warp method, score it.

use super::evaluate::{evaluate, SceneEval};
use super::{run, RunParams};
use crate::error::Result;
use crate::scene::Scene;
use crate::synth::{synthesize, SynthParams};
use std::path::Path;

/// Writes a synthetic scene to `dir/scene`, predicts every frame into `dir/warp` and
/// returns the evaluation against the scene's ground truth and both baselines.
pub fn demo(
    dir: &Path,
    synth: &SynthParams,
    params: &RunParams,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<SceneEval> {
    let scene_dir = dir.join("scene");
    synthesize(synth).write(&scene_dir)?;
    let scene = Scene::load(&scene_dir)?;
    let out = dir.join("warp");
    run(&scene, &out, params, progress)?;
    evaluate(&scene, &[("warp".to_string(), out.as_path())])
}
