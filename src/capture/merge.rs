//! Merging an exposure bracket into one HDR image (Debevec & Malik 1997, eq. 6).
//!
//! **Domain.** Per pixel and channel the merge is a hat-weighted mean in the *log*
//! domain, `ln E = Σ_j w(Z_j) (g(Z_j) − ln Δt_j) / Σ_j w(Z_j)`, with `g` the
//! response's log exposure per code ([`ResponseCurve`]) and `w` the hat weight
//! ([`hat_weight`]: zero at codes 0 and 255). This is the paper's estimator; it
//! treats every unclipped observation as a measurement of the same `ln E` and
//! trusts mid-range codes most. Frames that share an exposure time count as one
//! exposure: each of `k` such frames weighs `w(Z)/k` (see **Inputs**).
//!
//! **Clipping.** A channel whose every observation has zero weight is handled
//! explicitly: saturated in the darkest frame (code 255) it takes the darkest
//! frame's value `g(255) − ln Δt_min` — a *lower bound* of its radiance; black in
//! the brightest frame (code 0) it takes the brightest frame's value
//! `g(0) − ln Δt_max` (an upper bound). Pixels with any channel at or above
//! [`CLIP_CODE`] in the darkest frame are flagged [`SATURATED`]: their radiance
//! is at best a lower bound. [`MergeReport`] measures how much of the sphere and
//! of the light they are, so the under-estimate is reported instead of silent.
//!
//! **Inputs.** Exposures may come in any order and may repeat a time; one
//! exposure is a plain linearisation. Frames with the same exposure time are
//! averaged into one exposure rather than each weighing as a full one: a file
//! given twice then changes nothing, and repeated shots reduce noise without
//! tilting the bracket towards their exposure (with the plain weights, a
//! duplicated frame would double its say in every pixel, which moves the
//! noise-dominated dark pixels by ten percent or more). Exposure times that are zero,
//! negative or not finite, and images of different sizes, are errors naming the
//! file.

use super::debevec::{hat_weight, ResponseCurve, CODES};
use crate::error::{Error, Result};
use crate::image::{luminance, HdrImage, SdrImage};
use rayon::prelude::*;
use std::path::PathBuf;

/// Codes at or above this in the darkest frame count as clipped for the report
/// and the [`SATURATED`] flag: JPEG ringing spreads a clipped 255 by a few codes.
pub const CLIP_CODE: u8 = 250;
/// Flag bit: some channel is clipped (≥ [`CLIP_CODE`]) even in the darkest
/// exposure; the pixel's radiance is a lower bound.
pub const SATURATED: u8 = 1;
/// Flag bit: every channel is black (code 0) even in the brightest exposure; the
/// pixel's radiance is an upper bound.
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
    /// Share of pixels (solid-angle weighted when equirect) with a channel at or
    /// above [`CLIP_CODE`] in this frame.
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
    /// Pixels with some channel saturated (zero weight, code 255) in every frame.
    pub saturated_pixels: usize,
    /// Pixels black in every channel of every frame.
    pub black_pixels: usize,
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

