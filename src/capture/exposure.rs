//! Each frame's exposure and white balance along the walk (issue 20): a consumer
//! 360° camera meters every frame (auto-exposure, lagging the view) and drifts in
//! white balance, so one gain for the whole walk ([`super::calibrate`]) leaves
//! frames a stop or more off the probes' scale.
//!
//! **Per frame.** The nearest probe turned into the frame's orientation and both
//! averaged over blocks of a fixed angle ([`ExposureOptions::block_deg`]); every block whose frame
//! pixels are all well exposed votes, per channel, with the log ratio of the
//! frame's decoded code to the probe's radiance. A frame's log gain per channel is
//! the median vote; its uncertainty the votes' spread (interquartile range over
//! 1.349, a normal's sigma) over the square root of their number, floored at
//! [`ExposureOptions::floor`] (votes are not independent: parallax moves whole
//! surfaces).
//!
//! **Against the neighbouring frame.** Consecutive frames are a step apart, far
//! less than a frame and its probe, so parallax hardly moves what they see: the
//! frame before, decoded and turned into this frame's orientation, gives the
//! change of log gain from one frame to the next the same way (blocks well
//! exposed in both), with a smaller floor ([`ExposureOptions::relative_floor`]).
//!
//! **Matched by flow** (off by default). Both comparisons can first move the probe and the frame
//! before onto the frame along the optical flow between their codes
//! ([`ExposureOptions::follow_flow`]; the probe encoded at the walk's single
//! gain, for the flow only): rotation alone compares what different surfaces
//! show where the walk's motion moves them, and around a lamp's lit halo,
//! which grows as the walk nears it, that reads as exposure.
//!
//! **Along the walk.** Per channel, the log gains `x` of all frames minimise
//! `sum (x[k] - p[k])^2 / s_p^2 + sum (x[k] - x[k-1] - r[k])^2 / s_r^2` (`p` the
//! probe measurements, `r` the frame-to-frame ones): the frame-to-frame changes
//! carry the walk's shape, jumps included (a meter that jumps shows the jump in
//! `r`), and the probes its level, their parallax errors averaged over the
//! frames. Residuals beyond [`HUBER`] sigmas are reweighted (iteratively, Huber's
//! loss), so a probe comparison that parallax or a passer-by spoils, or one bad
//! frame-to-frame step, loses its pull. A frame with no usable block keeps the
//! chain through its neighbours.

use super::calibrate::{nearest_probe_in_frame, CalibrateOptions};
use super::median;
use crate::error::{Error, Result};
use crate::image::{io, HdrImage, SdrImage};
use crate::scene::Scene;
use crate::sphere::rotate;
use crate::tonemap::Response;
use serde::Serialize;

/// Settings of [`walk_exposure`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExposureOptions {
    /// Well-exposed codes, as for the walk's single gain.
    pub blocks: CalibrateOptions,
    /// Side of the blocks frame and probe are averaged over, in degrees of
    /// longitude (5.625: 8 pixels at 512 wide), at least 2 pixels.
    pub block_deg: f64,
    /// Smallest uncertainty of a frame's log gain against its probe (0.05:
    /// 0.07 EV; parallax moves whole surfaces, so the votes are not
    /// independent).
    pub floor: f64,
    /// Smallest uncertainty of the change of log gain between consecutive
    /// frames.
    pub relative_floor: f64,
    /// Growth of a probe measurement's uncertainty with the frame's distance
    /// from its probe, per walk-median distance (0: none).
    pub parallax: f64,
    /// Match the probe and the frame before to the frame by optical flow (DIS,
    /// patches of normalised mean, so an exposure change does not move them)
    /// before comparing them, instead of by rotation alone: walking towards a
    /// lamp grows the lit halo around it, so blocks compared at the same
    /// direction read the walk's motion as exposure. Measured on the corpus's
    /// video variants (docs/consumer-video.md): the gains' error falls (kitchen
    /// variant median / worst 0.047 / 0.132 -> 0.041 / 0.077 EV; corpus
    /// variants' medians 0.30-0.54 -> 0.26-0.41 EV) but fusion on the
    /// development split does not improve (irradiance error 0.2443 -> 0.2437,
    /// p95 0.508 -> 0.584), so it is off by default.
    pub follow_flow: bool,
    /// Fit the camera's lens vignetting (a falloff towards each lens's rim, the
    /// same in every frame: [`super::vignetting`]) and take it out of each
    /// frame's measurement against its probe. Off by default: the gains it
    /// gives are reported, not yet used to decode the frames.
    pub vignetting: bool,
}

