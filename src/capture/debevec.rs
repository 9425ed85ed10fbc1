//! Camera response recovery from exposure brackets, after Debevec & Malik 1997,
//! "Recovering High Dynamic Range Radiance Maps from Photographs" (SIGGRAPH 97).
//!
//! A pixel of radiance `E_i` photographed for `Δt_j` seconds stores the code
//! `Z_ij = f(E_i Δt_j)`. With `g = ln f⁻¹`, every unclipped observation gives one
//! linear equation `g(Z_ij) = ln E_i + ln Δt_j`. Per colour channel we minimise
//!
//! ```text
//!   α Σ_ij [w(Z_ij) (g(Z_ij) − ln E_i − ln Δt_j)]²  +  λ Σ_{z=1}^{254} [w(z) g''(z)]²
//! ```
//!
//! over the 256 values of `g` and the `N` unknown `ln E_i`, subject to
//! `g(128) = 0`, where `g''(z)` is a second difference (below) and `w` is the hat
//! weight restricted to the codes that are measurements ([`usable_hat`]; the
//! smoothness rows keep the plain [`hat_weight`]).
//!
//! **Observations.** Not every code is a measurement; the recovery and the merge
//! share one model of which are ([`Bracket`]). Clipped codes (≥ [`CLIP_CODE`],
//! or ≥ [`NEAR_CLIP_CODE`] next to a clipped sample: JPEG softens a saturated
//! 255 by up to ~25 codes near an edge and mixes the channels) and every longer
//! exposure of the same channel (a sensor is monotone) are left out, as are codes
//! at or below the channel's noise floor and every shorter exposure. Left in, the
//! softened clipped codes pull `g` up by 0.5–2 near the top (where the clamp
//! value `g(255)` of a clipped sun comes from), and black read noise bends `g`
//! at the bottom. The floor is measured on the bracket
//! ([`Bracket::estimate_noise_floor`]) with a first curve fitted with only code 0
//! treated as dark; when it finds one, the curve is fitted again without the
//! noise ([`Recovery::noise_floor`]). Codes without data — below the floor, from
//! the near-clip band up, 255 — are extrapolated along a power law by the
//! smoothness term. `α = 256 / Σ w²` normalises the data term so that it
//! weighs about one per code whatever the number of samples, which makes `λ`
//! independent of `N` (the paper's `λ` multiplies the squared term; its `gsolve`
//! listing multiplies the rows, i.e. uses `√λ`, and does not normalise).
//!
//! **Smoothness.** The paper's `g(z−1) − 2 g(z) + g(z+1)` vanishes on straight
//! lines `g = p + q z`, i.e. on an *exponential* response, so wherever the data
//! are silent — codes no pixel shows, the toe and shoulder where the hat weight
//! fades, or every code when `λ` is large — it bends the curve towards an
//! exponential (continuing `g = 2.2 ln z`, a gamma curve, in a straight line
//! from code 20 down to code 1 lands 4.5 too high). Here `g''` is the second
//! difference against `ln z` instead, `g''(z) = a_z g(z−1) − 2 g(z) + b_z g(z+1)`
//! with `a_z + b_z = 2` (`a_z ≈ 1 − 1/2z`, `b_z ≈ 1 + 1/2z`), which vanishes on
//! `g = p + q ln z`: a power law `f⁻¹(z) ∝ z^q`, the shape of real responses
//! (gamma curves). It differs from the paper's row by `O(1/z)`, so `λ` keeps its
//! meaning; at `z = 1` (where `ln 0` is undefined) the paper's row is used.
//!
//! **Solver.** The `ln E_i` are eliminated exactly (for a fixed `g` each is a
//! weighted mean), which leaves a dense symmetric 255 × 255 system in `g` (the
//! Schur complement, `g(128)` removed by the constraint) whatever `N` is. It is
//! assembled in `f64`, symmetrically scaled to a unit diagonal (Jacobi
//! conditioning), factored by a Cholesky decomposition written here, and polished
//! by two steps of iterative refinement. A tiny smoothness floor
//! ([`SMOOTHNESS_FLOOR`], unweighted) keeps the system definite for any `λ ≥ 0`,
//! including `λ = 0`, by interpolating (or extrapolating along a power law) the
//! codes the samples never show. Codes 0 and 255 have no data, so they are set by
//! the smoothness rows of codes 1 and 254 alone: extrapolated from their two
//! neighbours.
//!
//! **Samples.** Pixels are stratified by the sum of their codes over all exposures
//! — a monotone function of radiance, so the strata span the scene's whole dynamic
//! range rather than one exposure's — and drawn pseudo-randomly (spread over the
//! image) within each stratum, preferring pixels in flat neighbourhoods (small
//! 4-neighbour contrast in their best exposure), so a slight misregistration or
//! JPEG ringing does not corrupt the equations. Pixels whose usable codes fall by
//! more than a few levels as the exposure grows (moving content) and pixels with
//! fewer than two usable exposures (no information) are rejected.
//!
//! **Monotonicity.** A response is non-decreasing; noise or scarce data can make
//! the least-squares `g` dip. A final weighted isotonic regression (pool adjacent
//! violators) repairs that, and [`Recovery::monotone_fixes`] reports how many
//! codes it had to move.

use crate::error::{Error, Result};
use crate::image::censor::{Censor, Reading};
use crate::image::{HdrImage, SdrImage};
use crate::tonemap::Response;
use rayon::prelude::*;
use std::path::Path;

/// Number of 8-bit codes.
pub const CODES: usize = 256;
/// The code whose log exposure is pinned to 0 (`g(128) = 0`).
pub const ANCHOR_CODE: usize = 128;
/// Default smoothness weight `λ` (see the module docs for its normalisation).
pub const DEFAULT_LAMBDA: f64 = 10.0;
/// Default number of sampled pixel locations per channel.
pub const DEFAULT_SAMPLES: usize = 2000;
/// Unweighted smoothness always added so the system stays definite for `λ = 0`.
pub const SMOOTHNESS_FLOOR: f64 = 1e-6;
/// A pixel whose code drops by more than this as the exposure grows is taken to
/// have moved between exposures and is not sampled.
pub const MOTION_TOLERANCE: u8 = 6;
/// Number of radiance strata the samples are drawn from.
const STRATA: usize = 64;

