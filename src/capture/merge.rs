//! Merging an exposure bracket into one HDR image (Debevec & Malik 1997, eq. 6,
//! with an explicit observation model).
//!
//! **Domain.** Per pixel and channel the merge is a weighted mean in the *log*
//! domain, `ln E = Σ_j w(Z_j) (g(Z_j) − ln Δt_j) / Σ_j w(Z_j)`, with `g` the
//! response's log exposure per code ([`ResponseCurve`]), over the frames in which
//! the channel is actually *measured*. Frames that share an exposure time count as
//! one exposure: each of `k` such frames weighs `w(Z)/k` (see **Inputs**).
//!
//! **Which frames measure a channel** ([`Bracket`], shared with response
//! recovery). A code can fail to be a measurement at either end:
//!
//! * *Clipped.* Codes at or above [`CLIP_CODE`] (250) are saturated: JPEG ringing
//!   spreads a clipped 255 down by a few codes, and on a 2-px sun the brighter
//!   frames read 248–254 instead of 255. Next to a clipped sample (any channel,
//!   3×3) codes from [`NEAR_CLIP_CODE`] (230) on count as clipped too: JPEG codes
//!   the channels together in 8×8 blocks with chroma shared by 2×2 pixels, so a
//!   saturated sample there decodes 5–25 codes low and a clipped channel drags
//!   its neighbours' values. Because a sensor is monotone, a channel clipped at
//!   one exposure is clipped at every longer one, whatever code JPEG left there:
//!   every frame from the first clipped one (and its repeats) on is dropped.
//! * *Noise.* Codes at or below the channel's **noise floor** are read noise, not
//!   signal: the dark frames of a wide bracket show black at codes 7–25, which the
//!   hat weight would read as radiance thousands of times too high (biasing the
//!   whole image by about −0.1 ln). Symmetrically, every frame up to the last dark
//!   one is dropped. The floor is measured on the bracket itself with the given
//!   response ([`Bracket::estimate_noise_floor`]): the highest code whose
//!   observations scatter by more than [`NOISE_LOG_ERROR`] in ln (a
//!   signal-to-noise ratio below about 2) around what a well-exposed frame of the
//!   same pixel predicts. It follows the camera, its ISO and its JPEG settings;
//!   no noise model is assumed. A single exposure has none (floor 0: only code 0
//!   is dark). [`MergeReport::noise_floor`] reports it.
//!
//! **Weights.** Between the floor and the clip the weight is the code's relative
//! exposure `exp g(z)`: in the log domain an observation's variance is
//! `(σ_x / x)²`, which for a shot-noise-limited sensor (`σ_x² ∝ x`) is `∝ 1/x`, so
//! `exp g` is its inverse variance. For one pixel, `x ∝ Δt`: this weights the
//! frames by exposure time, and the longest unclipped exposure, the one with the
//! best signal-to-noise ratio, counts most (read noise and 8-bit quantisation
//! favour it even more). Across the near-clip band (`NEAR_CLIP_CODE..CLIP_CODE`)
//! the weight falls linearly to zero: there a code may still be a softened clipped
//! value, noise is cut off by saturation, and the response is least known. Debevec
//! and Malik's hat, which trusts mid-grey most and a code of 240 as little as one
//! of 15, is still used to *recover* the response (restricted to the same usable
//! codes, [`super::debevec::usable_hat`]).
//!
//! **No measurement.** When a channel has no usable frame the merge says so
//! explicitly instead of averaging noise: clipped even in the darkest frame, it
//! takes that frame's lower bound, the clamp value `g(255) − ln Δt_min` for a
//! clipped code (never less), its own value for a possibly clipped one; dark even
//! in the brightest frame, it takes that frame's value `g(Z) − ln Δt_max` (an
//! upper bound). Pixels with some channel clipped in the darkest frame are flagged
//! [`SATURATED`] and pixels dark in every channel [`BLACK`]. [`MergeReport`]
//! measures how much of the sphere and of the light the saturated pixels are, so
//! the under-estimate is reported instead of silent.
//!
//! **Inputs.** Exposures may come in any order and may repeat a time; one
//! exposure time is a plain linearisation (repeats averaged), clipped pixels
//! flagged. Frames with the same exposure time are averaged into one exposure
//! rather than each weighing as a full one: a file given twice then changes
//! nothing, and repeated shots reduce noise without tilting the bracket towards
//! their exposure. Exposure times that are zero, negative or not finite, and
//! images of different sizes, are errors naming the file.

