//! The thesis's render metrics (its Table 5.1): glTF models lit by a predicted
//! probe and by the ground-truth probe of the same frame, compared as tone-mapped
//! images with SSIM, MSE and PSNR; the two baselines are scored the same way.
//!
//! Protocol, per scored frame and model: every probe (prediction, ground truth,
//! nearest probe rotated to the frame, linearised SDR frame) is prefiltered
//! ([`Prefiltered::from_env`]) and lights the model, framed by
//! [`Camera::framing`] from `view_dir` in the frame's camera axes, on a
//! transparent (black) background. Both renders are tone-mapped with
//! [`reinhard_global`] at key 0.18 using the log-average luminance of the
//! ground-truth render's covered pixels, so an exposure error shows. MSE is over
//! all pixels and channels in display units, PSNR is `10 log10(1 / MSE)` (capped
//! at 100 dB), SSIM is [`crate::eval::ssim`] of the luma.

use super::evaluate::{nearest_probe_baseline, BASELINE_PROBE, BASELINE_SDR};
use super::{existing_prediction, linearize, load_frame};
use crate::error::{Error, Result};
use crate::ibl::export::{PrefilterOptions, Prefiltered};
use crate::image::{io, luminance, HdrImage};
use crate::render::{render, Background, Camera, Model, RenderOptions};
use crate::scene::Scene;
use crate::tonemap::reinhard_global;
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Settings of the render evaluation.
#[derive(Clone, Debug)]
pub struct RenderEvalOptions {
    /// Frames scored, spread evenly over the frames with ground truth (0 = all).
    pub frames: usize,
    /// Render width and height in pixels.
    pub size: usize,
    /// Supersampling per pixel side.
    pub supersample: usize,
    /// Direction the camera looks along, in the frame's camera axes.
    pub view_dir: Vec3,
    /// Vertical field of view in degrees.
    pub vfov_deg: f32,
    /// Prefiltering of every probe.
    pub prefilter: PrefilterOptions,
}

impl Default for RenderEvalOptions {
    /// Five frames, 256x256 renders with 2x2 supersampling, looking forward and
    /// slightly down, 64-texel specular faces.
    fn default() -> Self {
        let mut prefilter = PrefilterOptions::default();
        prefilter.specular.face_size = 64;
        prefilter.specular.samples = 128;
        RenderEvalOptions {
            frames: 5,
            size: 256,
            supersample: 2,
            view_dir: Vec3::new(0.0, -0.35, -1.0).normalize(),
            vfov_deg: 35.0,
            prefilter,
        }
    }
}

/// Scores of one render against the ground-truth render.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RenderScore {
    /// Frame id.
    pub frame: String,
    /// Distance from the frame to its nearest probe, metres.
    pub probe_distance_m: f32,
    /// Model file name.
    pub model: String,
    /// Method or baseline label.
    pub label: String,
    /// Mean SSIM of the tone-mapped luma.
    pub ssim: f64,
    /// Mean squared error of the tone-mapped RGB.
    pub mse: f64,
    /// PSNR in dB.
    pub psnr: f64,
}

/// Mean scores of one label on one model (or `"all"` models).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RenderRow {
    /// Method or baseline label.
    pub label: String,
    /// Model file name, or `all`.
    pub model: String,
    /// Renders averaged.
    pub n: usize,
    /// Mean SSIM.
    pub ssim: f64,
    /// Mean MSE.
    pub mse: f64,
    /// Mean PSNR (dB).
    pub psnr: f64,
}

/// The render evaluation of a scene.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RenderEval {
    /// Scene name.
    pub scene: String,
    /// Means per label and model, then per label over all models.
    pub table: Vec<RenderRow>,
    /// Every render's scores.
    pub scores: Vec<RenderScore>,
}

impl RenderEval {
    /// The table as aligned text, one row per label and model.
    pub fn to_text(&self) -> String {
        let mut s = format!(
            "{:<24} {:<22} {:>4} {:>8} {:>10} {:>8}\n",
            "method", "model", "n", "SSIM", "MSE", "PSNR"
        );
        for r in &self.table {
            s += &format!(
                "{:<24} {:<22} {:>4} {:>8.4} {:>10.6} {:>8.2}\n",
                r.label, r.model, r.n, r.ssim, r.mse, r.psnr
            );
        }
        s
    }
}

/// Indices of `k` frames spread evenly over `n` (all when `k` is 0 or >= n).
fn spread(n: usize, k: usize) -> Vec<usize> {
    if k == 0 || k >= n {
        return (0..n).collect();
    }
    (0..k).map(|i| (i * (n - 1)) / (k - 1).max(1)).collect()
}

fn prefiltered(img: &HdrImage, opts: &PrefilterOptions) -> Result<Prefiltered> {
    let mut img = img.clone();
    img.repair_invalid();
    Prefiltered::from_env(&img, opts)
}

/// Tone-maps a render for comparison with `log_avg` of the reference.
fn display(img: &HdrImage, log_avg: f32) -> Vec<f32> {
    reinhard_global(img, 0.18, None, Some(log_avg))
}

/// Log-average luminance of the pixels a render covers (alpha > 0.5).
fn covered_log_average(img: &HdrImage, alpha: &[f32]) -> f32 {
    let (mut s, mut n) = (0.0f64, 0usize);
    for (p, &a) in img.pixels().zip(alpha) {
        if a > 0.5 {
            s += (1e-6 + luminance(p).max(0.0) as f64).ln();
            n += 1;
        }
    }
    if n == 0 {
        1.0
    } else {
        (s / n as f64).exp() as f32
    }
}