impl Default for ExposureOptions {
    fn default() -> Self {
        ExposureOptions {
            blocks: CalibrateOptions::default(),
            block_deg: 5.625,
            floor: 0.05,
            relative_floor: 0.01,
            parallax: 1.0,
            follow_flow: false,
            vignetting: false,
        }
    }
}

/// One frame's exposure as its blocks measured it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct FrameExposure {
    /// Natural-log gain per channel (radiance = f⁻¹(code) / gain); NaN without
    /// a usable block.
    pub log_gain: [f64; 3],
    /// Natural-log gain of the luminance (the channels' Rec. 709 weights).
    pub log_luminance_gain: f64,
    /// Uncertainty (one sigma) of the log gains.
    pub sigma: f64,
    /// Blocks that voted.
    pub blocks: usize,
}

impl FrameExposure {
    fn missing() -> Self {
        FrameExposure {
            log_gain: [f64::NAN; 3],
            log_luminance_gain: f64::NAN,
            sigma: f64::INFINITY,
            blocks: 0,
        }
    }

    fn usable(&self) -> bool {
        self.blocks > 0
            && self.log_luminance_gain.is_finite()
            && self.log_gain.iter().all(|v| v.is_finite())
    }
}

/// What the walk's frames were exposed with.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WalkExposure {
    /// Each frame as measured against its probe, in walk order.
    pub measured: Vec<FrameExposure>,
    /// Each frame's change of log gain from the frame before (the first
    /// frame's is unused).
    pub relative: Vec<FrameExposure>,
    /// Each frame's gain per channel after the walk pass (linear, not log).
    pub gain: Vec<[f32; 3]>,
    /// Each frame's uncertainty (one sigma, natural log) after the walk pass.
    pub sigma: Vec<f64>,
    /// Frames whose probe measurement the walk down-weighted (an outlier).
    pub outliers: Vec<usize>,
    /// Frames with no usable probe measurement, carried by their neighbours.
    pub filled: Vec<usize>,
    /// Spread of the frames' measured luminance log gains (interquartile
    /// range) against their median uncertainty.
    pub spread_over_noise: f64,
    /// Range of the walk's solved luminance gains, in EV (stops).
    pub swing_ev: f64,
    /// How the frames' blocks agree with the probes by code level, once each
    /// frame's solved gain is taken out ([`response_fit`]): empty when no
    /// frame was measured against a probe.
    pub response_fit: Vec<CodeLevel>,
    /// The lens vignetting fitted to the walk (`1 - k rim`, [`super::vignetting`])
    /// and taken out of `measured`, with [`ExposureOptions::vignetting`].
    pub vignetting: Option<f64>,
}

/// The frames' blocks of one range of codes against the probes, their solved
/// gains taken out: with the right response the median is 0 at every level.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct CodeLevel {
    /// Lowest and highest mean luminance code (0-255) of the range.
    pub codes: (f32, f32),
    /// Median residual, in EV.
    pub median_ev: f64,
    /// Blocks in the range.
    pub blocks: usize,
}

/// Code ranges [`response_fit`] splits the well-exposed codes into.
const LEVELS: usize = 6;

/// Residuals of the blocks' luminance log ratios (`levels[k]`: frame `k`'s
/// blocks, mean code and log ratio) against each frame's solved luminance log
/// gain, by code range between `lo` and `hi`: a response that is wrong for the
/// frames (a video tone curve other than the photos') bends them with the code.
pub fn response_fit(
    levels: &[Vec<(f32, f64)>],
    gain: &[[f32; 3]],
    lo: u8,
    hi: u8,
) -> Vec<CodeLevel> {
    let mut bins: Vec<Vec<f64>> = vec![Vec::new(); LEVELS];
    let step = (hi as f32 - lo as f32).max(1.0) / LEVELS as f32;
    for (blocks, g) in levels.iter().zip(gain) {
        let solved = (REC709[0] / g[0] as f64 + REC709[1] / g[1] as f64 + REC709[2] / g[2] as f64)
            .recip()
            .ln();
        if !solved.is_finite() {
            continue;
        }
        for &(code, lum) in blocks {
            let i = (((code - lo as f32) / step).floor().max(0.0) as usize).min(LEVELS - 1);
            bins[i].push((lum - solved) / std::f64::consts::LN_2);
        }
    }
    bins.iter_mut()
        .enumerate()
        .filter(|(_, v)| !v.is_empty())
        .map(|(i, v)| CodeLevel {
            codes: (
                lo as f32 + i as f32 * step,
                lo as f32 + (i + 1) as f32 * step,
            ),
            median_ev: median(v),
            blocks: v.len(),
        })
        .collect()
}