use super::debevec::{Bracket, ResponseCurve, CODES};
pub use super::debevec::{CLIP_CODE, NEAR_CLIP_CODE};
use crate::error::{Error, Result};
use crate::image::{luminance, HdrImage, SdrImage};
use rayon::prelude::*;
use std::path::PathBuf;

/// Flag bit: some channel is clipped (≥ [`CLIP_CODE`], or ≥ [`NEAR_CLIP_CODE`]
/// next to a clipped sample) even in the darkest exposure; the pixel's radiance
/// is a lower bound.
pub const SATURATED: u8 = 1;
/// Flag bit: every channel is black or at or below its noise floor even in the
/// brightest exposure; the pixel's radiance is an upper bound.
pub const BLACK: u8 = 2;

/// One frame of a bracket: the image, its exposure time and the file it came from.
#[derive(Clone, Debug)]
pub struct Exposure {
    /// File name, used in messages.
    pub name: PathBuf,
    /// The 8-bit image.
    pub image: SdrImage,
    /// Exposure time in seconds (must be finite and positive).
    pub time_s: f64,
}

/// Settings of [`merge`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MergeOptions {
    /// Whether the images are equirect panoramas (solid-angle weighting in the
    /// report); `None` decides by a 2:1 aspect ratio.
    pub equirect: Option<bool>,
}

/// One input frame as the merge used it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FrameReport {
    /// File name.
    pub name: PathBuf,
    /// Exposure time in seconds.
    pub time_s: f64,
    /// Share of pixels (solid-angle weighted when equirect) with a channel
    /// clipped in this frame (module docs).
    pub clipped_fraction: f64,
}

/// What a merge measured about its own limits (see the module docs).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct MergeReport {
    /// Image width.
    pub width: usize,
    /// Image height.
    pub height: usize,
    /// Whether fractions are solid-angle weighted (equirect input).
    pub equirect: bool,
    /// The frames, darkest (shortest time) first.
    pub frames: Vec<FrameReport>,
    /// Fraction of the image (of the sphere when equirect) clipped in the darkest
    /// frame: the [`SATURATED`] pixels.
    pub clipped_fraction: f64,
    /// Share of the estimated light (luminance × solid angle) carried by the
    /// clipped pixels. Their radiance is a lower bound, so the true share is at
    /// least this.
    pub clipped_light_share: f64,
    /// Pixels with some channel clipped in every frame (the [`SATURATED`] ones).
    pub saturated_pixels: usize,
    /// Pixels black or below the noise floor in every channel of every frame
    /// (the [`BLACK`] ones).
    pub black_pixels: usize,
    /// Per channel, the highest code treated as noise, measured on the bracket
    /// (0: only black; see the module docs).
    pub noise_floor: [u8; 3],
    /// Warnings for the user (clipping, duplicates, ...).
    pub warnings: Vec<String>,
}

impl MergeReport {
    /// A few human-readable lines: frames, clipping, warnings.
    pub fn summary(&self) -> String {
        let mut s = format!(
            "merged {} exposure(s) of {}x{} ({} to {} s)\n",
            self.frames.len(),
            self.width,
            self.height,
            fmt_time(self.frames.first().map_or(0.0, |f| f.time_s)),
            fmt_time(self.frames.last().map_or(0.0, |f| f.time_s)),
        );
        let what = if self.equirect { "sphere" } else { "image" };
        s += &format!(
            "clipped in the darkest frame: {:.4}% of the {what}, >= {:.1}% of the light\n",
            100.0 * self.clipped_fraction,
            100.0 * self.clipped_light_share
        );
        let [r, g, b] = self.noise_floor;
        s += &format!("noise floor (codes read as noise): R <= {r}, G <= {g}, B <= {b}\n");
        for w in &self.warnings {
            s += &format!("warning: {w}\n");
        }
        s
    }
}