/// Debevec & Malik's hat weight, scaled to `[0, 1]`: 0 at codes 0 and 255 (no
/// information: clipped), 1 at mid-grey, linear in between.
#[inline]
pub fn hat_weight(z: u8) -> f64 {
    let z = z as f64;
    if z <= 127.5 {
        z / 127.5
    } else {
        (255.0 - z) / 127.5
    }
}

/// Codes at or above this are *possibly* clipped when some sample (any channel)
/// of the same frame within one pixel is clipped: JPEG bleeding
/// ([`crate::image::censor::BLEED_CODE`]).
pub use crate::image::censor::BLEED_CODE as NEAR_CLIP_CODE;
/// Codes at or above this are clipped ([`crate::image::censor`], which defines
/// clipping for all of lumiprobe).
pub use crate::image::censor::CLIP_CODE;
/// An observation is noise, not a measurement, when its typical log error
/// against a well-exposed frame of the same pixel exceeds this (a signal-to-noise
/// ratio below about 2): the codes of such exposures are dominated by read noise,
/// cut off at code 0, and their logarithm is biased upwards. See
/// [`Bracket::estimate_noise_floor`].
pub const NOISE_LOG_ERROR: f64 = 0.5;
/// The lowest code of a reference observation in the noise-floor estimate: any
/// usable camera records mid-grey far above its noise.
const REFERENCE_CODE: usize = 128;
/// Observations a predicted code needs (pooled over ±2 codes) to be judged.
const FLOOR_MIN_SAMPLES: usize = 16;
/// At most this many pixels are visited by the noise-floor estimate.
const FLOOR_MAX_PIXELS: usize = 1 << 16;

/// A bracket's frames sorted by exposure time, with the observation model that
/// response recovery and the merge share:
///
/// * **Clipped** observations: code ≥ [`CLIP_CODE`], or ≥ [`NEAR_CLIP_CODE`] next to
///   a clipped sample of the same frame. The sensor is monotone, so a channel
///   clipped at one exposure is clipped at every longer one, whatever code JPEG
///   left there: every frame from the first clipped one on is unusable.
/// * **Dark** observations: code at or below the channel's noise floor (code 0
///   at least). Symmetrically, every frame up to the last dark one is noise.
///
/// [`Bracket::usable`] gives the frames in between; the rest are bounds.
pub struct Bracket<'a> {
    frames: Vec<&'a [u8]>,
    ln_t: Vec<f64>,
    /// Per sorted frame, the range of sorted frames sharing its exposure time.
    group: Vec<(usize, usize)>,
    /// Per sorted frame and pixel: a sample within one pixel is ≥ [`CLIP_CODE`].
    near_clip: Vec<Vec<bool>>,
    /// Per channel: codes at or below this are noise.
    floor: [u8; 3],
}

