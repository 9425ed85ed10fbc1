//! Worst-case statistics of per-frame scores: what the mean hides.
//!
//! For each metric of [`Metrics`] over the frames of one method:
//!
//! * **mean**: arithmetic mean (as [`Metrics::mean`]).
//! * **p95**, *the 95th-percentile-bad value*: the frames are sorted from best to
//!   worst (ascending for the lower-is-better metrics, descending for `psnr_tm`
//!   and `ssim_tm`) and the value at fraction [`P95`] of the way is taken, with
//!   linear interpolation between the two nearest ranks: at sorted position
//!   `h = 0.95 (n - 1)` (0-based), `x[floor h] + (h - floor h) (x[floor h + 1] -
//!   x[floor h])`. This is the usual 95th percentile (NumPy's default "linear"
//!   rule) for the errors, and the 5th percentile, the low end, for PSNR and SSIM:
//!   about one frame in twenty is worse than it.
//! * **worst**: the single worst frame's value and its id (the first in walk order
//!   on ties).
//!
//! Per method also:
//!
//! * **frames over SDR irradiance**: frames whose `irradiance_rel_err` exceeds
//!   that of the linearised SDR baseline on the same frame, and frames exceeding it
//!   by more than [`SDR_MARGIN`] (2 points).
//! * **flicker**: for each pair of consecutive scored frames `t-1, t` in walk
//!   order, with `E` the diffuse irradiance luminance at the Fibonacci normals of
//!   `irradiance_rel_err` (prediction `Ep`, ground truth `Eg`),
//!   `flicker_t = ||(Ep_t - Ep_{t-1}) - (Eg_t - Eg_{t-1})|| / ||Eg_t||` (L2 over
//!   the normals): the change of the prediction's lighting from one frame to the
//!   next that the true lighting does not make, relative to the true lighting.
//!   When `Eg_t` is zero everywhere it is 0 if the numerator is too, else 1. Its
//!   mean over pairs and its worst pair (named by frame `t`) are reported.
//!
//! NaN robustness: a NaN sample is left out of the mean and the percentile
//! (counted in [`Stat::nan_frames`]) and is the worst frame, so a broken frame is
//! never hidden; the worst value is then NaN (`null` in JSON). Infinite values are
//! ordinary (very bad or very good) values. No frames give `None` everywhere.

use super::{Metrics, METRIC_NAMES};
use serde::{Deserialize, Serialize};

/// Fraction of the way from the best to the worst frame where p95 is read.
pub const P95: f64 = 0.95;

/// Margin over the SDR baseline's irradiance error of the second count.
pub const SDR_MARGIN: f64 = 0.02;

/// Which end of a metric is good.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Better {
    /// Errors: lower is better.
    Lower,
    /// PSNR, SSIM: higher is better.
    Higher,
}

impl Better {
    /// The direction of metric `i` of [`METRIC_NAMES`].
    pub fn of_metric(i: usize) -> Better {
        match METRIC_NAMES.get(i) {
            Some(&"psnr_tm") | Some(&"ssim_tm") => Better::Higher,
            _ => Better::Lower,
        }
    }

    /// Whether `a` is strictly worse than `b` (NaN is worse than anything else).
    pub fn worse(self, a: f64, b: f64) -> bool {
        match (a.is_nan(), b.is_nan()) {
            (true, false) => true,
            (_, true) => false,
            _ => match self {
                Better::Lower => a > b,
                Better::Higher => a < b,
            },
        }
    }
}

/// The value at fraction `q` (in `[0, 1]`) of the way from the best to the worst
/// of `values`, linearly interpolated between ranks (see the module docs); NaN
/// values are left out. `None` when no value is left.
pub fn percentile_bad(values: &[f64], better: Better, q: f64) -> Option<f64> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| !x.is_nan()).collect();
    if v.is_empty() {
        return None;
    }
    match better {
        Better::Lower => v.sort_by(f64::total_cmp),
        Better::Higher => v.sort_by(|a, b| b.total_cmp(a)),
    }
    let h = q.clamp(0.0, 1.0) * (v.len() - 1) as f64;
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(v.len() - 1);
    let f = h - lo as f64;
    if f == 0.0 || v[lo] == v[hi] {
        return Some(v[lo]);
    }
    Some(v[lo] + f * (v[hi] - v[lo]))
}

/// Mean, p95 and worst of one metric over frames.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Stat {
    /// Mean over the frames (NaN samples left out).
    pub mean: Option<f64>,
    /// The 95th-percentile-bad value ([`percentile_bad`] at [`P95`]).
    pub p95: Option<f64>,
    /// The worst frame's value.
    pub worst: Option<f64>,
    /// The worst frame's id.
    pub worst_frame: Option<String>,
    /// Samples that were NaN.
    #[serde(default)]
    pub nan_frames: usize,
}