/// An exposure time as `1/N s` when short, else in seconds.
fn fmt_time(t: f64) -> String {
    if t > 0.0 && t < 0.5 {
        format!("1/{:.0}", 1.0 / t)
    } else {
        format!("{t}")
    }
}

/// The merged image, per-pixel flags ([`SATURATED`], [`BLACK`]) and the report.
#[derive(Clone, Debug)]
pub struct Merged {
    /// Linear radiance, relative to the response's scale (`exp g / seconds`).
    pub image: HdrImage,
    /// One byte of flag bits per pixel, row-major.
    pub flags: Vec<u8>,
    /// Clipping statistics and warnings.
    pub report: MergeReport,
}

/// Validates a bracket (non-empty, positive finite times, equal sizes) and returns
/// the frame indices sorted by exposure time (stable for equal times).
pub fn check_exposures(exps: &[Exposure]) -> Result<Vec<usize>> {
    let Some(first) = exps.first() else {
        return Err(Error::Invalid("no exposures to merge".into()));
    };
    for e in exps {
        if !(e.time_s.is_finite() && e.time_s > 0.0) {
            return Err(Error::Invalid(format!(
                "{}: exposure time {} s is not a positive number",
                e.name.display(),
                e.time_s
            )));
        }
        if e.image.width() != first.image.width() || e.image.height() != first.image.height() {
            return Err(Error::Invalid(format!(
                "{} is {}x{} but {} is {}x{}: all exposures must have the same size",
                e.name.display(),
                e.image.width(),
                e.image.height(),
                first.name.display(),
                first.image.width(),
                first.image.height()
            )));
        }
    }
    if first.image.width() == 0 || first.image.height() == 0 {
        return Err(Error::Invalid(format!(
            "{}: the image is empty",
            first.name.display()
        )));
    }
    let mut order: Vec<usize> = (0..exps.len()).collect();
    order.sort_by(|&a, &b| exps[a].time_s.total_cmp(&exps[b].time_s));
    Ok(order)
}

/// The merge weight of each code per channel (module docs, **Weights**): the
/// code's relative exposure `exp g(z)` between the noise floor and
/// [`CLIP_CODE`], tapered linearly to zero across the near-clip band from
/// [`NEAR_CLIP_CODE`], zero elsewhere.
fn weights(g: &[[f64; CODES]; 3], floor: [u8; 3]) -> [[f64; CODES]; 3] {
    let mut wt = [[0.0f64; CODES]; 3];
    let (near, clip) = (NEAR_CLIP_CODE as usize, CLIP_CODE as usize);
    for c in 0..3 {
        for z in floor[c] as usize + 1..clip {
            let taper = ((clip - z) as f64 / (clip - near) as f64).min(1.0);
            // Relative to the top code so that the numbers stay near 1.
            wt[c][z] = (g[c][z] - g[c][clip - 1]).exp() * taper;
        }
    }
    wt
}