impl WalkExposure {
    /// The spread (EV) of [`WalkExposure::response_fit`]'s medians over the
    /// ranges with at least `min_blocks` blocks (0 with fewer than two such).
    pub fn response_misfit_ev(&self, min_blocks: usize) -> f64 {
        let m: Vec<f64> = self
            .response_fit
            .iter()
            .filter(|l| l.blocks >= min_blocks)
            .map(|l| l.median_ev)
            .collect();
        if m.len() < 2 {
            return 0.0;
        }
        m.iter().cloned().fold(f64::MIN, f64::max) - m.iter().cloned().fold(f64::MAX, f64::min)
    }
}

/// Smallest range of a walk's exposure (EV) for which each frame's own gain is
/// used by default: on kitchen with a locked exposure the solved gains span
/// 0.15 EV and per-frame gains cost 0.13 points of irradiance error (1.70% ->
/// 1.83%); the consumer variants span 0.7 to 1.3 EV and gain 3 to 6 points.
pub const MIN_SWING_EV: f64 = 0.25;

impl WalkExposure {
    /// True when the walk's exposure moved by more than `min_swing_ev` (its
    /// solved luminance gains' range), so that per-frame gains are worth their
    /// own error (about 0.05 EV a frame).
    pub fn varies_by(&self, min_swing_ev: f64) -> bool {
        self.swing_ev > min_swing_ev
    }

    /// [`WalkExposure::varies_by`] [`MIN_SWING_EV`].
    pub fn varies(&self) -> bool {
        self.varies_by(MIN_SWING_EV)
    }
}

fn iqr(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.len() < 2 {
        return 0.0;
    }
    let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
    q(0.75) - q(0.25)
}

const REC709: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// One frame's exposure against the probe turned into its orientation
/// (`probe_in_frame`, the frame's size).
pub fn frame_exposure(
    sdr: &SdrImage,
    probe_in_frame: &HdrImage,
    response: &Response,
    opts: &ExposureOptions,
) -> FrameExposure {
    exposure_and_levels(sdr, probe_in_frame, response, opts).0
}

/// Each voting block's luminance log ratio with its [`super::vignetting::rim`].
type RimVotes = Vec<(f64, f32)>;

/// [`frame_exposure`] and each voting block's mean luminance code (0-255)
/// with its luminance log ratio: where the response is right, the ratio does
/// not depend on the code.
fn exposure_and_levels(
    sdr: &SdrImage,
    probe_in_frame: &HdrImage,
    response: &Response,
    opts: &ExposureOptions,
) -> (FrameExposure, Vec<(f32, f64)>, RimVotes) {
    let mut levels = Vec::new();
    let mut rims = Vec::new();
    let (w, h) = (sdr.width(), sdr.height());
    // Blocks of a fixed angle, whatever the frame's width.
    let b = ((w as f64 * opts.block_deg / 360.0).round() as usize).max(2);
    if probe_in_frame.width() != w || probe_in_frame.height() != h || w < b || h < b {
        return (FrameExposure::missing(), levels, rims);
    }
    let decode: Vec<f64> = (0..256)
        .map(|c| response.decode(c as f32 / 255.0) as f64)
        .collect();
    let (lo, hi) = (opts.blocks.low_code, opts.blocks.high_code);
    let (bw, bh) = (w / b, h / b);
    let mut votes: [Vec<f64>; 4] = Default::default();
    for by in 0..bh {
        'block: for bx in 0..bw {
            let (mut f, mut p, mut code) = ([0.0f64; 3], [0.0f64; 3], 0.0f64);
            for y in by * b..(by + 1) * b {
                for x in bx * b..(bx + 1) * b {
                    let c = sdr.get(x, y);
                    if c.iter().any(|&v| v < lo || v > hi) {
                        continue 'block;
                    }
                    let r = probe_in_frame.get(x, y);
                    for k in 0..3 {
                        f[k] += decode[c[k] as usize];
                        p[k] += r[k] as f64;
                        code += REC709[k] * c[k] as f64;
                    }
                }
            }
            if !p.iter().all(|&v| v > 0.0 && v.is_finite()) {
                continue;
            }
            let ratios = [(f[0] / p[0]).ln(), (f[1] / p[1]).ln(), (f[2] / p[2]).ln()];
            let (fl, pl): (f64, f64) = (0..3).fold((0.0, 0.0), |(a, c), k| {
                (a + REC709[k] * f[k], c + REC709[k] * p[k])
            });
            let lum = (fl / pl).ln();
            if ratios.iter().all(|v| v.is_finite()) && lum.is_finite() {
                for k in 0..3 {
                    votes[k].push(ratios[k]);
                }
                votes[3].push(lum);
                levels.push(((code / (b * b) as f64) as f32, lum));
                let centre = crate::sphere::pixel_to_dir(bx * b + b / 2, by * b + b / 2, w, h);
                rims.push((lum, super::vignetting::rim(centre)));
            }
        }
    }
    let n = votes[3].len();
    if n == 0 {
        return (FrameExposure::missing(), levels, rims);
    }
    let sigma = (1.2533 * iqr(&mut votes[3].clone()) / 1.349 / (n as f64).sqrt()).max(opts.floor);
    let [r, g, bl, l] = &mut votes;
    (
        FrameExposure {
            log_gain: [median(r), median(g), median(bl)],
            log_luminance_gain: median(l),
            sigma,
            blocks: n,
        },
        levels,
        rims,
    )
}