impl<'a> Bracket<'a> {
    /// `frames` (RGB, `width` wide) with their exposure times in seconds, sorted
    /// here by time (stable for equal times); the noise floor starts at 0.
    pub fn new(frames: &[&'a [u8]], times: &[f64], width: usize) -> Self {
        let mut order: Vec<usize> = (0..frames.len()).collect();
        order.sort_by(|&a, &b| times[a].total_cmp(&times[b]));
        let sorted: Vec<&[u8]> = order.iter().map(|&j| frames[j]).collect();
        let t: Vec<f64> = order.iter().map(|&j| times[j]).collect();
        let p = sorted.len();
        let mut group = vec![(0, 0); p];
        let mut a = 0;
        while a < p {
            let b = (a + 1..p)
                .find(|&j| t[j] > t[a] * (1.0 + 1e-9))
                .unwrap_or(p);
            group[a..b].fill((a, b));
            a = b;
        }
        let near_clip = sorted
            .par_iter()
            .map(|f| Censor::default().near_clipped(f, width))
            .collect();
        Bracket {
            frames: sorted,
            ln_t: t.iter().map(|v| v.ln()).collect(),
            group,
            near_clip,
            floor: [0; 3],
        }
    }

    /// The frames, shortest exposure first.
    pub fn frames(&self) -> &[&'a [u8]] {
        &self.frames
    }

    /// `ln Δt` of the sorted frames.
    pub fn ln_t(&self) -> &[f64] {
        &self.ln_t
    }

    /// The range of sorted frames that share frame `j`'s exposure time.
    pub fn group(&self, j: usize) -> (usize, usize) {
        self.group[j]
    }

    /// Per channel, the highest code treated as noise.
    pub fn noise_floor(&self) -> [u8; 3] {
        self.floor
    }

    /// Sets the noise floor (codes at or below are noise; 0 = only black).
    pub fn set_noise_floor(&mut self, floor: [u8; 3]) {
        self.floor = floor;
    }

    /// Code of sorted frame `j` at pixel `i`, channel `c`.
    #[inline]
    pub fn code(&self, j: usize, i: usize, c: usize) -> u8 {
        self.frames[j][3 * i + c]
    }

    /// Whether sample (`j`, `i`, `c`) is clipped or possibly clipped (type docs).
    #[inline]
    pub fn clipped(&self, j: usize, i: usize, c: usize) -> bool {
        let z = self.code(j, i, c);
        Censor::default().reading(z, self.near_clip[j][i]) != Reading::Measured
    }

    /// The usable sorted frames `lo..hi` of pixel `i`, channel `c`: after the
    /// last dark frame (and every frame of its exposure time) and before the
    /// first clipped one (likewise). `hi == 0`: clipped even in the darkest
    /// exposure; `lo == len`: dark even in the brightest. `lo <= hi` always.
    pub fn usable(&self, i: usize, c: usize) -> (usize, usize) {
        let p = self.frames.len();
        let hi = (0..p)
            .find(|&j| self.clipped(j, i, c))
            .map_or(p, |j| self.group[j].0);
        let floor = self.floor[c];
        let lo = (0..hi)
            .rev()
            .find(|&j| self.code(j, i, c) <= floor)
            .map_or(0, |j| self.group[j].1);
        (lo, hi)
    }

    /// Estimates each channel's noise floor with the response `g` (and stores
    /// it): the highest code below [`REFERENCE_CODE`] whose observations are
    /// noise by [`NOISE_LOG_ERROR`].
    ///
    /// For a pixel, the longest usable exposure whose code is in
    /// `REFERENCE_CODE..NEAR_CLIP_CODE` is the reference: well above any noise,
    /// below any clipping. It predicts the exposure of every shorter frame of the
    /// pixel exactly (the ratio of the times), hence the code `ẑ` that frame
    /// would show without noise. The error of the frame's observation is
    /// `d = g(Z) − ln Δt − (g(Z_ref) − ln Δt_ref)`. Grouped by the *predicted* code
    /// (the true exposure, not the noisy observed one, so a uniform dark wall
    /// still shows its noise), the typical error is `1.4826 · median |d|` (the
    /// standard deviation for Gaussian errors, robust to misregistered pixels),
    /// pooled over `ẑ ± 2`. The floor is the highest `ẑ` where it exceeds
    /// [`NOISE_LOG_ERROR`] on at least [`FLOOR_MIN_SAMPLES`] observations, or 0
    /// when no code does (or the bracket never shows such exposures). It is
    /// measured on the bracket itself, so it follows the camera, its ISO and its
    /// JPEG settings; no noise model is assumed.
    pub fn estimate_noise_floor(&mut self, g: &[[f64; CODES]; 3]) -> [u8; 3] {
        self.floor = [0; 3];
        let n = self.frames.first().map_or(0, |f| f.len() / 3);
        let stride = n.div_ceil(FLOOR_MAX_PIXELS).max(1);
        let this = &*self;
        let floors: Vec<u8> = (0..3)
            .into_par_iter()
            .map(|c| {
                let gc = &g[c];
                let mut buckets: Vec<Vec<f32>> = vec![Vec::new(); REFERENCE_CODE];
                for i in (0..n).step_by(stride) {
                    let (lo, hi) = this.usable(i, c);
                    let Some(k) = (lo..hi).rev().find(|&j| {
                        let z = this.code(j, i, c) as usize;
                        (REFERENCE_CODE..NEAR_CLIP_CODE as usize).contains(&z)
                            && !this.near_clip[j][i]
                    }) else {
                        continue;
                    };
                    let v_ref = gc[this.code(k, i, c) as usize] - this.ln_t[k];
                    for j in 0..this.group[k].0 {
                        let pred = v_ref + this.ln_t[j];
                        let zh = gc.partition_point(|&v| v < pred).min(CODES - 1);
                        let zh = if zh > 0 && pred - gc[zh - 1] < gc[zh] - pred {
                            zh - 1
                        } else {
                            zh
                        };
                        if zh >= REFERENCE_CODE {
                            continue;
                        }
                        let d = gc[this.code(j, i, c) as usize] - pred;
                        buckets[zh].push(d as f32);
                    }
                }
                let mut floor = 0u8;
                let mut pool: Vec<f32> = Vec::new();
                for z in (1..REFERENCE_CODE).rev() {
                    pool.clear();
                    for b in &buckets[z.saturating_sub(2)..(z + 3).min(REFERENCE_CODE)] {
                        pool.extend_from_slice(b);
                    }
                    if pool.len() < FLOOR_MIN_SAMPLES {
                        continue;
                    }
                    for v in pool.iter_mut() {
                        *v = v.abs();
                    }
                    let mid = pool.len() / 2;
                    let med = *pool.select_nth_unstable_by(mid, f32::total_cmp).1 as f64;
                    if 1.4826 * med > NOISE_LOG_ERROR {
                        floor = z as u8;
                        break;
                    }
                }
                floor
            })
            .collect();
        self.floor = [floors[0], floors[1], floors[2]];
        self.floor
    }
}

/// The hat weight restricted to the usable codes of a channel whose noise floor
/// is `floor`: zero at and below the floor and from [`CLIP_CODE`] on, rising
/// linearly from the floor and falling linearly to [`CLIP_CODE`], scaled like
/// [`hat_weight`] (slope 1/127.5). With `floor = 0` it is the paper's hat with
/// its top end moved from 255 to [`CLIP_CODE`].
#[inline]
pub fn usable_hat(z: u8, floor: u8) -> f64 {
    if z <= floor || z >= CLIP_CODE {
        return 0.0;
    }
    (z - floor).min(CLIP_CODE - z) as f64 / 127.5
}

/// A per-channel camera response as log exposure per code, `g[c][z] = ln f⁻¹(z)`.
///
/// A recovered curve is known up to a factor (it is anchored at `g(128) = 0` in
/// every channel), so radiance merged with it is relative. Saved as JSON
/// (`{"g": [[256 numbers] x 3], "lambda": .., "samples": ..}`) so the SDR frames
/// of the same camera can be linearised later ([`ResponseCurve::linearize`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "CurveFile", into = "CurveFile")]
pub struct ResponseCurve {
    /// Log exposure `ln f⁻¹(z)` for each channel (R, G, B) and code; finite and
    /// non-decreasing in `z`.
    pub g: [[f64; CODES]; 3],
    /// Smoothness weight the curve was recovered with (0 for a given curve).
    pub lambda: f64,
    /// Pixel locations sampled per channel (0 for a given curve).
    pub samples: usize,
}

/// The JSON form of a [`ResponseCurve`] (serde does not derive 256-arrays).
#[derive(Clone, serde::Serialize, serde::Deserialize)]
struct CurveFile {
    g: Vec<Vec<f64>>,
    lambda: f64,
    samples: usize,
}

impl From<ResponseCurve> for CurveFile {
    fn from(c: ResponseCurve) -> Self {
        CurveFile {
            g: c.g.iter().map(|ch| ch.to_vec()).collect(),
            lambda: c.lambda,
            samples: c.samples,
        }
    }
}

impl TryFrom<CurveFile> for ResponseCurve {
    type Error = String;
    fn try_from(f: CurveFile) -> std::result::Result<Self, String> {
        if f.g.len() != 3 {
            return Err(format!("`g` has {} channels, expected 3", f.g.len()));
        }
        let mut g = [[0.0; CODES]; 3];
        for (c, ch) in f.g.iter().enumerate() {
            if ch.len() != CODES {
                return Err(format!(
                    "`g[{c}]` has {} values, expected {CODES}",
                    ch.len()
                ));
            }
            g[c].copy_from_slice(ch);
        }
        let curve = ResponseCurve {
            g,
            lambda: f.lambda,
            samples: f.samples,
        };
        curve.check().map(|_| curve)
    }
}

impl ResponseCurve {
    /// Tabulates a parametric [`Response`] in every channel (`g = ln decode(z/255)`;
    /// code 0, whose exposure is 0, is extrapolated linearly from codes 1 and 2).
    pub fn from_response(r: &Response) -> Self {
        let mut ch = [0.0f64; CODES];
        for (z, v) in ch.iter_mut().enumerate().skip(1) {
            *v = (r.decode(z as f32 / 255.0) as f64).max(1e-30).ln();
        }
        ch[0] = 2.0 * ch[1] - ch[2];
        for z in 1..CODES {
            ch[z] = ch[z].max(ch[z - 1]);
        }
        ResponseCurve {
            g: [ch; 3],
            lambda: 0.0,
            samples: 0,
        }
    }

