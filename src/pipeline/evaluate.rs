//! Scoring a run's predictions against a scene's ground truth, next to the two
//! baselines every method must beat: the nearest probe rotated into the frame's
//! orientation (right light, wrong structure) and the linearised SDR frame (right
//! structure, light sources clipped).

use super::{existing_prediction, linearize, load_frame, load_probe, prediction_path};
use crate::error::{Error, Result};
use crate::eval::summary::{summarize, FrameSample};
use crate::eval::{compare_to_truth, Metrics, MetricsTable, Truth};
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
    /// `(label, factor)` for predictions rescaled to the truth's global scale
    /// ([`evaluate_rescaled`]); empty otherwise.
    #[serde(default)]
    pub scales: Vec<(String, f64)>,
}

/// Mean luminance of an image (solid-angle weighting is not needed for a ratio of
/// two panoramas of the same size and layout).
fn mean_luminance(img: &HdrImage) -> f64 {
    let n = (img.width() * img.height()).max(1) as f64;
    img.pixels()
        .map(|p| crate::image::luminance(p) as f64)
        .sum::<f64>()
        / n
}

/// For each `(label, prediction folder)`, the median over frames with ground
/// truth of the truth's mean luminance over the prediction's (1 when no frame
/// has both).
pub fn scale_factors(scene: &Scene, preds: &[(String, &Path)]) -> Result<Vec<(String, f64)>> {
    let mut factors = Vec::new();
    for (label, dir) in preds {
        let mut logs = Vec::new();
        for frame in &scene.frames {
            let Some(gt_path) = &frame.ground_truth else {
                continue;
            };
            let p = prediction_path(dir, frame);
            if !p.exists() {
                continue;
            }
            let (a, b) = (
                mean_luminance(&io::read_hdr(gt_path)?),
                mean_luminance(&io::read_hdr(&p)?),
            );
            if a > 0.0 && b > 0.0 && (a / b).is_finite() {
                logs.push((a / b).ln());
            }
        }
        logs.sort_by(f64::total_cmp);
        let f = if logs.is_empty() {
            1.0
        } else {
            logs[logs.len() / 2].exp()
        };
        factors.push((label.clone(), f));
    }
    Ok(factors)
}

/// Largest ratio between a prediction's global scale and the truth's that
/// `eval` accepts without a warning.
pub const SCALE_WARN_RATIO: f64 = 2.0;

/// The warning `eval` prints for a prediction whose global scale is off the
/// truth's by more than [`SCALE_WARN_RATIO`] (`factor`: truth over prediction,
/// from [`scale_factors`]).
pub fn scale_warning(label: &str, dir: &Path, factor: f64) -> Option<String> {
    if !(factor.is_finite() && factor > 0.0)
        || (1.0 / SCALE_WARN_RATIO..=SCALE_WARN_RATIO).contains(&factor)
    {
        return None;
    }
    let (times, how) = if factor < 1.0 {
        (1.0 / factor, "brighter")
    } else {
        (factor, "dimmer")
    };
    Some(format!(
        "warning: {label} ({}): its probes are {times:.3}x {how} than the ground truth (median \
         over frames), so every radiometric score measures the scale: pass --rescale to score \
         them at the truth's scale, or give the probes an absolute unit (probes merged from \
         brackets are relative unless the camera's gain is known)",
        dir.display()
    ))
}