fn score(pred: &[f32], gt: &[f32], w: usize, h: usize) -> (f64, f64, f64) {
    let mse = pred
        .iter()
        .zip(gt)
        .map(|(a, b)| ((a - b) as f64).powi(2))
        .sum::<f64>()
        / pred.len().max(1) as f64;
    let psnr = if mse > 0.0 {
        (10.0 * (1.0 / mse).log10()).min(100.0)
    } else {
        100.0
    };
    let luma = |v: &[f32]| -> Vec<f32> {
        v.chunks_exact(3)
            .map(|c| 0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2])
            .collect()
    };
    let ssim = crate::eval::ssim(&luma(pred), &luma(gt), w, h);
    (ssim, mse, psnr)
}

/// Renders every model of `models` lit by each prediction and both baselines at
/// the frames chosen by `opts`, against the ground truth's renders.
pub fn render_eval(
    scene: &Scene,
    preds: &[(String, &Path)],
    models: &[PathBuf],
    opts: &RenderEvalOptions,
) -> Result<RenderEval> {
    if models.is_empty() {
        return Err(Error::Invalid("no model to render".into()));
    }
    let loaded: Vec<(String, Model)> = models
        .iter()
        .map(|p| {
            Ok((
                p.file_name()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default(),
                Model::load(p)?,
            ))
        })
        .collect::<Result<_>>()?;
    let with_gt: Vec<usize> = (0..scene.frames.len())
        .filter(|&i| scene.frames[i].ground_truth.is_some())
        .collect();
    if with_gt.is_empty() {
        return Err(Error::Invalid(format!(
            "scene {} has no frame with ground truth",
            scene.name
        )));
    }
    let ropts = RenderOptions {
        background: Background::Transparent,
        supersample: opts.supersample,
        lights: Vec::new(),
    };
    let mut scores = Vec::new();
    for &k in &spread(with_gt.len(), opts.frames) {
        let i = with_gt[k];
        let frame = &scene.frames[i];
        let gt = io::read_hdr(frame.ground_truth.as_ref().expect("filtered above"))?;
        let (w, h) = (gt.width(), gt.height());
        let mut sources: Vec<(String, HdrImage)> = Vec::new();
        for (label, dir) in preds {
            let p = existing_prediction(dir, frame)?;
            sources.push((label.clone(), io::read_hdr(&p)?));
        }
        sources.push((
            BASELINE_PROBE.to_string(),
            nearest_probe_baseline(scene, i, w, h)?,
        ));
        sources.push((
            BASELINE_SDR.to_string(),
            linearize(&load_frame(frame, None)?, scene, frame),
        ));
        let pi = scene.nearest_probe(frame.pose.position);
        let dist = crate::scene::distance_m(scene.probes[pi].pose.position, frame.pose.position);
        let gt_env = prefiltered(&gt, &opts.prefilter)?;
        let envs: Vec<(String, Prefiltered)> = sources
            .iter()
            .map(|(l, img)| Ok((l.clone(), prefiltered(img, &opts.prefilter)?)))
            .collect::<Result<_>>()?;
        for (name, model) in &loaded {
            let cam = Camera::framing(
                &model.bounds(),
                opts.view_dir,
                opts.vfov_deg,
                opts.size,
                opts.size,
            );
            let reference = render(model, &gt_env, &cam, &ropts)?;
            let la = covered_log_average(&reference.color, &reference.alpha);
            let ref_disp = display(&reference.color, la);
            for (label, env) in &envs {
                let r = render(model, env, &cam, &ropts)?;
                let (ssim, mse, psnr) =
                    score(&display(&r.color, la), &ref_disp, opts.size, opts.size);
                scores.push(RenderScore {
                    frame: frame.id.clone(),
                    probe_distance_m: dist,
                    model: name.clone(),
                    label: label.clone(),
                    ssim,
                    mse,
                    psnr,
                });
            }
        }
    }
    // Means per (label, model) in first-seen order, then per label over models.
    let mut table: Vec<RenderRow> = Vec::new();
    let mut add = |label: &str, model: &str, s: &RenderScore| {
        if let Some(r) = table
            .iter_mut()
            .find(|r| r.label == label && r.model == model)
        {
            r.n += 1;
            r.ssim += s.ssim;
            r.mse += s.mse;
            r.psnr += s.psnr;
        } else {
            table.push(RenderRow {
                label: label.to_string(),
                model: model.to_string(),
                n: 1,
                ssim: s.ssim,
                mse: s.mse,
                psnr: s.psnr,
            });
        }
    };
    for s in &scores {
        add(&s.label, &s.model, s);
    }
    for s in &scores {
        add(&s.label, "all", s);
    }
    for r in &mut table {
        let n = r.n as f64;
        r.ssim /= n;
        r.mse /= n;
        r.psnr /= n;
    }
    table.sort_by(|a, b| (a.model == "all").cmp(&(b.model == "all")));
    Ok(RenderEval {
        scene: scene.name.clone(),
        table,
        scores,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_spread_over_the_sequence() {
        assert_eq!(spread(20, 5), vec![0, 4, 9, 14, 19]);
        assert_eq!(spread(3, 5), vec![0, 1, 2]);
        assert_eq!(spread(4, 0), vec![0, 1, 2, 3]);
        assert_eq!(spread(7, 1), vec![0]);
    }

    #[test]
    fn identical_renders_score_perfectly_and_different_ones_do_not() {
        let a: Vec<f32> = (0..16 * 16 * 3).map(|i| (i % 7) as f32 / 7.0).collect();
        let (s, m, p) = score(&a, &a, 16, 16);
        assert_eq!((s, m, p), (1.0, 0.0, 100.0));
        let b: Vec<f32> = a.iter().map(|v| v * 0.5).collect();
        let (s, m, p) = score(&b, &a, 16, 16);
        assert!(s < 1.0 && m > 0.0 && p < 100.0);
    }
}