    /// The response documented for the evaluation data,
    /// `f(x) = min(1, 1.08 x^(1/2.2) / (1 + 0.08 x^(1/2.2)))`.
    pub fn documented() -> Self {
        Self::from_response(&Response::RationalGamma {
            scale: 1.08,
            knee: 0.08,
            gamma: 2.2,
        })
    }

    /// Relative linear exposure `f⁻¹(z) = exp g(z)` of code `z` in channel `c`.
    #[inline]
    pub fn linear(&self, c: usize, z: u8) -> f64 {
        self.g[c][z as usize].exp()
    }

    /// Channel `c` as a [`Response::Table`], for code that takes a single curve
    /// (the table is the relative exposure `exp g(z)` per code).
    pub fn to_table(&self, c: usize) -> Response {
        Response::Table {
            linear: self.g[c.min(2)].iter().map(|v| v.exp() as f32).collect(),
        }
    }

    /// Linear radiance of an SDR frame exposed for `time_s` seconds:
    /// `exp g(z) / time_s` per channel (codes 255 give a lower bound).
    pub fn linearize(&self, img: &SdrImage, time_s: f64) -> Result<HdrImage> {
        if !(time_s.is_finite() && time_s > 0.0) {
            return Err(Error::Invalid(format!(
                "exposure time {time_s} s is not a positive number"
            )));
        }
        let lut: Vec<[f32; CODES]> = (0..3)
            .map(|c| {
                let mut t = [0.0f32; CODES];
                for (z, v) in t.iter_mut().enumerate() {
                    *v = (self.g[c][z].exp() / time_s) as f32;
                }
                t
            })
            .collect();
        let data = img
            .data()
            .chunks_exact(3)
            .flat_map(|p| {
                [
                    lut[0][p[0] as usize],
                    lut[1][p[1] as usize],
                    lut[2][p[2] as usize],
                ]
            })
            .collect();
        HdrImage::from_vec(img.width(), img.height(), data)
    }

    /// Checks that every channel is finite and non-decreasing and `λ` is valid.
    fn check(&self) -> std::result::Result<(), String> {
        if !(self.lambda.is_finite() && self.lambda >= 0.0) {
            return Err(format!(
                "`lambda` {} is not a finite number >= 0",
                self.lambda
            ));
        }
        for (c, ch) in self.g.iter().enumerate() {
            if let Some(z) = ch.iter().position(|v| !v.is_finite()) {
                return Err(format!("`g[{c}][{z}]` is not finite"));
            }
            if let Some(z) = (1..CODES).find(|&z| ch[z] < ch[z - 1]) {
                return Err(format!(
                    "`g[{c}]` decreases at code {z} ({} < {}): a response must be monotone",
                    ch[z],
                    ch[z - 1]
                ));
            }
        }
        Ok(())
    }

    /// Validates the curve (finite, monotone), naming `path` in the error.
    pub fn validate(&self, path: &Path) -> Result<()> {
        self.check().map_err(|m| Error::format(path, m))
    }

    /// Loads a curve saved by [`ResponseCurve::save`], validating it.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = crate::fsutil::read(path)?;
        serde_json::from_slice(&bytes)
            .map_err(|e| Error::format(path, format!("not a response curve: {e}")))
    }

    /// Writes the curve as pretty JSON, atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        self.validate(path)?;
        let text = serde_json::to_vec_pretty(self)
            .map_err(|e| Error::format(path, format!("cannot serialise the curve: {e}")))?;
        crate::fsutil::write_atomic(path, &text)
    }
}

/// Settings of [`recover`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecoverOptions {
    /// Smoothness weight `λ ≥ 0` (module docs).
    pub lambda: f64,
    /// Pixel locations to sample per channel.
    pub samples: usize,
    /// Seed of the pseudo-random choice within strata (results are deterministic).
    pub seed: u64,
}

impl Default for RecoverOptions {
    fn default() -> Self {
        RecoverOptions {
            lambda: DEFAULT_LAMBDA,
            samples: DEFAULT_SAMPLES,
            seed: 1,
        }
    }
}