/// Like [`evaluate`], with every prediction first multiplied by one global factor
/// per folder: the median over frames of the truth's mean luminance over the
/// prediction's. For predictions whose absolute scale is unknowable (probes merged
/// from brackets without a calibrated camera are relative radiance); the factors
/// are reported in [`SceneEval::scales`]. Baselines are not rescaled.
pub fn evaluate_rescaled(scene: &Scene, preds: &[(String, &Path)]) -> Result<SceneEval> {
    let factors = scale_factors(scene, preds)?;
    let mut ev = evaluate_scaled(
        scene,
        preds,
        &factors.iter().map(|x| x.1).collect::<Vec<_>>(),
        None,
    )?;
    ev.scales = factors;
    Ok(ev)
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
/// Every row of the table carries the worst-case statistics of
/// [`crate::eval::summary`] (p95, worst frame, frames over the SDR baseline's
/// irradiance error, flicker between consecutive scored frames in walk order).
pub fn evaluate(scene: &Scene, preds: &[(String, &Path)]) -> Result<SceneEval> {
    evaluate_scaled(scene, preds, &vec![1.0; preds.len()], None)
}

/// Suffix of the rows [`evaluate_apart`] adds: the label's scores over the
/// frames the inputs can answer.
pub const ANSWERABLE: &str = "@answerable";

/// Like [`evaluate`], with every row also scored over the frames not in
/// `unanswerable` (frame ids: light that no probe saw, which no method can
/// recover), as a row labelled `<label>@answerable`; none when no frame is left.
/// Flicker in those rows is between consecutive answerable frames.
pub fn evaluate_apart(
    scene: &Scene,
    preds: &[(String, &Path)],
    unanswerable: &std::collections::HashSet<String>,
) -> Result<SceneEval> {
    evaluate_scaled(scene, preds, &vec![1.0; preds.len()], Some(unanswerable))
}

fn evaluate_scaled(
    scene: &Scene,
    preds: &[(String, &Path)],
    factors: &[f64],
    unanswerable: Option<&std::collections::HashSet<String>>,
) -> Result<SceneEval> {
    use rayon::prelude::*;
    // Per scored frame: its scores, and the irradiance at the metrics' normals of
    // the truth and of each row's image (for flicker), computed with the scores.
    type Scored = (FrameScores, Vec<f64>, Vec<Vec<f64>>);
    let per_frame: Vec<Result<Option<Scored>>> = (0..scene.frames.len())
        .into_par_iter()
        .map(|i| {
            let frame = &scene.frames[i];
            let Some(gt_path) = &frame.ground_truth else {
                return Ok(None);
            };
            let truth = Truth::new(&io::read_hdr(gt_path)?)?;
            let (w, h) = truth.size();
            let mut scores = Vec::new();
            let mut irradiance = Vec::new();
            let mut score = |label: &str, img: &HdrImage| -> Result<()> {
                let c = compare_to_truth(img, &truth)?;
                scores.push((label.to_string(), c.metrics));
                irradiance.push(c.irradiance);
                Ok(())
            };
            for ((label, dir), &f) in preds.iter().zip(factors) {
                let p = existing_prediction(dir, frame)?;
                let mut pred = io::read_hdr(&p)?;
                if f != 1.0 {
                    pred.data_mut().iter_mut().for_each(|v| *v *= f as f32);
                }
                score(label, &pred)?;
            }
            score(BASELINE_PROBE, &nearest_probe_baseline(scene, i, w, h)?)?;
            score(
                BASELINE_SDR,
                &linearize(&load_frame(frame, None)?, scene, frame),
            )?;
            let pi = scene.nearest_probe(frame.pose.position);
            let scores = FrameScores {
                id: frame.id.clone(),
                probe_distance_m: crate::scene::distance_m(
                    scene.probes[pi].pose.position,
                    frame.pose.position,
                ),
                scores,
            };
            Ok(Some((scores, truth.irradiance().to_vec(), irradiance)))
        })
        .collect();
    let mut scored = Vec::new();
    for r in per_frame {
        if let Some(f) = r? {
            scored.push(f);
        }
    }
    if scored.is_empty() {
        return Err(Error::Invalid(format!(
            "scene {} has no frame with ground truth to score",
            scene.name
        )));
    }
    let labels: Vec<String> = scored[0].0.scores.iter().map(|s| s.0.clone()).collect();
    let sdr = labels.iter().position(|l| l == BASELINE_SDR);
    let mut table = MetricsTable::new();
    let push = |table: &mut MetricsTable, label: String, frames: &[&Scored], k: usize| {
        let col: Vec<Metrics> = frames.iter().map(|f| f.0.scores[k].1).collect();
        let samples: Vec<FrameSample> = frames
            .iter()
            .map(|(f, eg, ep)| FrameSample {
                id: &f.id,
                metrics: &f.scores[k].1,
                irradiance: &ep[k],
                truth_irradiance: eg,
                sdr_irradiance_err: sdr.map(|s| f.scores[s].1.irradiance_rel_err),
            })
            .collect();
        table.push_with_tail(label, &col, summarize(&samples));
    };
    let all: Vec<&Scored> = scored.iter().collect();
    for (k, label) in labels.iter().enumerate() {
        push(&mut table, label.clone(), &all, k);
    }
    if let Some(flagged) = unanswerable {
        let kept: Vec<&Scored> = all
            .iter()
            .copied()
            .filter(|f| !flagged.contains(&f.0.id))
            .collect();
        if !kept.is_empty() {
            for (k, label) in labels.iter().enumerate() {
                push(&mut table, format!("{label}{ANSWERABLE}"), &kept, k);
            }
        }
    }
    Ok(SceneEval {
        scene: scene.name.clone(),
        table,
        frames: scored.into_iter().map(|f| f.0).collect(),
        scales: Vec::new(),
    })
}

/// Error against distance to the nearest probe (the thesis's Fig. 5.13) as text:
/// frames split into `bins` equal distance ranges, mean tone-mapped PSNR and
/// log-luminance RMSE per method in each.
pub fn distance_table(ev: &SceneEval, bins: usize) -> String {
    let bins = bins.max(1);
    let d: Vec<f32> = ev.frames.iter().map(|f| f.probe_distance_m).collect();
    let lo = d.iter().cloned().fold(f32::INFINITY, f32::min);
    let hi = d.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
    let width = ((hi - lo) / bins as f32).max(1e-6);
    let bin_of = |x: f32| (((x - lo) / width) as usize).min(bins - 1);
    let mut s =
        String::from("error against distance to the nearest probe (PSNR dB / log-lum RMSE)\n");
    s += &format!("{:<24}", "method \\ distance m");
    for b in 0..bins {
        let (a, c) = (lo + b as f32 * width, lo + (b + 1) as f32 * width);
        let n = d.iter().filter(|&&x| bin_of(x) == b).count();
        s += &format!(" {:>17}", format!("{a:.2}-{c:.2} ({n})"));
    }
    s.push('\n');
    let Some(first) = ev.frames.first() else {
        return s;
    };
    for (k, (label, _)) in first.scores.iter().enumerate() {
        s += &format!("{label:<24}");
        for b in 0..bins {
            let m: Vec<&Metrics> = ev
                .frames
                .iter()
                .filter(|f| bin_of(f.probe_distance_m) == b)
                .map(|f| &f.scores[k].1)
                .collect();
            if m.is_empty() {
                s += &format!(" {:>17}", "-");
            } else {
                let n = m.len() as f64;
                let p = m.iter().map(|x| x.psnr_tm).sum::<f64>() / n;
                let l = m.iter().map(|x| x.log_lum_rmse).sum::<f64>() / n;
                s += &format!(" {:>17}", format!("{p:.2} / {l:.3}"));
            }
        }
        s.push('\n');
    }
    s
}

/// Per-frame scores against distance as CSV: `frame,distance_m,method,psnr_tm,
/// ssim_tm,log_lum_rmse,irradiance_rel_err,dominant_dir_err_deg`.
pub fn distance_csv(ev: &SceneEval) -> String {
    let mut s = String::from(
        "frame,distance_m,method,psnr_tm,ssim_tm,log_lum_rmse,irradiance_rel_err,dominant_dir_err_deg\n",
    );
    for f in &ev.frames {
        for (label, m) in &f.scores {
            s += &format!(
                "{},{:.4},{},{:.4},{:.5},{:.5},{:.5},{:.3}\n",
                f.id,
                f.probe_distance_m,
                label,
                m.psnr_tm,
                m.ssim_tm,
                m.log_lum_rmse,
                m.irradiance_rel_err,
                m.dominant_dir_err_deg
            );
        }
    }
    s
}

/// Tone-mapped PSNR of each method against distance to the nearest probe, one
/// series per method (and per method's renders, averaged over models, when
/// `renders` is given).
pub fn distance_plot(
    ev: &SceneEval,
    renders: Option<&super::render_eval::RenderEval>,
) -> crate::eval::plot::Plot {
    use crate::eval::plot::{Plot, Series};
    let mut series: Vec<Series> = Vec::new();
    if let Some(first) = ev.frames.first() {
        for (k, (label, _)) in first.scores.iter().enumerate() {
            series.push(Series {
                name: label.trim_start_matches("baseline:").to_string(),
                labels: Vec::new(),
                points: ev
                    .frames
                    .iter()
                    .map(|f| (f.probe_distance_m as f64, f.scores[k].1.psnr_tm))
                    .collect(),
                line: false,
            });
        }
    }
    if let Some(re) = renders {
        let mut labels: Vec<&str> = Vec::new();
        for s in &re.scores {
            if !labels.contains(&s.label.as_str()) {
                labels.push(&s.label);
            }
        }
        for l in labels {
            let mut frames: Vec<(&str, f64, f64, usize)> = Vec::new();
            for s in re.scores.iter().filter(|s| s.label == l) {
                match frames.iter_mut().find(|f| f.0 == s.frame) {
                    Some(f) => {
                        f.2 += s.psnr;
                        f.3 += 1;
                    }
                    None => frames.push((&s.frame, s.probe_distance_m as f64, s.psnr, 1)),
                }
            }
            series.push(Series {
                name: format!("{} render", l.trim_start_matches("baseline:")),
                labels: Vec::new(),
                points: frames.iter().map(|f| (f.1, f.2 / f.3 as f64)).collect(),
                line: true,
            });
        }
    }
    Plot {
        title: format!("{}: error against distance to the nearest probe", ev.scene),
        x_label: "distance to nearest probe (m)".into(),
        y_label: "PSNR tone-mapped (dB)".into(),
        log_x: false,
        log_y: false,
        x_names: Vec::new(),
        series,
    }
}