/// Huber's threshold, in sigmas: a residual beyond it weighs as if it were
/// there (a probe comparison off by parallax, a person walking past).
const HUBER: f64 = 2.0;

/// Solves, per channel, the least squares of the walk (module docs): each
/// frame's log gain `x` near its probe measurement and `x[k] - x[k-1]` near the
/// relative measurement of frame `k` against frame `k - 1`, each by inverse
/// variance, reweighted (Huber) so outliers lose their pull. `relative[0]` is
/// unused.
pub fn along_walk(
    measured: &[FrameExposure],
    relative: &[FrameExposure],
    opts: &ExposureOptions,
) -> WalkExposure {
    let n = measured.len();
    let var = |m: &FrameExposure, floor: f64| m.sigma.max(floor).powi(2);
    let a0: Vec<f64> = measured
        .iter()
        .map(|m| {
            if m.usable() {
                1.0 / var(m, opts.floor)
            } else {
                0.0
            }
        })
        .collect();
    let b0: Vec<f64> = (0..n)
        .map(|k| match relative.get(k) {
            Some(r) if k > 0 && r.usable() => 1.0 / var(r, opts.relative_floor),
            _ => 0.0,
        })
        .collect();
    // Frames of a chain with no probe measurement anywhere are held, weakly,
    // at the walk's median so the system stays solvable.
    let mut lums: Vec<f64> = measured
        .iter()
        .filter(|m| m.usable())
        .map(|m| m.log_luminance_gain)
        .collect();
    let mut sig: Vec<f64> = measured
        .iter()
        .filter(|m| m.usable())
        .map(|m| m.sigma)
        .collect();
    let mut per: Vec<Vec<f64>> = (0..3)
        .map(|c| {
            measured
                .iter()
                .filter(|m| m.usable())
                .map(|m| m.log_gain[c])
                .collect()
        })
        .collect();
    let prior: Vec<f64> = per.iter_mut().map(|v| median(v)).collect();
    let mut gain = vec![[f32::NAN; 3]; n];
    let mut sigma = vec![f64::INFINITY; n];
    let mut down = vec![false; n];
    for c in 0..3 {
        let p: Vec<f64> = measured.iter().map(|m| m.log_gain[c]).collect();
        let r: Vec<f64> = (0..n)
            .map(|k| relative.get(k).map_or(0.0, |m| m.log_gain[c]))
            .collect();
        let (mut a, mut b) = (a0.clone(), b0.clone());
        let mut x = vec![0.0f64; n];
        for _ in 0..6 {
            x = solve_chain(&a, &b, &p, &r, prior[c]);
            // Reweight: residuals beyond HUBER sigmas pull as if at HUBER.
            for k in 0..n {
                if a0[k] > 0.0 {
                    let e = (x[k] - p[k]).abs() * a0[k].sqrt();
                    a[k] = a0[k] * if e > HUBER { HUBER / e } else { 1.0 };
                }
                if k > 0 && b0[k] > 0.0 {
                    let e = (x[k] - x[k - 1] - r[k]).abs() * b0[k].sqrt();
                    b[k] = b0[k] * if e > HUBER { HUBER / e } else { 1.0 };
                }
            }
        }
        for k in 0..n {
            gain[k][c] = x[k].exp() as f32;
            if c == 1 {
                let prec = a[k] + b[k] + b.get(k + 1).copied().unwrap_or(0.0);
                sigma[k] = if prec > 0.0 {
                    prec.sqrt().recip()
                } else {
                    f64::INFINITY
                };
                down[k] = a0[k] > 0.0 && a[k] < 0.999 * a0[k];
            }
        }
    }
    let noise = median(&mut sig);
    let spread = iqr(&mut lums);
    let solved: Vec<f64> = gain
        .iter()
        .map(|g| {
            (0.2126 / g[0] as f64 + 0.7152 / g[1] as f64 + 0.0722 / g[2] as f64)
                .recip()
                .ln()
        })
        .filter(|v| v.is_finite())
        .collect();
    let swing_ev = if solved.is_empty() {
        0.0
    } else {
        let (lo, hi) = solved
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        (hi - lo) / std::f64::consts::LN_2
    };
    WalkExposure {
        swing_ev,
        measured: measured.to_vec(),
        relative: relative.to_vec(),
        gain,
        sigma,
        outliers: (0..n).filter(|&k| down[k]).collect(),
        filled: (0..n).filter(|&k| a0[k] == 0.0).collect(),
        spread_over_noise: if noise > 0.0 { spread / noise } else { 0.0 },
        response_fit: Vec::new(),
        vignetting: None,
    }
}