/// A recovered response and how the recovery went.
#[derive(Clone, Debug, PartialEq)]
pub struct Recovery {
    /// The curve.
    pub curve: ResponseCurve,
    /// Codes per channel that the final monotone (isotonic) pass had to move;
    /// non-zero means the least-squares curve was not monotone there.
    pub monotone_fixes: [usize; 3],
    /// Pixel locations actually sampled per channel.
    pub samples_used: [usize; 3],
    /// Independent data equations per channel (observations minus one per sample),
    /// to compare with the 255 free unknowns of `g`.
    pub equations: [usize; 3],
    /// Weighted RMS residual of the data equations per channel (in ln units).
    pub rms_residual: [f64; 3],
    /// Per channel, the highest code treated as noise (measured on the bracket,
    /// [`Bracket::estimate_noise_floor`]; 0 = only black).
    pub noise_floor: [u8; 3],
    /// Things a user should know (few samples, monotone repairs, ...).
    pub warnings: Vec<String>,
}

/// Recovers the response of each channel from exposures of one static scene
/// (`images[j]` taken for `times[j]` seconds, any order). Needs at least two
/// distinct exposure times and same-sized images; see the module docs.
pub fn recover(images: &[&SdrImage], times: &[f64], opts: &RecoverOptions) -> Result<Recovery> {
    if images.len() != times.len() {
        return Err(Error::Invalid(format!(
            "{} images but {} exposure times",
            images.len(),
            times.len()
        )));
    }
    let Some(first) = images.first() else {
        return Err(Error::Invalid(
            "no exposures to recover a response from".into(),
        ));
    };
    let (w, h) = (first.width(), first.height());
    if let Some((j, im)) = images
        .iter()
        .enumerate()
        .find(|(_, im)| im.width() != w || im.height() != h)
    {
        return Err(Error::Invalid(format!(
            "exposure {j} is {}x{}, exposure 0 is {w}x{h}",
            im.width(),
            im.height()
        )));
    }
    if let Some((j, t)) = times
        .iter()
        .enumerate()
        .find(|(_, t)| !(t.is_finite() && **t > 0.0))
    {
        return Err(Error::Invalid(format!(
            "exposure {j} has exposure time {t} s; it must be a positive number"
        )));
    }
    let mut order: Vec<usize> = (0..times.len()).collect();
    order.sort_by(|&a, &b| times[a].total_cmp(&times[b]));
    let distinct = order
        .windows(2)
        .filter(|p| times[p[1]] > times[p[0]] * (1.0 + 1e-9))
        .count()
        + 1;
    if distinct < 2 {
        return Err(Error::Invalid(
            "response recovery needs at least two different exposure times \
             (use the documented response or a saved curve for a single exposure)"
                .into(),
        ));
    }
    if !(opts.lambda.is_finite() && opts.lambda >= 0.0) {
        return Err(Error::Invalid(format!(
            "smoothness lambda {} must be a finite number >= 0",
            opts.lambda
        )));
    }
    if opts.samples == 0 || w * h == 0 {
        return Err(Error::Invalid(
            "response recovery needs at least one sample and a non-empty image".into(),
        ));
    }
    let data: Vec<&[u8]> = images.iter().map(|im| im.data()).collect();
    let mut bracket = Bracket::new(&data, times, w);
    // Pass 1 treats only code 0 as dark; its curve measures the noise floor
    // (`Bracket::estimate_noise_floor`), and pass 2 leaves the noise out.
    let fit_all = |bracket: &Bracket| -> Vec<Result<ChannelFit>> {
        (0..3)
            .into_par_iter()
            .map(|c| {
                let picks = select_samples(bracket, w, h, c, opts);
                fit_channel(bracket, &picks, c, opts.lambda).map_err(|m| {
                    Error::Invalid(format!(
                        "cannot recover the response of the {} channel: {m}",
                        ["red", "green", "blue"][c]
                    ))
                })
            })
            .collect()
    };
    let mut per_channel = fit_all(&bracket);
    if per_channel.iter().all(|f| f.is_ok()) {
        let mut g = [[0.0; CODES]; 3];
        for (gc, f) in g.iter_mut().zip(&per_channel) {
            if let Ok(f) = f {
                *gc = f.g;
            }
        }
        let mut floor = bracket.estimate_noise_floor(&g);
        if floor != [0; 3] {
            let second = fit_all(&bracket);
            // A channel the floor leaves without data keeps its first fit.
            for (c, fit) in second.into_iter().enumerate() {
                if fit.is_ok() {
                    per_channel[c] = fit;
                } else {
                    floor[c] = 0;
                }
            }
            bracket.set_noise_floor(floor);
        }
    }
    let mut curve = ResponseCurve {
        g: [[0.0; CODES]; 3],
        lambda: opts.lambda,
        samples: opts.samples,
    };
    let mut rec = Recovery {
        curve: curve.clone(),
        monotone_fixes: [0; 3],
        samples_used: [0; 3],
        equations: [0; 3],
        rms_residual: [0.0; 3],
        noise_floor: bracket.noise_floor(),
        warnings: Vec::new(),
    };
    for (c, fit) in per_channel.into_iter().enumerate() {
        let fit = fit?;
        let name = ["red", "green", "blue"][c];
        curve.g[c] = fit.g;
        rec.monotone_fixes[c] = fit.monotone_fixes;
        rec.samples_used[c] = fit.samples;
        rec.equations[c] = fit.equations;
        rec.rms_residual[c] = fit.rms;
        if fit.equations < 2 * (CODES - 1) {
            rec.warnings.push(format!(
                "{name} channel: only {} data equations for {} unknowns; the curve leans on \
                 smoothness (use more samples or more exposures)",
                fit.equations,
                CODES - 1
            ));
        }
        if fit.monotone_fixes > 0 {
            rec.warnings.push(format!(
                "{name} channel: the least-squares curve was not monotone; {} codes were \
                 adjusted by isotonic regression",
                fit.monotone_fixes
            ));
        }
    }
    rec.curve = curve;
    Ok(rec)
}