/// Merges a bracket with the response `curve` (module docs). Any order, repeated
/// times and a single exposure are accepted; invalid times and mismatched sizes
/// are errors naming the file.
pub fn merge(exps: &[Exposure], curve: &ResponseCurve, opts: &MergeOptions) -> Result<Merged> {
    let order = check_exposures(exps)?;
    curve.validate(std::path::Path::new("response curve"))?;
    let (w, h) = (exps[0].image.width(), exps[0].image.height());
    let equirect = opts.equirect.unwrap_or(w == 2 * h);
    let data: Vec<&[u8]> = exps.iter().map(|e| e.image.data()).collect();
    let times: Vec<f64> = exps.iter().map(|e| e.time_s).collect();
    // Sorted like `order` (both sorts are stable by time).
    let mut bracket = Bracket::new(&data, &times, w);
    let p = exps.len();
    let single = bracket.group(0).1 == p;
    if !single {
        bracket.estimate_noise_floor(&curve.g);
    }
    let floor = bracket.noise_floor();
    let ln_t = bracket.ln_t();
    // Weight share of each (sorted) frame: 1/k for k frames of one exposure time.
    let share: Vec<f64> = (0..p)
        .map(|j| {
            let (a, b) = bracket.group(j);
            1.0 / (b - a) as f64
        })
        .collect();
    let g = &curve.g;
    let wt = weights(g, floor);
    let row_area = |y: usize| {
        if equirect {
            crate::sphere::pixel_solid_angle(y, w, h) as f64
        } else {
            1.0
        }
    };

    /// Per-row statistics, summed in row order.
    #[derive(Default, Clone)]
    struct RowStats {
        area: f64,
        clipped_area: f64,
        light: f64,
        clipped_light: f64,
        saturated: usize,
        black: usize,
        frame_clipped: Vec<f64>,
    }

    let bracket = &bracket;
    let mut image = HdrImage::new(w, h);
    let mut flags = vec![0u8; w * h];
    let stats: Vec<RowStats> = image
        .data_mut()
        .par_chunks_mut(3 * w)
        .zip(flags.par_chunks_mut(w))
        .enumerate()
        .map(|(y, (row, frow))| {
            let da = row_area(y);
            let mut st = RowStats {
                frame_clipped: vec![0.0; p],
                ..Default::default()
            };
            for x in 0..w {
                let i = y * w + x;
                let mut out = [0.0f32; 3];
                let mut clipped = false;
                let mut black = true;
                for c in 0..3 {
                    let code = |j: usize| bracket.code(j, i, c) as usize;
                    let ln_e = if single {
                        // Nothing to merge: the linearisation (mean over repeats).
                        if bracket.clipped(0, i, c) {
                            clipped = true;
                        }
                        if code(p - 1) > floor[c] as usize {
                            black = false;
                        }
                        (0..p).map(|j| share[j] * (g[c][code(j)] - ln_t[j])).sum()
                    } else {
                        let (lo, hi) = bracket.usable(i, c);
                        if lo < p {
                            black = false;
                        }
                        let mut num = 0.0f64;
                        let mut den = 0.0f64;
                        for j in lo..hi {
                            let z = code(j);
                            let wz = wt[c][z] * share[j];
                            num += wz * (g[c][z] - ln_t[j]);
                            den += wz;
                        }
                        // A clipped observation's lower bound: the clamp value
                        // g(255) for a clipped code, its own value for a possibly
                        // clipped one.
                        let bound = |j: usize| {
                            let z = code(j);
                            let zb = if z >= CLIP_CODE as usize { 255 } else { z };
                            g[c][zb] - ln_t[j]
                        };
                        if den > 0.0 {
                            num / den
                        } else if hi == 0 {
                            // Clipped even in the darkest exposure: its bound.
                            clipped = true;
                            let (a, b) = bracket.group(0);
                            (a..b).map(bound).fold(f64::NEG_INFINITY, f64::max)
                        } else if lo == p {
                            // Noise even in the brightest exposure: its value.
                            let (a, b) = bracket.group(p - 1);
                            (a..b).map(|j| share[j] * (g[c][code(j)] - ln_t[j])).sum()
                        } else if lo == hi {
                            // Dark in one exposure and clipped in the next (a jump
                            // across the whole range): between the two bounds.
                            let upper = g[c][floor[c] as usize + 1] - ln_t[lo - 1];
                            0.5 * (upper + bound(hi))
                        } else {
                            // Usable frames whose weights all underflowed (a curve
                            // spanning hundreds of ln units): their plain mean.
                            let n = (hi - lo) as f64;
                            (lo..hi).map(|j| g[c][code(j)] - ln_t[j]).sum::<f64>() / n
                        }
                    };
                    out[c] = ln_e.exp().min(f32::MAX as f64) as f32;
                }
                for j in 0..p {
                    if (0..3).any(|c| bracket.clipped(j, i, c)) {
                        st.frame_clipped[j] += da;
                    }
                }
                let mut flag = 0u8;
                if clipped {
                    flag |= SATURATED;
                    st.saturated += 1;
                }
                if black {
                    flag |= BLACK;
                    st.black += 1;
                }
                frow[x] = flag;
                row[3 * x..3 * x + 3].copy_from_slice(&out);
                let l = luminance(out) as f64 * da;
                st.area += da;
                st.light += l;
                if clipped {
                    st.clipped_area += da;
                    st.clipped_light += l;
                }
            }
            st
        })
        .collect();

    let mut tot = RowStats {
        frame_clipped: vec![0.0; p],
        ..Default::default()
    };
    for s in &stats {
        tot.area += s.area;
        tot.clipped_area += s.clipped_area;
        tot.light += s.light;
        tot.clipped_light += s.clipped_light;
        tot.saturated += s.saturated;
        tot.black += s.black;
        for (a, b) in tot.frame_clipped.iter_mut().zip(&s.frame_clipped) {
            *a += b;
        }
    }
    let frac = |a: f64| if tot.area > 0.0 { a / tot.area } else { 0.0 };
    let clipped_fraction = frac(tot.clipped_area);
    let clipped_light_share = if tot.light > 0.0 {
        tot.clipped_light / tot.light
    } else {
        0.0
    };
    let frames_report: Vec<FrameReport> = order
        .iter()
        .enumerate()
        .map(|(k, &j)| FrameReport {
            name: exps[j].name.clone(),
            time_s: exps[j].time_s,
            clipped_fraction: frac(tot.frame_clipped[k]),
        })
        .collect();

    let mut warnings = Vec::new();
    let what = if equirect { "sphere" } else { "image" };
    let darkest = &exps[order[0]];
    if tot.saturated == w * h {
        warnings.push(format!(
            "every pixel is saturated even in the darkest exposure ({}, {} s): the result \
             is only a lower bound; add shorter exposures",
            darkest.name.display(),
            fmt_time(darkest.time_s)
        ));
    } else if clipped_fraction > 0.0 {
        warnings.push(format!(
            "the brightest sources clip even at the darkest exposure ({}, {} s): {:.4}% of \
             the {what}, >= {:.1}% of the light; their radiance is a lower bound",
            darkest.name.display(),
            fmt_time(darkest.time_s),
            100.0 * clipped_fraction,
            100.0 * clipped_light_share
        ));
    }
    if tot.black > 0 {
        warnings.push(format!(
            "{} pixel(s) are black (at or below the noise floor, codes {:?}) even in the \
             brightest exposure; their radiance is an upper bound",
            tot.black, floor
        ));
    }
    for pair in order.windows(2) {
        let (a, b) = (&exps[pair[0]], &exps[pair[1]]);
        if b.time_s <= a.time_s * (1.0 + 1e-9) {
            warnings.push(format!(
                "{} and {} have the same exposure time ({} s); both are used, averaged \
                 as one exposure",
                a.name.display(),
                b.name.display(),
                a.time_s
            ));
        }
    }
    if p == 1 {
        warnings.push(
            "a single exposure: the result is a linearisation, clipped where the frame clips"
                .into(),
        );
    }
    Ok(Merged {
        image,
        flags,
        report: MergeReport {
            width: w,
            height: h,
            equirect,
            frames: frames_report,
            clipped_fraction,
            clipped_light_share,
            saturated_pixels: tot.saturated,
            black_pixels: tot.black,
            noise_floor: floor,
            warnings,
        },
    })
}