impl Stat {
    /// The statistics of `(frame id, value)` samples in walk order.
    pub fn of(samples: &[(&str, f64)], better: Better) -> Stat {
        let values: Vec<f64> = samples.iter().map(|s| s.1).collect();
        let finite: Vec<f64> = values.iter().copied().filter(|v| !v.is_nan()).collect();
        let mean = (!finite.is_empty()).then(|| finite.iter().sum::<f64>() / finite.len() as f64);
        let mut worst: Option<(&str, f64)> = None;
        for &(id, v) in samples {
            if worst.map_or(true, |(_, w)| better.worse(v, w)) {
                worst = Some((id, v));
            }
        }
        Stat {
            mean,
            p95: percentile_bad(&values, better, P95),
            worst: worst.map(|w| w.1),
            worst_frame: worst.map(|w| w.0.to_string()),
            nan_frames: values.len() - finite.len(),
        }
    }
}

/// One [`Stat`] per metric, named as in [`METRIC_NAMES`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MetricStats {
    /// Tone-mapped PSNR (p95 and worst are the low end).
    pub psnr_tm: Stat,
    /// Tone-mapped SSIM (p95 and worst are the low end).
    pub ssim_tm: Stat,
    /// Tone-mapped MSE.
    pub mse_tm: Stat,
    /// RMSE of log10 luminance.
    pub log_lum_rmse: Stat,
    /// Relative irradiance error.
    pub irradiance_rel_err: Stat,
    /// Dominant light direction error in degrees.
    pub dominant_dir_err_deg: Stat,
}

impl MetricStats {
    /// Metric `i` of [`METRIC_NAMES`].
    pub fn get(&self, i: usize) -> &Stat {
        [
            &self.psnr_tm,
            &self.ssim_tm,
            &self.mse_tm,
            &self.log_lum_rmse,
            &self.irradiance_rel_err,
            &self.dominant_dir_err_deg,
        ][i]
    }

    fn from_fn(mut f: impl FnMut(usize) -> Stat) -> MetricStats {
        MetricStats {
            psnr_tm: f(0),
            ssim_tm: f(1),
            mse_tm: f(2),
            log_lum_rmse: f(3),
            irradiance_rel_err: f(4),
            dominant_dir_err_deg: f(5),
        }
    }
}

/// Frames whose `value` exceeds `reference` by more than `margin` (pairs per
/// frame). A NaN value counts as over; a NaN reference with a number value does
/// not.
pub fn frames_over(pairs: &[(f64, f64)], margin: f64) -> usize {
    pairs
        .iter()
        .filter(|(v, r)| v.is_nan() || *v > r + margin)
        .count()
}

/// `flicker_t` of one pair of consecutive frames (module docs): the prediction's
/// irradiance at `t-1` and `t`, then the truth's.
pub fn flicker_step(ep_prev: &[f64], ep: &[f64], eg_prev: &[f64], eg: &[f64]) -> f64 {
    let mut num = 0.0f64;
    let mut den = 0.0f64;
    for (((a0, a1), b0), b1) in ep_prev.iter().zip(ep).zip(eg_prev).zip(eg) {
        let d = (a1 - a0) - (b1 - b0);
        num += d * d;
        den += b1 * b1;
    }
    if num.is_nan() || den.is_nan() {
        f64::NAN
    } else if den > 0.0 {
        (num / den).sqrt()
    } else if num > 0.0 {
        1.0
    } else {
        0.0
    }
}

/// Mean and worst flicker of a method.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FlickerStat {
    /// Mean over pairs of consecutive frames.
    pub mean: Option<f64>,
    /// The worst pair's value.
    pub worst: Option<f64>,
    /// Frame `t` of the worst pair `t-1, t`.
    pub worst_frame: Option<String>,
    /// Pairs of consecutive frames.
    pub pairs: usize,
}

/// Flicker over frames in walk order: `(frame id, Ep, Eg)` per frame.
pub fn flicker(frames: &[(&str, &[f64], &[f64])]) -> FlickerStat {
    let steps: Vec<(&str, f64)> = frames
        .windows(2)
        .map(|w| (w[1].0, flicker_step(w[0].1, w[1].1, w[0].2, w[1].2)))
        .collect();
    let s = Stat::of(&steps, Better::Lower);
    FlickerStat {
        mean: s.mean,
        worst: s.worst,
        worst_frame: s.worst_frame,
        pairs: steps.len(),
    }
}