/// The result for one channel.
struct ChannelFit {
    g: [f64; CODES],
    monotone_fixes: usize,
    samples: usize,
    equations: usize,
    rms: f64,
}

/// SplitMix64: a deterministic hash for the pseudo-random choice of samples.
#[inline]
fn mix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

/// Chooses the pixel indices sampled for channel `c` (module docs: strata by the
/// sum of codes, flat neighbourhoods first, pseudo-random within a stratum).
fn select_samples(
    bracket: &Bracket,
    w: usize,
    h: usize,
    c: usize,
    opts: &RecoverOptions,
) -> Vec<usize> {
    let frames = bracket.frames();
    let ln_t = bracket.ln_t();
    let p = frames.len();
    let code = |j: usize, i: usize| frames[j][3 * i + c];
    // Candidates: key (sum of codes), flatness score and hash.
    let mut cands: Vec<(u32, u8, u64, usize)> = Vec::new();
    for i in 0..w * h {
        let mut key = 0u32;
        let mut moved = false;
        let mut best = 0usize;
        let mut best_d = u8::MAX;
        let (lo, hi) = bracket.usable(i, c);
        for j in 0..p {
            let z = code(j, i);
            key += z as u32;
            let d = (z as i16 - 128).unsigned_abs() as u8;
            if d < best_d {
                best_d = d;
                best = j;
            }
            // Only usable observations can betray motion: a clipped code
            // softened by JPEG may well read lower than the frame before.
            if j > lo && j < hi && ln_t[j] > ln_t[j - 1] {
                let prev = code(j - 1, i);
                if prev > z.saturating_add(MOTION_TOLERANCE) {
                    moved = true;
                }
            }
        }
        if hi < lo + 2 || moved {
            continue;
        }
        let (x, y) = (i % w, i / w);
        let z0 = code(best, i) as i16;
        let mut contrast = 0i16;
        for (nx, ny) in [
            (x.wrapping_sub(1), y),
            (x + 1, y),
            (x, y.wrapping_sub(1)),
            (x, y + 1),
        ] {
            if nx < w && ny < h {
                contrast = contrast.max((code(best, ny * w + nx) as i16 - z0).abs());
            }
        }
        let hash =
            mix(i as u64 ^ opts.seed.wrapping_mul(0x2545_f491_4f6c_dd1d) ^ ((c as u64) << 56));
        cands.push((key, contrast.min(255) as u8, hash, i));
    }
    if cands.is_empty() {
        return Vec::new();
    }
    let kmin = cands.iter().map(|c| c.0).min().unwrap_or(0) as u64;
    let kmax = cands.iter().map(|c| c.0).max().unwrap_or(0) as u64;
    let nb = STRATA.min(opts.samples).max(1);
    let mut bins: Vec<Vec<(u8, u64, usize)>> = vec![Vec::new(); nb];
    for &(k, con, hash, i) in &cands {
        let b = ((k as u64 - kmin) * nb as u64 / (kmax - kmin + 1)) as usize;
        bins[b.min(nb - 1)].push((con, hash, i));
    }
    // Within a bin: flat pixels (contrast at most the bin's median) first, each
    // group in hash order.
    for bin in &mut bins {
        if bin.is_empty() {
            continue;
        }
        let mut cs: Vec<u8> = bin.iter().map(|b| b.0).collect();
        let mid = cs.len() / 2;
        let med = *cs.select_nth_unstable(mid).1;
        bin.sort_unstable_by_key(|&(con, hash, _)| (con > med, hash));
    }
    // Water-filling quotas: small bins give all they have, the rest share.
    let mut ids: Vec<usize> = (0..nb).filter(|&b| !bins[b].is_empty()).collect();
    ids.sort_by_key(|&b| bins[b].len());
    let mut left = opts.samples;
    let mut picks = Vec::with_capacity(opts.samples);
    let m = ids.len();
    for (k, &b) in ids.iter().enumerate() {
        let take = bins[b].len().min(left / (m - k));
        picks.extend(bins[b][..take].iter().map(|t| t.2));
        left -= take;
    }
    picks.sort_unstable();
    picks
}

