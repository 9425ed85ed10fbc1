//! Scoring a run's predictions against a scene's ground truth, next to the two
//! baselines every method must beat: the nearest probe rotated into the frame's
//! orientation (right light, wrong structure) and the linearised SDR frame (right
//! structure, light sources clipped).

use super::{linearize, load_frame, load_probe, prediction_path};
use crate::error::{Error, Result};
use crate::eval::{compare_resized, Metrics, MetricsTable};
use crate::image::{io, HdrImage};
use crate::scene::Scene;
use crate::sphere::rotate;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Label of the nearest-probe baseline.
pub const BASELINE_PROBE: &str = "baseline:nearest-probe";
/// Label of the linearised-SDR baseline.
pub const BASELINE_SDR: &str = "baseline:sdr";

/// Scores of one frame.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FrameScores {
    /// Frame id.
    pub id: String,
    /// Distance to the nearest probe in metres.
    pub probe_distance_m: f32,
    /// `(label, metrics)` for each scored method and baseline.
    pub scores: Vec<(String, Metrics)>,
}

/// The evaluation of one or more predictions on a scene.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SceneEval {
    /// Scene name.
    pub scene: String,
    /// Mean per method.
    pub table: MetricsTable,
    /// Per-frame scores.
    pub frames: Vec<FrameScores>,
}

/// The nearest-probe baseline for a frame at the ground truth's size.
pub fn nearest_probe_baseline(
    scene: &Scene,
    frame_index: usize,
    w: usize,
    h: usize,
) -> Result<HdrImage> {
    let frame = &scene.frames[frame_index];
    let pi = scene.nearest_probe(frame.pose.position);
    let (probe, _) = load_probe(scene, pi, None)?;
    Ok(rotate(
        &probe,
        frame.pose.from_other(&scene.probes[pi].pose),
        w,
        h,
    ))
}

/// Scores each `(label, prediction folder)` and both baselines on every frame that
/// has ground truth. Predictions of another size are resampled to the truth's.
pub fn evaluate(scene: &Scene, preds: &[(String, &Path)]) -> Result<SceneEval> {
    use rayon::prelude::*;
    let per_frame: Vec<Result<Option<FrameScores>>> = (0..scene.frames.len())
        .into_par_iter()
        .map(|i| {
            let frame = &scene.frames[i];
            let Some(gt_path) = &frame.ground_truth else {
                return Ok(None);
            };
            let gt = io::read_hdr(gt_path)?;
            let mut scores = Vec::new();
            for (label, dir) in preds {
                let p = prediction_path(dir, frame);
                if !p.exists() {
                    return Err(Error::Invalid(format!(
                        "{}: prediction for frame {} is missing (run `lumiprobe run` first)",
                        p.display(),
                        frame.id
                    )));
                }
                let pred = io::read_hdr(&p)?;
                scores.push((label.clone(), compare_resized(&pred, &gt)?));
            }
            let base = nearest_probe_baseline(scene, i, gt.width(), gt.height())?;
            scores.push((BASELINE_PROBE.to_string(), compare_resized(&base, &gt)?));
            let sdr = linearize(&load_frame(frame, None)?, scene);
            scores.push((BASELINE_SDR.to_string(), compare_resized(&sdr, &gt)?));
            let pi = scene.nearest_probe(frame.pose.position);
            Ok(Some(FrameScores {
                id: frame.id.clone(),
                probe_distance_m: scene.probes[pi].pose.position.distance(frame.pose.position),
                scores,
            }))
        })
        .collect();
    let mut frames = Vec::new();
    for r in per_frame {
        if let Some(f) = r? {
            frames.push(f);
        }
    }
    if frames.is_empty() {
        return Err(Error::Invalid(format!(
            "scene {} has no frame with ground truth to score",
            scene.name
        )));
    }
    let mut table = MetricsTable::new();
    for (k, (label, _)) in frames[0].scores.iter().enumerate() {
        let col: Vec<Metrics> = frames.iter().map(|f| f.scores[k].1).collect();
        table.push(label.clone(), &col);
    }
    Ok(SceneEval {
        scene: scene.name.clone(),
        table,
        frames,
    })
}