/// Minimises `sum a[k] (x[k] - p[k])^2 + sum b[k] (x[k] - x[k-1] - r[k])^2`
/// (plus a 1e-9 pull towards `prior`, so a chain with no `a` stays solvable):
/// a tridiagonal system, solved by forward elimination.
fn solve_chain(a: &[f64], b: &[f64], p: &[f64], r: &[f64], prior: f64) -> Vec<f64> {
    let n = a.len();
    let eps = 1e-9;
    let mut diag = vec![0.0f64; n];
    let mut rhs = vec![0.0f64; n];
    for k in 0..n {
        let pk = if a[k] > 0.0 { p[k] } else { 0.0 };
        diag[k] = a[k] + eps;
        rhs[k] = a[k] * pk + eps * prior;
        if k > 0 && b[k] > 0.0 {
            diag[k] += b[k];
            rhs[k] += b[k] * r[k];
        }
        if k + 1 < n && b[k + 1] > 0.0 {
            diag[k] += b[k + 1];
            rhs[k] -= b[k + 1] * r[k + 1];
        }
    }
    // Off-diagonal between k-1 and k: -b[k]. Thomas algorithm.
    let mut c = vec![0.0f64; n];
    let mut d = vec![0.0f64; n];
    for k in 0..n {
        let off = if k > 0 { -b[k] } else { 0.0 };
        let den = diag[k] - if k > 0 { off * c[k - 1] } else { 0.0 };
        let up = if k + 1 < n { -b[k + 1] } else { 0.0 };
        c[k] = up / den;
        d[k] = (rhs[k] - if k > 0 { off * d[k - 1] } else { 0.0 }) / den;
    }
    let mut x = vec![0.0f64; n];
    for k in (0..n).rev() {
        x[k] = d[k] - if k + 1 < n { c[k] * x[k + 1] } else { 0.0 };
    }
    x
}