/// One frame of one method, as [`summarize`] reads it.
#[derive(Clone, Copy, Debug)]
pub struct FrameSample<'a> {
    /// Frame id.
    pub id: &'a str,
    /// The method's scores on the frame.
    pub metrics: &'a Metrics,
    /// The prediction's irradiance `Ep` at the normals.
    pub irradiance: &'a [f64],
    /// The truth's irradiance `Eg` at the same normals.
    pub truth_irradiance: &'a [f64],
    /// The SDR baseline's `irradiance_rel_err` on the frame, when it was scored.
    pub sdr_irradiance_err: Option<f64>,
}

/// Everything this module reports for one method (module docs).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RowSummary {
    /// Mean, p95 and worst of each metric.
    pub metrics: MetricStats,
    /// Frames whose irradiance error exceeds the SDR baseline's; `None` without
    /// that baseline.
    pub frames_over_sdr_irr: Option<usize>,
    /// Frames whose irradiance error exceeds the SDR baseline's by more than
    /// [`SDR_MARGIN`].
    pub frames_over_sdr_irr_margin: Option<usize>,
    /// Temporal flicker of the irradiance.
    pub flicker: FlickerStat,
}

/// The summary of one method's frames, given in walk order.
pub fn summarize(frames: &[FrameSample]) -> RowSummary {
    let metrics = MetricStats::from_fn(|i| {
        let samples: Vec<(&str, f64)> = frames
            .iter()
            .map(|f| (f.id, f.metrics.values()[i]))
            .collect();
        Stat::of(&samples, Better::of_metric(i))
    });
    let pairs: Vec<(f64, f64)> = frames
        .iter()
        .filter_map(|f| {
            f.sdr_irradiance_err
                .map(|r| (f.metrics.irradiance_rel_err, r))
        })
        .collect();
    let any_reference = frames.iter().any(|f| f.sdr_irradiance_err.is_some());
    let seq: Vec<(&str, &[f64], &[f64])> = frames
        .iter()
        .map(|f| (f.id, f.irradiance, f.truth_irradiance))
        .collect();
    RowSummary {
        metrics,
        frames_over_sdr_irr: any_reference.then(|| frames_over(&pairs, 0.0)),
        frames_over_sdr_irr_margin: any_reference.then(|| frames_over(&pairs, SDR_MARGIN)),
        flicker: flicker(&seq),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: Option<f64>, b: f64) -> bool {
        a.is_some_and(|a| (a - b).abs() < 1e-12)
    }

    #[test]
    fn p95_interpolates_between_ranks_in_the_bad_direction() {
        let v: Vec<f64> = (1..=20).map(|i| i as f64).collect();
        // h = 0.95 * 19 = 18.05: between 19 and 20 for an error ...
        assert!(close(percentile_bad(&v, Better::Lower, P95), 19.05));
        // ... and between 2 and 1 for a score, the low end.
        assert!(close(percentile_bad(&v, Better::Higher, P95), 1.95));
        // Order of the input does not matter; one value is its own percentile.
        let mut r = v.clone();
        r.reverse();
        assert!(close(percentile_bad(&r, Better::Lower, P95), 19.05));
        assert!(close(percentile_bad(&[3.0], Better::Lower, P95), 3.0));
        assert!(close(percentile_bad(&v, Better::Lower, 0.5), 10.5));
        assert!(close(percentile_bad(&v, Better::Lower, 1.0), 20.0));
        assert_eq!(percentile_bad(&[], Better::Lower, P95), None);
    }

    #[test]
    fn worst_frame_and_mean() {
        let s = [("a", 0.1), ("b", 0.5), ("c", 0.2), ("d", 0.5)];
        let st = Stat::of(&s, Better::Lower);
        assert!(close(st.mean, 0.325));
        assert_eq!(st.worst, Some(0.5));
        assert_eq!(st.worst_frame.as_deref(), Some("b"), "first on ties");
        // p95 of [0.1, 0.2, 0.5, 0.5]: h = 2.85, between 0.5 and 0.5.
        assert!(close(st.p95, 0.5));
        let psnr = [("a", 30.0), ("b", 21.0), ("c", 35.0)];
        let st = Stat::of(&psnr, Better::Higher);
        assert_eq!(st.worst_frame.as_deref(), Some("b"));
        // Sorted best first [35, 30, 21]: h = 1.9, 30 - 0.9 * 9.
        assert!(close(st.p95, 21.9));
        assert_eq!(Stat::of(&[], Better::Lower), Stat::default());
    }

    #[test]
    fn nan_is_the_worst_frame_but_not_in_the_mean() {
        let s = [("a", 0.1), ("b", f64::NAN), ("c", 0.3)];
        for better in [Better::Lower, Better::Higher] {
            let st = Stat::of(&s, better);
            assert!(close(st.mean, 0.2), "{st:?}");
            assert_eq!(st.worst_frame.as_deref(), Some("b"));
            assert!(st.worst.unwrap().is_nan());
            assert_eq!(st.nan_frames, 1);
            assert!(st.p95.unwrap().is_finite());
        }
        let all_nan = Stat::of(&[("a", f64::NAN)], Better::Lower);
        assert_eq!((all_nan.mean, all_nan.p95), (None, None));
        assert_eq!(all_nan.worst_frame.as_deref(), Some("a"));
        assert_eq!(percentile_bad(&[f64::NAN], Better::Higher, P95), None);
    }

    #[test]
    fn frames_over_the_sdr_baseline() {
        let pairs = [(0.10, 0.05), (0.10, 0.09), (0.05, 0.10), (f64::NAN, 0.1)];
        assert_eq!(frames_over(&pairs, 0.0), 3);
        assert_eq!(frames_over(&pairs, SDR_MARGIN), 2);
        assert_eq!(frames_over(&[(0.1, 0.1)], 0.0), 0, "equal is not over");
        assert_eq!(frames_over(&[], 0.0), 0);
    }

    #[test]
    fn flicker_of_known_sequences() {
        let gt = [vec![1.0, 1.0], vec![2.0, 2.0], vec![2.0, 2.0]];
        // A prediction that follows the truth's changes exactly, offset by a
        // constant, does not flicker.
        let follow = [vec![1.5, 0.5], vec![2.5, 1.5], vec![2.5, 1.5]];
        let seq: Vec<(&str, &[f64], &[f64])> = ["f0", "f1", "f2"]
            .iter()
            .zip(follow.iter().zip(&gt))
            .map(|(id, (p, g))| (*id, p.as_slice(), g.as_slice()))
            .collect();
        let f = flicker(&seq);
        assert_eq!(f.pairs, 2);
        assert_eq!(f.mean, Some(0.0));
        // A constant prediction misses the truth's change at f1: ||(0,0) - (1,1)|| /
        // ||(2,2)|| = 0.5, and makes none at f2.
        let flat = [vec![1.0, 1.0], vec![1.0, 1.0], vec![1.0, 1.0]];
        let seq: Vec<(&str, &[f64], &[f64])> = ["f0", "f1", "f2"]
            .iter()
            .zip(flat.iter().zip(&gt))
            .map(|(id, (p, g))| (*id, p.as_slice(), g.as_slice()))
            .collect();
        let f = flicker(&seq);
        assert!(close(f.worst, 0.5), "{f:?}");
        assert_eq!(f.worst_frame.as_deref(), Some("f1"));
        assert!(close(f.mean, 0.25));
        // A jump against a dark truth: 1; no jump: 0; fewer than two frames: none.
        assert_eq!(flicker_step(&[0.0], &[1.0], &[0.0], &[0.0]), 1.0);
        assert_eq!(flicker_step(&[1.0], &[1.0], &[0.0], &[0.0]), 0.0);
        assert!(flicker_step(&[f64::NAN], &[1.0], &[1.0], &[1.0]).is_nan());
        let one = flicker(&seq[..1]);
        assert_eq!((one.pairs, one.mean, one.worst), (0, None, None));
    }

    #[test]
    fn summary_of_a_row() {
        let m = |irr: f64, psnr: f64| Metrics {
            psnr_tm: psnr,
            ssim_tm: 0.9,
            mse_tm: 0.01,
            log_lum_rmse: 0.2,
            irradiance_rel_err: irr,
            dominant_dir_err_deg: 3.0,
            invalid_pixels: 0,
        };
        let ms = [m(0.05, 30.0), m(0.20, 25.0), m(0.10, 28.0)];
        let sdr = [0.10, 0.15, 0.11];
        let e: Vec<Vec<f64>> = vec![vec![1.0], vec![1.0], vec![1.0]];
        let ids = ["a", "b", "c"];
        let frames: Vec<FrameSample> = (0..3)
            .map(|i| FrameSample {
                id: ids[i],
                metrics: &ms[i],
                irradiance: &e[i],
                truth_irradiance: &e[i],
                sdr_irradiance_err: Some(sdr[i]),
            })
            .collect();
        let s = summarize(&frames);
        assert_eq!(
            s.metrics.irradiance_rel_err.worst_frame.as_deref(),
            Some("b")
        );
        assert_eq!(s.metrics.psnr_tm.worst, Some(25.0));
        assert_eq!(s.metrics.get(4), &s.metrics.irradiance_rel_err);
        assert_eq!(s.frames_over_sdr_irr, Some(1));
        assert_eq!(s.frames_over_sdr_irr_margin, Some(1));
        assert_eq!(s.flicker.mean, Some(0.0));
        let none = summarize(&[]);
        assert_eq!(none.frames_over_sdr_irr, None);
        assert_eq!(none.metrics.psnr_tm.mean, None);
    }
}