/// Assembles and solves the reduced normal equations of one channel. A sample's
/// observations are its usable frames ([`Bracket::usable`]), hat-weighted.
fn fit_channel(
    bracket: &Bracket,
    picks: &[usize],
    c: usize,
    lambda: f64,
) -> std::result::Result<ChannelFit, String> {
    let ln_t = bracket.ln_t();
    let n = CODES;
    let mut m = vec![0.0f64; n * n];
    let mut b = vec![0.0f64; n];
    let mut data_w = [0.0f64; CODES];
    let mut obs: Vec<(usize, f64, f64)> = Vec::with_capacity(ln_t.len());
    let mut total_c = 0.0f64;
    let mut equations = 0usize;
    let mut used = 0usize;
    // The usable observations of sample `i`: (code, ln Δt, hat weight).
    let floor = bracket.noise_floor()[c];
    let observe = |i: usize, obs: &mut Vec<(usize, f64, f64)>| {
        obs.clear();
        let (lo, hi) = bracket.usable(i, c);
        for j in lo..hi {
            let z = bracket.code(j, i, c);
            let wz = usable_hat(z, floor);
            if wz > 0.0 {
                obs.push((z as usize, ln_t[j], wz));
            }
        }
    };
    // First pass: the data weight normaliser α = 256 / Σ w².
    for &i in picks {
        observe(i, &mut obs);
        if obs.len() >= 2 {
            total_c += obs.iter().map(|o| o.2 * o.2).sum::<f64>();
        }
    }
    if total_c <= 0.0 {
        return Err("no pixel is unclipped in two exposures".into());
    }
    let alpha = CODES as f64 / total_c;
    for &i in picks {
        observe(i, &mut obs);
        if obs.len() < 2 {
            continue;
        }
        for o in obs.iter_mut() {
            o.2 = alpha * o.2 * o.2;
        }
        used += 1;
        equations += obs.len() - 1;
        let cs: f64 = obs.iter().map(|o| o.2).sum();
        let ybar: f64 = obs.iter().map(|o| o.2 * o.1).sum::<f64>() / cs;
        for &(za, ya, ca) in &obs {
            m[za * n + za] += ca;
            data_w[za] += ca;
            b[za] += ca * (ya - ybar);
            for &(zb, _, cb) in &obs {
                m[za * n + zb] -= ca * cb / cs;
            }
        }
    }
    if equations == 0 {
        return Err("no pixel is unclipped in two exposures".into());
    }
    // Smoothness rows: (λ w(z)² + floor) g''(z)², g'' against ln z (module docs).
    for z in 1..CODES - 1 {
        let hw = hat_weight(z as u8);
        let s = lambda * hw * hw + SMOOTHNESS_FLOOR;
        let idx = [z - 1, z, z + 1];
        let coef = smoothness_row(z);
        for a in 0..3 {
            for bb in 0..3 {
                m[idx[a] * n + idx[bb]] += s * coef[a] * coef[bb];
            }
        }
    }
    // Remove g(128) (pinned to 0) and solve the remaining 255 unknowns.
    let keep: Vec<usize> = (0..CODES).filter(|&z| z != ANCHOR_CODE).collect();
    let k = keep.len();
    let mut a = vec![0.0f64; k * k];
    let mut rhs = vec![0.0f64; k];
    for (r, &zr) in keep.iter().enumerate() {
        rhs[r] = b[zr];
        for (q, &zq) in keep.iter().enumerate() {
            a[r * k + q] = m[zr * n + zq];
        }
    }
    let x = solve_spd(&a, &rhs, k).ok_or_else(|| {
        "the equations do not determine the curve (too few pixels unclipped in two \
         different exposures)"
            .to_string()
    })?;
    let mut g = [0.0f64; CODES];
    for (r, &z) in keep.iter().enumerate() {
        g[z] = x[r];
    }
    if g.iter().any(|v| !v.is_finite()) {
        return Err("the solve produced non-finite values".into());
    }
    // Weighted RMS residual of the data equations (before the monotone pass).
    let mut sse = 0.0;
    let mut sw = 0.0;
    for &i in picks {
        observe(i, &mut obs);
        if obs.len() < 2 {
            continue;
        }
        for o in obs.iter_mut() {
            o.2 *= o.2;
        }
        let cs: f64 = obs.iter().map(|o| o.2).sum();
        let mean = obs.iter().map(|o| o.2 * (g[o.0] - o.1)).sum::<f64>() / cs;
        for &(z, y, cw) in &obs {
            let r = g[z] - y - mean;
            sse += cw * r * r;
            sw += cw;
        }
    }
    let weights: Vec<f64> = data_w.iter().map(|d| d + 1e-3).collect();
    let before = g;
    isotonic(&mut g, &weights);
    let monotone_fixes = g
        .iter()
        .zip(&before)
        .filter(|(a, b)| (*a - *b).abs() > 1e-9)
        .count();
    let anchor = g[ANCHOR_CODE];
    for v in &mut g {
        *v -= anchor;
    }
    Ok(ChannelFit {
        g,
        monotone_fixes,
        samples: used,
        equations,
        rms: if sw > 0.0 { (sse / sw).sqrt() } else { 0.0 },
    })
}

/// Coefficients of the smoothness row of code `z` (`1 ≤ z ≤ 254`) on
/// `g(z−1), g(z), g(z+1)`: the three-point second difference against `u = ln z`,
/// scaled so that the outer coefficients sum to 2 like the paper's `[1, −2, 1]`.
/// It vanishes on `g = p + q ln z`. Code 1 (whose left neighbour is `ln 0`) uses
/// `[1, −2, 1]`.
fn smoothness_row(z: usize) -> [f64; 3] {
    if z < 2 {
        return [1.0, -2.0, 1.0];
    }
    let u = |k: usize| (k as f64).ln();
    let left = 1.0 / (u(z) - u(z - 1));
    let right = 1.0 / (u(z + 1) - u(z));
    let s = 2.0 / (left + right);
    [s * left, -2.0, s * right]
}

/// Solves the symmetric positive definite system `a x = b` (`n x n`, row-major):
/// Jacobi scaling to a unit diagonal, Cholesky factorisation, two steps of
/// iterative refinement. `None` when the matrix is not numerically definite.
pub(crate) fn solve_spd(a: &[f64], b: &[f64], n: usize) -> Option<Vec<f64>> {
    let d: Vec<f64> = (0..n)
        .map(|i| {
            let v = a[i * n + i];
            if v > 0.0 && v.is_finite() {
                1.0 / v.sqrt()
            } else {
                f64::NAN
            }
        })
        .collect();
    if d.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let mut s = vec![0.0f64; n * n];
    for i in 0..n {
        for j in 0..n {
            s[i * n + j] = a[i * n + j] * d[i] * d[j];
        }
    }
    let mut l = s.clone();
    cholesky(&mut l, n)?;
    let bs: Vec<f64> = (0..n).map(|i| b[i] * d[i]).collect();
    let mut x = bs.clone();
    chol_solve(&l, n, &mut x);
    for _ in 0..2 {
        let mut r: Vec<f64> = (0..n)
            .map(|i| bs[i] - (0..n).map(|j| s[i * n + j] * x[j]).sum::<f64>())
            .collect();
        chol_solve(&l, n, &mut r);
        for (xi, ri) in x.iter_mut().zip(&r) {
            *xi += ri;
        }
    }
    let out: Vec<f64> = x.iter().zip(&d).map(|(x, d)| x * d).collect();
    out.iter().all(|v| v.is_finite()).then_some(out)
}