/// Every frame's exposure and white balance against its nearest probe, then the
/// walk pass. Fails with an error naming the scene when no frame has a
/// well-exposed block seen by a probe.
pub fn walk_exposure(scene: &Scene, opts: &ExposureOptions) -> Result<WalkExposure> {
    let mut probes: Vec<Option<HdrImage>> = vec![None; scene.probes.len()];
    let mut measured = Vec::with_capacity(scene.frames.len());
    let mut relative = Vec::with_capacity(scene.frames.len());
    let mut distances = Vec::with_capacity(scene.frames.len());
    let mut levels = Vec::with_capacity(scene.frames.len());
    let mut rims = Vec::with_capacity(scene.frames.len());
    let mut before: Option<(HdrImage, Option<HdrImage>, crate::scene::Pose)> = None;
    let decode: Vec<f32> = (0..256)
        .map(|c| scene.response.decode(c as f32 / 255.0))
        .collect();
    let (lo, hi) = (opts.blocks.low_code, opts.blocks.high_code);
    for f in &scene.frames {
        let sdr = io::read_sdr(&f.sdr)?;
        // The frame before, decoded (badly exposed pixels NaN, so no block
        // holding one votes) and turned into this frame's orientation.
        relative.push(match &before {
            Some((prev, codes, pose))
                if prev.width() == sdr.width() && prev.height() == sdr.height() =>
            {
                let r = f.pose.from_other(pose);
                let turned = rotate(prev, r, sdr.width(), sdr.height());
                let turned = match codes {
                    Some(codes) => {
                        let codes = rotate(codes, r, sdr.width(), sdr.height());
                        follow_flow(&sdr, &codes, &turned)?
                    }
                    None => turned,
                };
                frame_exposure(&sdr, &turned, &scene.response, opts)
            }
            _ => FrameExposure::missing(),
        });
        let dec = HdrImage::from_fn(sdr.width(), sdr.height(), |x, y| {
            let c = sdr.get(x, y);
            if c.iter().all(|&v| v >= lo && v <= hi) {
                c.map(|v| decode[v as usize])
            } else {
                [f32::NAN; 3]
            }
        });
        // The codes as floats, for the flow only.
        let codes = opts.follow_flow.then(|| {
            HdrImage::from_fn(sdr.width(), sdr.height(), |x, y| {
                sdr.get(x, y).map(|v| v as f32)
            })
        });
        before = Some((dec, codes, f.pose));
        let (turned, k) = nearest_probe_in_frame(scene, f, &mut probes, sdr.width(), sdr.height())?;
        // The probe as the frame's codes at the walk's gain, for the flow only.
        let turned = if opts.follow_flow {
            let g = scene.path_gain;
            let codes = HdrImage::from_fn(turned.width(), turned.height(), |x, y| {
                turned
                    .get(x, y)
                    .map(|v| 255.0 * scene.response.encode(v * g))
            });
            follow_flow(&sdr, &codes, &turned)?
        } else {
            turned
        };
        let (mut m, lv, rv) = exposure_and_levels(&sdr, &turned, &scene.response, opts);
        levels.push(lv);
        rims.push(rv);
        distances.push(f.pose.position.distance(scene.probes[k].pose.position) as f64);
        m.sigma = m.sigma.max(opts.floor);
        measured.push(m);
    }
    // Parallax grows with the distance from the probe: a frame twice the walk's
    // median distance from its probe is trusted half as much in sigma (the
    // ratio keeps it free of the poses' unit).
    let mut sorted = distances.clone();
    let reference = median(&mut sorted);
    if reference > 0.0 && reference.is_finite() {
        for (m, d) in measured.iter_mut().zip(&distances) {
            m.sigma *= 1.0 + opts.parallax * d / reference;
        }
    }
    if !measured.iter().any(FrameExposure::usable) {
        return Err(Error::Invalid(format!(
            "{} (scene {}): none of its {} frames has a well-exposed region a probe also sees \
             (every one clipped or dark there), so no frame's exposure can be measured against the \
             probes; run without --frame-exposure and give the gain in the manifest",
            scene.root.display(),
            scene.name,
            scene.frames.len()
        )));
    }
    // The lens falloff, the same in every frame, out of each frame's probe
    // measurement. The frame-to-frame steps are left as they are: the frame
    // before is turned into this frame's axes, so the falloffs cancel only as
    // far as the camera did not turn between them (a step is a small turn).
    // It is achromatic: every channel moves by the luminance's shift.
    let vignetting = opts.vignetting.then(|| super::vignetting::fit(&rims));
    if let Some(k) = vignetting {
        for (m, votes) in measured.iter_mut().zip(&rims) {
            if m.usable() {
                let shift = super::vignetting::frame_median(votes, k)
                    - super::vignetting::frame_median(votes, 0.0);
                if shift.is_finite() {
                    m.log_luminance_gain += shift;
                    for v in m.log_gain.iter_mut() {
                        *v += shift;
                    }
                }
            }
        }
    }
    let mut w = along_walk(&measured, &relative, opts);
    w.response_fit = response_fit(&levels, &w.gain, lo, hi);
    w.vignetting = vignetting;
    Ok(w)
}