/// Luminance (cd/m²) that exposes the sensor to its clipping level in one
/// second at f/1 and ISO 1: ISO 12232's saturation-based speed puts the
/// clipping exposure at `H = 78 / S` lux·s, and the camera equation gives
/// `H = q L t / N²` with the usual lens factor `q = 0.65`, so
/// `L = (78 / 0.65) x N² / (t S)` for a linear exposure `x` (1 at clipping).
/// Cameras calibrate their ISO within about a third of a stop of this.
pub const SATURATION_LUMINANCE: f64 = 78.0 / 0.65;

/// How radiance merged from brackets becomes luminance in cd/m².
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AbsoluteScale {
    /// Multiplies the merged radiance (`exp g / seconds`); `None` until the
    /// response is known.
    pub factor: Option<f64>,
    /// The brackets' f-number.
    pub f_number: f64,
    /// The brackets' ISO.
    pub iso: u32,
}

/// The factor taking radiance merged with `curve` from brackets shot with
/// these Exif settings to luminance in cd/m² ([`SATURATION_LUMINANCE`]), the
/// curve's exposure at code 254 taken as the clipping level (no factor
/// without a curve); `None` when a bracket lacks FNumber or ISO, or the
/// brackets differ in them (a merge assumes that only the exposure time
/// changes).
pub fn absolute_scale(
    exif: &[crate::capture::exif::ExifExposure],
    curve: Option<&ResponseCurve>,
) -> Option<AbsoluteScale> {
    let first = exif.first()?;
    let (n, iso) = (first.f_number?, first.iso?);
    let same = exif
        .iter()
        .all(|e| e.iso == Some(iso) && e.f_number.is_some_and(|m| (m - n).abs() <= 1e-3 * n));
    if !same || !(n > 0.0 && n.is_finite()) || iso == 0 {
        return None;
    }
    let factor = match curve {
        Some(c) => {
            let clip = c.g[1][254].exp();
            let f = SATURATION_LUMINANCE * n * n / (iso as f64 * clip);
            if !(f.is_finite() && f > 0.0) {
                return None;
            }
            Some(f)
        }
        None => None,
    };
    Some(AbsoluteScale {
        factor,
        f_number: n,
        iso,
    })
}