/// In-place Cholesky factorisation `a = L Lᵀ` (lower triangle holds `L`).
/// Fails when a pivot is not clearly positive (relative to a unit diagonal).
fn cholesky(a: &mut [f64], n: usize) -> Option<()> {
    let dot = |p: &[f64], q: &[f64]| p.iter().zip(q).map(|(x, y)| x * y).sum::<f64>();
    let mut rj = vec![0.0f64; n];
    for j in 0..n {
        rj[..j].copy_from_slice(&a[j * n..j * n + j]);
        let dj = a[j * n + j] - dot(&rj[..j], &rj[..j]);
        if !(dj > 1e-13) {
            return None;
        }
        let dj = dj.sqrt();
        a[j * n + j] = dj;
        for i in j + 1..n {
            let s = a[i * n + j] - dot(&a[i * n..i * n + j], &rj[..j]);
            a[i * n + j] = s / dj;
        }
    }
    Some(())
}

/// Solves `L Lᵀ x = b` in place with the factor from [`cholesky`].
fn chol_solve(l: &[f64], n: usize, x: &mut [f64]) {
    for i in 0..n {
        let mut s = x[i];
        for k in 0..i {
            s -= l[i * n + k] * x[k];
        }
        x[i] = s / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = x[i];
        for k in i + 1..n {
            s -= l[k * n + i] * x[k];
        }
        x[i] = s / l[i * n + i];
    }
}

/// Weighted isotonic regression (pool adjacent violators): the non-decreasing
/// sequence closest to `v` in weighted least squares.
pub(crate) fn isotonic(v: &mut [f64], weights: &[f64]) {
    // Blocks of (weighted mean, total weight, length).
    let mut blocks: Vec<(f64, f64, usize)> = Vec::with_capacity(v.len());
    for (&x, &wt) in v.iter().zip(weights) {
        let wt = if wt > 0.0 && wt.is_finite() {
            wt
        } else {
            1e-12
        };
        blocks.push((x, wt, 1));
        while blocks.len() >= 2 {
            let (m2, w2, n2) = blocks[blocks.len() - 1];
            let (m1, w1, n1) = blocks[blocks.len() - 2];
            if m1 <= m2 {
                break;
            }
            blocks.truncate(blocks.len() - 2);
            blocks.push(((m1 * w1 + m2 * w2) / (w1 + w2), w1 + w2, n1 + n2));
        }
    }
    let mut i = 0;
    for (mean, _, len) in blocks {
        for x in &mut v[i..i + len] {
            *x = mean;
        }
        i += len;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smoothness_rows_vanish_on_power_laws() {
        for z in 2..CODES - 1 {
            let r = smoothness_row(z);
            assert!((r[0] + r[2] - 2.0).abs() < 1e-12, "{z}");
            for (p, q) in [(0.3, 2.2), (-1.0, 1.0)] {
                let g = |k: usize| p + q * (k as f64).ln();
                let v = r[0] * g(z - 1) + r[1] * g(z) + r[2] * g(z + 1);
                assert!(v.abs() < 1e-9, "{z}: {v}");
            }
            // Close to the paper's [1, -2, 1] at mid codes.
            if z >= 64 {
                assert!((r[0] - 1.0).abs() < 0.01 && (r[2] - 1.0).abs() < 0.01);
            }
        }
        assert_eq!(smoothness_row(1), [1.0, -2.0, 1.0]);
    }

    #[test]
    fn isotonic_pools_violators() {
        let mut v = [1.0, 3.0, 2.0, 4.0, 0.0];
        isotonic(&mut v, &[1.0; 5]);
        assert!(v.windows(2).all(|p| p[1] >= p[0]), "{v:?}");
        assert!((v.iter().sum::<f64>() - 10.0).abs() < 1e-12);
        assert_eq!(&v[..1], &[1.0]);
    }

    #[test]
    fn spd_solver_matches_a_known_solution() {
        // A tridiagonal SPD matrix with wildly different row scales.
        let n = 40;
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            let s = 10f64.powi((i % 7) as i32 - 3);
            a[i * n + i] = 4.0 * s * s;
            if i + 1 < n {
                let s2 = 10f64.powi(((i + 1) % 7) as i32 - 3);
                a[i * n + i + 1] = -s * s2;
                a[(i + 1) * n + i] = -s * s2;
            }
        }
        let x_true: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
        let b: Vec<f64> = (0..n)
            .map(|i| (0..n).map(|j| a[i * n + j] * x_true[j]).sum())
            .collect();
        let x = solve_spd(&a, &b, n).unwrap();
        for (p, q) in x.iter().zip(&x_true) {
            assert!((p - q).abs() < 1e-9, "{p} vs {q}");
        }
        // A singular matrix is refused.
        assert!(solve_spd(&[1.0, 1.0, 1.0, 1.0], &[1.0, 1.0], 2).is_none());
    }

    #[test]
    fn curve_json_round_trip_and_validation() {
        let c = ResponseCurve::documented();
        let s = serde_json::to_string(&c).unwrap();
        let back: ResponseCurve = serde_json::from_str(&s).unwrap();
        // serde_json's float parsing is exact to within an ulp or so.
        for ch in 0..3 {
            for z in 0..CODES {
                assert!((back.g[ch][z] - c.g[ch][z]).abs() < 1e-12);
            }
        }
        let mut bad = c.clone();
        bad.g[1][100] = bad.g[1][99] - 1.0;
        let s = serde_json::to_string(&CurveFile::from(bad)).unwrap();
        assert!(serde_json::from_str::<ResponseCurve>(&s).is_err());
        assert!(
            serde_json::from_str::<ResponseCurve>(r#"{"g":[[1]],"lambda":0,"samples":0}"#).is_err()
        );
    }

    #[test]
    fn documented_curve_inverts_the_response() {
        let c = ResponseCurve::documented();
        let r = Response::RationalGamma {
            scale: 1.08,
            knee: 0.08,
            gamma: 2.2,
        };
        for z in [10u8, 64, 128, 200, 250] {
            let x = c.linear(1, z) as f32;
            assert!((r.encode(x) * 255.0 - z as f32).abs() < 0.01, "{z}");
        }
        assert!(c.g[0][0].is_finite() && c.g[0][0] < c.g[0][1]);
    }
}