/// Merges a bracket with the response `curve` (module docs). Any order, repeated
/// times and a single exposure are accepted; invalid times and mismatched sizes
/// are errors naming the file.
pub fn merge(exps: &[Exposure], curve: &ResponseCurve, opts: &MergeOptions) -> Result<Merged> {
    let order = check_exposures(exps)?;
    curve.validate(std::path::Path::new("response curve"))?;
    let (w, h) = (exps[0].image.width(), exps[0].image.height());
    let equirect = opts.equirect.unwrap_or(w == 2 * h);
    let frames: Vec<&[u8]> = order.iter().map(|&j| exps[j].image.data()).collect();
    let ln_t: Vec<f64> = order.iter().map(|&j| exps[j].time_s.ln()).collect();
    let p = frames.len();
    // Weight share of each (sorted) frame: 1/k for k frames of one exposure time.
    let mut share = vec![1.0f64; p];
    let mut first = 0;
    while first < p {
        let t0 = exps[order[first]].time_s;
        let end = (first + 1..p)
            .find(|&j| exps[order[j]].time_s > t0 * (1.0 + 1e-9))
            .unwrap_or(p);
        share[first..end].fill(1.0 / (end - first) as f64);
        first = end;
    }
    let g = &curve.g;
    // EXPERIMENT knobs.
    let env = |k: &str, d: f64| -> f64 {
        std::env::var(k)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(d)
    };
    let clip_rule = env("MW_CLIP", 0.0) > 0.0;
    let floor = env("MW_FLOOR", -1.0);
    let wmode = env("MW_WEIGHT", 0.0) as i32;
    let taper = env("MW_TAPER", 16.0);
    let clip = if clip_rule { CLIP_CODE as usize } else { 256 };
    let mut wt = [[0.0f64; CODES]; 3];
    for c in 0..3 {
        for z in 0..CODES {
            let zf = z as f64;
            wt[c][z] = match wmode {
                0 => hat_weight(z as u8),
                1 => {
                    let lo = floor.max(0.0);
                    let hi = clip.min(255) as f64;
                    ((zf - lo).min(hi - zf)).max(0.0) / 127.5
                }
                _ => {
                    let hi = clip.min(255) as f64;
                    (g[c][z] - g[c][200]).exp() * ((hi - zf) / taper).clamp(0.0, 1.0)
                }
            };
            if z as f64 <= floor || z >= clip {
                wt[c][z] = 0.0;
            }
        }
    }
    let nb_rule = env("MW_NB", 0.0) > 0.0;
    // First sorted frame where the 3x3 neighbourhood has a clipped sample.
    let first_bad: Vec<usize> = {
        let n = w * h;
        let mut fb = vec![p; n];
        if nb_rule {
            for (j, f) in frames.iter().enumerate().rev() {
                let clipped: Vec<bool> = f
                    .chunks_exact(3)
                    .map(|q| q.iter().any(|&v| v as usize >= clip))
                    .collect();
                for y in 0..h {
                    for x in 0..w {
                        let mut any = false;
                        for yy in y.saturating_sub(1)..(y + 2).min(h) {
                            for xx in x.saturating_sub(1)..(x + 2).min(w) {
                                any |= clipped[yy * w + xx];
                            }
                        }
                        if any {
                            fb[y * w + x] = j;
                        }
                    }
                }
            }
        }
        fb
    };
    // Index range of the frames sharing the time of each sorted frame.
    let mut grp = vec![(0usize, 0usize); p];
    {
        let mut a = 0;
        while a < p {
            let t0 = exps[order[a]].time_s;
            let b = (a + 1..p)
                .find(|&j| exps[order[j]].time_s > t0 * (1.0 + 1e-9))
                .unwrap_or(p);
            for j in a..b {
                grp[j] = (a, b);
            }
            a = b;
        }
    }
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
                let mut any_saturated_all = false;
                let mut black_all = true;
                for c in 0..3 {
                    let code = |j: usize| frames[j][3 * i + c] as usize;
                    // Usable frames: [lo, hi).
                    let mut hi = p;
                    if clip_rule {
                        if let Some(jc) = (0..p).find(|&j| code(j) >= clip) {
                            hi = grp[jc].0;
                        }
                    }
                    let mut lo = 0;
                    if floor >= 0.0 {
                        if let Some(jd) = (0..p).rev().find(|&j| code(j) as f64 <= floor) {
                            lo = grp[jd].1;
                        }
                    }
                    let mut num = 0.0f64;
                    let mut den = 0.0f64;
                    let hi1 = if first_bad[i] < p {
                        hi.min(grp[first_bad[i]].0)
                    } else {
                        hi
                    };
                    for j in lo..hi1 {
                        let z = code(j);
                        let wz = wt[c][z] * share[j];
                        num += wz * (g[c][z] - ln_t[j]);
                        den += wz;
                    }
                    if den == 0.0 {
                        for j in lo..hi {
                            let z = code(j);
                            let wz = wt[c][z] * share[j];
                            num += wz * (g[c][z] - ln_t[j]);
                            den += wz;
                        }
                    }
                    let dark = frames[0][3 * i + c];
                    let bright = frames[p - 1][3 * i + c];
                    if bright != 0 {
                        black_all = false;
                    }
                    let ln_e = if den > 0.0 {
                        num / den
                    } else if hi == 0 || dark == 255 {
                        any_saturated_all = true;
                        g[c][255] - ln_t[0]
                    } else if lo == p || bright == 0 {
                        g[c][bright as usize] - ln_t[p - 1]
                    } else {
                        let first_sat = (0..p).find(|&j| code(j) >= clip.min(255)).unwrap_or(0);
                        let last_black = (0..p)
                            .rev()
                            .find(|&j| code(j) as f64 <= floor.max(0.0))
                            .unwrap_or(0);
                        0.5 * ((g[c][255] - ln_t[first_sat])
                            + (g[c][floor.max(1.0) as usize] - ln_t[last_black]))
                    };
                    out[c] = ln_e.exp().min(f32::MAX as f64) as f32;
                }
                let clipped = (0..3).any(|c| frames[0][3 * i + c] >= CLIP_CODE);
                for (j, f) in frames.iter().enumerate() {
                    if (0..3).any(|c| f[3 * i + c] >= CLIP_CODE) {
                        st.frame_clipped[j] += da;
                    }
                }
                let mut flag = 0u8;
                if clipped {
                    flag |= SATURATED;
                }
                if black_all {
                    flag |= BLACK;
                    st.black += 1;
                }
                if any_saturated_all {
                    st.saturated += 1;
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
            "{} pixel(s) are black even in the brightest exposure; their radiance is an \
             upper bound",
            tot.black
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
            warnings,
        },
    })
}