#[cfg(test)]
mod scale_tests {
    use super::*;
    use crate::capture::exif::ExifExposure;

    fn shot(n: f64, iso: u32) -> ExifExposure {
        ExifExposure {
            exposure_time_s: Some(1.0 / 60.0),
            f_number: Some(n),
            iso: Some(iso),
        }
    }

    #[test]
    fn the_meter_equation_gives_candela_per_square_metre() {
        // The documented response clips at exposure 1: a wall at linear 0.18
        // in a 1/60 s, f/2.2, ISO 100 shot is 0.18 x 120 x 2.2² x 60 / 100.
        let c = ResponseCurve::documented();
        let a = absolute_scale(&[shot(2.2, 100), shot(2.2, 100)], Some(&c)).unwrap();
        let merged = 0.18 * 60.0; // exp g / t
        let l = merged * a.factor.unwrap();
        let want = 0.18 * 120.0 * 2.2 * 2.2 * 60.0 / 100.0;
        assert!((l / want - 1.0).abs() < 0.01, "{l} against {want}");
        // Twice the ISO, half the luminance for the same merged value.
        let b = absolute_scale(&[shot(2.2, 200)], Some(&c)).unwrap();
        assert!((a.factor.unwrap() / b.factor.unwrap() - 2.0).abs() < 1e-9);
        // Without the tags, or with brackets that differ in them: no unit.
        let mut none = shot(2.2, 100);
        none.iso = None;
        assert!(absolute_scale(&[none], Some(&c)).is_none());
        assert!(absolute_scale(&[shot(2.2, 100), shot(4.0, 100)], Some(&c)).is_none());
        assert!(absolute_scale(&[], Some(&c)).is_none());
        // Known settings, no curve yet: the unit without its factor.
        assert_eq!(
            absolute_scale(&[shot(2.2, 100)], None).unwrap().factor,
            None
        );
    }
}