/// `prev` (the frame before, decoded, in this frame's orientation) moved onto
/// `sdr` along the optical flow from `sdr` to `prev_codes` (the frame before's
/// codes, turned the same way): each pixel then compares with what the frame
/// before saw of the same surface.
fn follow_flow(sdr: &SdrImage, prev_codes: &HdrImage, prev: &HdrImage) -> Result<HdrImage> {
    let (w, h) = (sdr.width(), sdr.height());
    let gray = |c: [f32; 3]| (0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]).clamp(0.0, 255.0) as u8;
    let a: Vec<u8> = (0..w * h)
        .map(|i| gray(sdr.get(i % w, i / w).map(|v| v as f32)))
        .collect();
    let b: Vec<u8> = (0..w * h)
        .map(|i| gray(prev_codes.get(i % w, i / w)))
        .collect();
    let flow = crate::cv::dis_flow(&a, &b, w, h, &crate::cv::DisParams::default())?;
    Ok(HdrImage::from_fn(w, h, |x, y| {
        let i = y * w + x;
        let (fx, fy) = (flow[2 * i], flow[2 * i + 1]);
        if !(fx.is_finite() && fy.is_finite()) {
            return [f32::NAN; 3];
        }
        crate::sphere::sample_px(prev, x as f32 + 0.5 + fx, y as f32 + 0.5 + fy)
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn residuals_by_code_are_flat_for_the_right_response_and_bend_for_another() {
        // Two frames with gains 0.5 and 1 (luminance), blocks at every code
        // level; the right response leaves each block's log ratio at its frame's
        // gain, a wrong one adds a code-dependent bend (here 0.5 EV per 100 codes).
        let gain = [[0.5f32; 3], [1.0f32; 3]];
        let blocks = |bend: f64| -> Vec<Vec<(f32, f64)>> {
            gain.iter()
                .map(|g| {
                    (20..230)
                        .map(|c| {
                            let code = c as f32;
                            (
                                code,
                                (g[1] as f64).ln()
                                    + bend * (code as f64 - 20.0) / 100.0 * std::f64::consts::LN_2,
                            )
                        })
                        .collect()
                })
                .collect()
        };
        let mut w = along_walk(
            &[frame(0.0, 0.1), frame(0.0, 0.1)],
            &[step(0.0, 0.1), step(0.0, 0.1)],
            &ExposureOptions::default(),
        );
        w.gain = gain.to_vec();
        w.response_fit = response_fit(&blocks(0.0), &w.gain, 20, 230);
        assert_eq!(w.response_fit.len(), LEVELS);
        assert!(
            w.response_fit.iter().all(|l| l.median_ev.abs() < 1e-9),
            "{:?}",
            w.response_fit
        );
        assert!(w.response_misfit_ev(10) < 1e-9);
        w.response_fit = response_fit(&blocks(0.5), &w.gain, 20, 230);
        let spread = w.response_misfit_ev(10);
        assert!(
            (spread - 0.5 * 175.0 / 100.0).abs() < 0.1,
            "spread {spread}"
        );
    }

    #[test]
    fn the_frame_before_moved_along_the_flow_lands_on_the_same_surfaces() {
        // A textured panorama and the same one moved 3 pixels right: the frame
        // before, moved along the flow, must give back this frame's values.
        let (w, h) = (128, 64);
        let tex = |x: f32, y: f32| {
            128.0 + 60.0 * (x * 0.31).sin() * (y * 0.23).cos() + 30.0 * (0.17 * (x + y)).sin()
        };
        let codes: Vec<u8> = (0..w * h)
            .flat_map(|i| [tex((i % w) as f32, (i / w) as f32) as u8; 3])
            .collect();
        let now = SdrImage::from_vec(w, h, codes).unwrap();
        let before = HdrImage::from_fn(w, h, |x, y| {
            let v = tex(x as f32 - 3.0, y as f32).round();
            [v, v, v]
        });
        let moved = follow_flow(&now, &before, &before).unwrap();
        let (mut err, mut err_rotated, mut n) = (0.0f64, 0.0f64, 0);
        for y in 16..48 {
            for x in 16..112 {
                let c = now.get(x, y)[0] as f64;
                err += (moved.get(x, y)[0] as f64 - c).abs();
                err_rotated += (before.get(x, y)[0] as f64 - c).abs();
                n += 1;
            }
        }
        let (err, err_rotated) = (err / n as f64, err_rotated / n as f64);
        assert!(
            err < 0.25 * err_rotated,
            "moved along the flow: {err:.2} codes off, unmoved {err_rotated:.2}"
        );
        assert!(err < 3.0, "moved along the flow: {err:.2} codes off");
    }

    fn frame(log: f64, sigma: f64) -> FrameExposure {
        FrameExposure {
            log_gain: [log + 0.1, log, log - 0.1],
            log_luminance_gain: log,
            sigma,
            blocks: 50,
        }
    }

    #[test]
    fn a_constant_frame_against_a_constant_probe_gives_their_ratio_per_channel() {
        let c = [100u8, 128, 160];
        let sdr = SdrImage::from_vec(32, 16, c.repeat(32 * 16)).unwrap();
        let probe = HdrImage::from_fn(32, 16, |_, _| [0.5, 0.25, 0.125]);
        let r = Response::Srgb;
        let e = frame_exposure(&sdr, &probe, &r, &ExposureOptions::default());
        // 32 wide: blocks of 2 pixels (5.6 degrees is under one).
        assert_eq!(e.blocks, 16 * 8);
        for (k, p) in [0.5f64, 0.25, 0.125].iter().enumerate() {
            let want = (r.decode(c[k] as f32 / 255.0) as f64 / p).ln();
            assert!(
                (e.log_gain[k] - want).abs() < 1e-6,
                "{k}: {} vs {want}",
                e.log_gain[k]
            );
        }
        assert_eq!(e.sigma, ExposureOptions::default().floor);
        // All clipped: nothing measured.
        let sdr = SdrImage::from_vec(32, 16, vec![255; 32 * 16 * 3]).unwrap();
        let e = frame_exposure(&sdr, &probe, &r, &ExposureOptions::default());
        assert!(!e.usable());
    }

    fn step(d: f64, sigma: f64) -> FrameExposure {
        FrameExposure {
            log_gain: [d; 3],
            log_luminance_gain: d,
            sigma,
            blocks: 50,
        }
    }

    /// A walk of `n` frames whose true log gain is `truth(k)`, measured
    /// against the probes with `probe_err(k)` added and frame to frame exactly.
    fn walk(
        n: usize,
        truth: impl Fn(usize) -> f64,
        probe_err: impl Fn(usize) -> f64,
    ) -> WalkExposure {
        let m: Vec<FrameExposure> = (0..n)
            .map(|k| frame(truth(k) + probe_err(k), 0.05))
            .collect();
        let r: Vec<FrameExposure> = (0..n)
            .map(|k| step(if k == 0 { 0.0 } else { truth(k) - truth(k - 1) }, 0.01))
            .collect();
        along_walk(&m, &r, &ExposureOptions::default())
    }

    #[test]
    fn one_wrong_frame_is_mended_a_jump_is_kept_and_a_gap_is_filled() {
        // A smooth walk at log gain 0 whose frame 3 the probe puts 1 (1.44 EV)
        // off: the frame-to-frame steps keep it with its neighbours.
        let w = walk(8, |_| 0.0, |k| if k == 3 { 1.0 } else { 0.0 });
        assert!(w.outliers.contains(&3), "{:?}", w.outliers);
        for k in 0..8 {
            assert!(
                (w.gain[k][1] as f64).ln().abs() < 0.03,
                "{k}: {:?}",
                w.gain[k]
            );
        }
        // A jump at frame 4 (the meter moved): both sides keep their level.
        let w = walk(8, |k| if k < 4 { 0.0 } else { 1.0 }, |_| 0.0);
        assert!(w.outliers.is_empty(), "{:?}", w.outliers);
        for k in 0..8 {
            let want = if k < 4 { 0.0 } else { 1.0 };
            assert!(
                ((w.gain[k][1] as f64).ln() - want).abs() < 1e-4,
                "{k}: {:?}",
                w.gain[k]
            );
        }
        // The channels keep their balance.
        assert!(((w.gain[5][0] as f64).ln() - 1.1).abs() < 1e-4);
        assert!(((w.gain[5][2] as f64).ln() - 0.9).abs() < 1e-4);
        // Probe errors that parallax makes (a bias on a stretch of the walk)
        // are spread over the walk: a 0.15 bias on 3 of 20 frames moves no
        // frame by a third of it, and the walk by a sixth of it on average.
        let w = walk(
            20,
            |k| (k as f64 * 0.3).sin() * 0.5,
            |k| if (7..10).contains(&k) { -0.15 } else { 0.0 },
        );
        let mut sum = 0.0;
        for k in 0..20 {
            let got = (w.gain[k][1] as f64).ln();
            let want = (k as f64 * 0.3).sin() * 0.5;
            assert!((got - want).abs() < 0.05, "{k}: {got} vs {want}");
            sum += (got - want).abs();
        }
        assert!(sum / 20.0 < 0.025, "{}", sum / 20.0);
        // A frame with nothing measured against its probe is carried by its
        // neighbours.
        let m: Vec<FrameExposure> = (0..4)
            .map(|k| {
                if k == 0 {
                    FrameExposure::missing()
                } else {
                    frame(0.2, 0.05)
                }
            })
            .collect();
        let r: Vec<FrameExposure> = (0..4).map(|_| step(0.0, 0.01)).collect();
        let w = along_walk(&m, &r, &ExposureOptions::default());
        assert_eq!(w.filled, vec![0]);
        assert!(
            ((w.gain[0][1] as f64).ln() - 0.2).abs() < 1e-4,
            "{:?}",
            w.gain[0]
        );
        assert!(!w.varies());
    }
}
