//! Scores a predicted HDR probe against the ground-truth probe of the same frame.
//!
//! These are the project's documented metrics. Both images are equirect panoramas
//! of the same size (see [`compare_resized`] otherwise), in linear RGB.
//!
//! * **Tone-mapped images.** Both are tone-mapped with
//!   [`crate::tonemap::reinhard_global`]`(img, 0.18, None, Some(log_avg_gt))`, using
//!   the *ground truth's* log-average luminance for both, so an exposure error in the
//!   prediction shows. The result is sRGB-encoded display RGB in `[0, 1]`.
//! * **`mse_tm`**: mean over pixels and channels of the squared difference of the
//!   tone-mapped images, in `[0, 1]` units, unweighted (as in the thesis).
//! * **`psnr_tm`**: `10 log10(1 / mse_tm)` in dB, capped at 100 dB (also when
//!   `mse_tm = 0`).
//! * **`ssim_tm`**: mean SSIM (Wang et al. 2004; 11x11 Gaussian window, sigma 1.5,
//!   `K1 = 0.01`, `K2 = 0.03`, `L = 1`) of the luma `0.299 R + 0.587 G + 0.114 B`
//!   of the tone-mapped images; columns wrap at the seam and rows across the poles
//!   (see [`ssim()`]).
//! * **`log_lum_rmse`**: `sqrt(sum_px w (log10(Lp + eps) - log10(Lg + eps))^2 / sum w)`
//!   with `L` the Rec. 709 luminance of the linear images, `w` the pixel's solid
//!   angle, and `eps = 1e-3 * median(Lg)` (`1e-6` when that median is 0).
//! * **`irradiance_rel_err`**: both images are projected onto order-2 spherical
//!   harmonics ([`crate::ibl::Sh9`]); the diffuse irradiance `E(n)` (luminance of
//!   the RGB irradiance, Ramamoorthi & Hanrahan 2001, not clamped) is evaluated at
//!   the 256 fixed normals of [`crate::ibl::fibonacci_directions`], and the error is
//!   `sqrt(sum (Ep - Eg)^2) / sqrt(sum Eg^2)`. When the ground truth's irradiance is
//!   zero everywhere it is 0 if the prediction's is too, else 1.
//! * **`dominant_dir_err_deg`**: angle in degrees between the dominant light
//!   directions of the two images. The dominant direction is the normalised first
//!   moment of luminance, `int L(d) d dOmega`, i.e. the normalised band-1 SH
//!   luminance vector. An image whose first moment is negligible (below `1e-5` of
//!   its flux, e.g. a constant environment) has none: the error is 0 if neither
//!   image has one and 90 (the mean angle to a random direction) if only one has.
//!
//! Every metric is finite for any input: NaN, infinite and negative samples are
//! repaired first ([`HdrImage::repair_invalid`]: NaN and negatives to 0, +inf to the
//! largest finite sample). Pixels of the prediction that needed repair are counted in
//! [`Metrics::invalid_pixels`]; the ground truth is repaired silently.
//!
//! All reductions run per row in parallel and add the row results in row order, so
//! the numbers do not depend on the thread count.

pub mod plot;
pub mod ssim;
pub mod summary;
pub mod table;

pub use ssim::ssim;
pub use table::{MetricsRow, MetricsTable};

use crate::error::{Error, Result};
use crate::ibl::sh::{dominant_dir_f64, irradiance_scalar_f64, luminance_f64, project_f64};
use crate::image::HdrImage;
use rayon::prelude::*;
use std::borrow::Cow;

/// Key (target mid-grey) of the global Reinhard tone map used by the metrics.
pub const TM_KEY: f32 = 0.18;
/// Ceiling of [`Metrics::psnr_tm`] in dB (reached by identical images).
pub const PSNR_CAP_DB: f64 = 100.0;
/// Number of Fibonacci normals where irradiance is compared.
pub const IRRADIANCE_NORMALS: usize = 256;

/// Scores of one predicted probe against its ground truth (definitions in the
/// [module docs](self)). Lower is better except for `psnr_tm` and `ssim_tm`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Metrics {
    /// PSNR of the tone-mapped images in dB, capped at 100.
    pub psnr_tm: f64,
    /// Mean SSIM of the luma of the tone-mapped images (1 = identical).
    pub ssim_tm: f64,
    /// Mean squared error of the tone-mapped images, in `[0, 1]` units.
    pub mse_tm: f64,
    /// Solid-angle-weighted RMSE of log10 luminance (log10(2) = a factor of 2).
    pub log_lum_rmse: f64,
    /// Relative L2 error of SH diffuse irradiance over 256 normals.
    pub irradiance_rel_err: f64,
    /// Angle between the dominant light directions, in degrees.
    pub dominant_dir_err_deg: f64,
    /// Pixels of the prediction with a NaN, infinite or negative sample (repaired
    /// before scoring). In a mean over frames ([`Metrics::mean`]) this is the total.
    pub invalid_pixels: u64,
}

/// Names of the six score columns, in the order of [`Metrics::values`].
pub const METRIC_NAMES: [&str; 6] = [
    "psnr_tm",
    "ssim_tm",
    "mse_tm",
    "log_lum_rmse",
    "irradiance_rel_err",
    "dominant_dir_err_deg",
];

impl Metrics {
    /// The six scores in the order of [`METRIC_NAMES`], for generic tables.
    pub fn values(&self) -> [f64; 6] {
        [
            self.psnr_tm,
            self.ssim_tm,
            self.mse_tm,
            self.log_lum_rmse,
            self.irradiance_rel_err,
            self.dominant_dir_err_deg,
        ]
    }

    /// Arithmetic mean of each score over frames (PSNR averaged in dB, after
    /// capping), with `invalid_pixels` summed; `None` for no frames.
    pub fn mean(frames: &[Metrics]) -> Option<Metrics> {
        if frames.is_empty() {
            return None;
        }
        let n = frames.len() as f64;
        let mut s = [0.0f64; 6];
        let mut invalid = 0u64;
        for m in frames {
            for (a, v) in s.iter_mut().zip(m.values()) {
                *a += v;
            }
            invalid = invalid.saturating_add(m.invalid_pixels);
        }
        let s = s.map(|v| v / n);
        Some(Metrics {
            psnr_tm: s[0],
            ssim_tm: s[1],
            mse_tm: s[2],
            log_lum_rmse: s[3],
            irradiance_rel_err: s[4],
            dominant_dir_err_deg: s[5],
            invalid_pixels: invalid,
        })
    }
}

/// Scores `pred` against `gt` (definitions in the [module docs](self)). Fails when
/// the sizes differ or an image is empty; use [`compare_resized`] to resample a
/// prediction of another size.
pub fn compare(pred: &HdrImage, gt: &HdrImage) -> Result<Metrics> {
    check_nonempty(gt, "ground truth")?;
    check_nonempty(pred, "prediction")?;
    if pred.width() != gt.width() || pred.height() != gt.height() {
        return Err(Error::Invalid(format!(
            "prediction is {}x{} but ground truth is {}x{}",
            pred.width(),
            pred.height(),
            gt.width(),
            gt.height()
        )));
    }
    Ok(compare_to_truth(pred, &Truth::new(gt)?)?.metrics)
}

/// Like [`compare`], but a prediction of another size is first repaired (its
/// invalid pixels counted at its own resolution) and resampled to the ground
/// truth's size with [`crate::sphere::resize`].
pub fn compare_resized(pred: &HdrImage, gt: &HdrImage) -> Result<Metrics> {
    check_nonempty(gt, "ground truth")?;
    check_nonempty(pred, "prediction")?;
    Ok(compare_to_truth(pred, &Truth::new(gt)?)?.metrics)
}

/// A ground-truth probe made ready for scoring, so that several predictions of
/// the same frame share its tone map, its SH projection, its irradiance at the
/// [`IRRADIANCE_NORMALS`] normals and its median luminance (each computed once).
pub struct Truth {
    /// The truth with invalid samples repaired.
    img: HdrImage,
    /// Its log-average luminance, the key of both tone maps.
    log_avg: f32,
    /// Its tone-mapped RGB.
    tm: Vec<f32>,
    /// Luma of `tm`, for SSIM.
    luma: Vec<f32>,
    /// Luminance SH coefficients.
    lum_sh: [f64; 9],
    /// Diffuse irradiance luminance at the Fibonacci normals.
    irradiance: Vec<f64>,
    /// The `eps` of `log_lum_rmse`.
    log_eps: f64,
}

impl Truth {
    /// Prepares `gt` (repaired silently); fails when it is empty.
    pub fn new(gt: &HdrImage) -> Result<Truth> {
        check_nonempty(gt, "ground truth")?;
        let (g, _) = sanitized(gt);
        let img = g.into_owned();
        let log_avg = crate::tonemap::log_average_luminance(&img);
        let ((tm, sh), log_eps) = rayon::join(
            || {
                rayon::join(
                    || crate::tonemap::reinhard_global(&img, TM_KEY, None, Some(log_avg)),
                    || project_f64(&img),
                )
            },
            || log_epsilon(&img),
        );
        let luma: Vec<f32> = tm.chunks_exact(3).map(luma_of).collect();
        let lum_sh = luminance_f64(&sh);
        Ok(Truth {
            irradiance: irradiance_at_normals(&lum_sh),
            img,
            log_avg,
            tm,
            luma,
            lum_sh,
            log_eps,
        })
    }

    /// Width and height of the truth.
    pub fn size(&self) -> (usize, usize) {
        (self.img.width(), self.img.height())
    }

    /// Diffuse irradiance luminance `Eg` at the [`IRRADIANCE_NORMALS`] Fibonacci
    /// normals (in the order of [`crate::ibl::fibonacci_directions`]).
    pub fn irradiance(&self) -> &[f64] {
        &self.irradiance
    }
}

/// The scores of one prediction and its diffuse irradiance luminance `Ep` at the
/// same normals as [`Truth::irradiance`], for temporal figures over frames.
#[derive(Clone, Debug, PartialEq)]
pub struct Comparison {
    /// The scores.
    pub metrics: Metrics,
    /// `Ep` at the [`IRRADIANCE_NORMALS`] normals.
    pub irradiance: Vec<f64>,
}

/// Scores `pred` against a prepared truth. A prediction of another size is
/// repaired first (invalid pixels counted at its own resolution) and resampled to
/// the truth's size, as in [`compare_resized`]. Fails when `pred` is empty.
pub fn compare_to_truth(pred: &HdrImage, truth: &Truth) -> Result<Comparison> {
    check_nonempty(pred, "prediction")?;
    let (p, invalid) = sanitized(pred);
    let (w, h) = truth.size();
    let p = if p.width() != w || p.height() != h {
        Cow::Owned(crate::sphere::resize(&p, w, h))
    } else {
        p
    };
    Ok(compare_clean(&p, truth, invalid))
}

fn check_nonempty(img: &HdrImage, what: &str) -> Result<()> {
    if img.width() == 0 || img.height() == 0 {
        return Err(Error::Invalid(format!(
            "{what} is empty ({}x{})",
            img.width(),
            img.height()
        )));
    }
    Ok(())
}

/// The image with NaN / infinite / negative samples repaired, and how many pixels
/// had at least one such sample. Borrows when nothing needs repair.
fn sanitized(img: &HdrImage) -> (Cow<'_, HdrImage>, u64) {
    let bad = img
        .data()
        .par_chunks(3 * img.width().max(1))
        .map(|row| {
            row.chunks_exact(3)
                .filter(|p| p.iter().any(|v| !v.is_finite() || *v < 0.0))
                .count() as u64
        })
        .sum::<u64>();
    if bad == 0 {
        return (Cow::Borrowed(img), 0);
    }
    let mut owned = img.clone();
    owned.repair_invalid();
    (Cow::Owned(owned), bad)
}

/// Rec. 709 luminance in `f64` (no overflow for samples near `f32::MAX`).
#[inline]
fn lum64(p: &[f32]) -> f64 {
    0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64
}

/// Luma of a tone-mapped pixel, the plane SSIM compares.
#[inline]
fn luma_of(a: &[f32]) -> f32 {
    0.299 * a[0] + 0.587 * a[1] + 0.114 * a[2]
}

/// All metrics for a non-empty, repaired prediction of the truth's size.
fn compare_clean(pred: &HdrImage, truth: &Truth, invalid_pixels: u64) -> Comparison {
    let (w, h) = truth.size();
    let (tm_p, (sh_p, log_lum_rmse)) = rayon::join(
        || crate::tonemap::reinhard_global(pred, TM_KEY, None, Some(truth.log_avg)),
        || {
            rayon::join(
                || project_f64(pred),
                || log_lum_rmse(pred, &truth.img, truth.log_eps),
            )
        },
    );

    // MSE over the tone-mapped RGB and the luma plane for SSIM.
    let mut luma_p = vec![0.0f32; w * h];
    let sse: f64 = luma_p
        .par_chunks_mut(w)
        .zip(tm_p.par_chunks(3 * w).zip(truth.tm.par_chunks(3 * w)))
        .map(|(lp, (tp, tg))| {
            let mut s = 0.0f64;
            for (i, (a, b)) in tp.chunks_exact(3).zip(tg.chunks_exact(3)).enumerate() {
                for c in 0..3 {
                    let d = (a[c] - b[c]) as f64;
                    s += d * d;
                }
                lp[i] = luma_of(a);
            }
            s
        })
        .collect::<Vec<f64>>()
        .iter()
        .sum();
    let mse_tm = sse / (3 * w * h) as f64;
    let psnr_tm = if mse_tm > 0.0 {
        (10.0 * (1.0 / mse_tm).log10()).min(PSNR_CAP_DB)
    } else {
        PSNR_CAP_DB
    };
    let ssim_tm = ssim(&luma_p, &truth.luma, w, h);

    let lp = luminance_f64(&sh_p);
    let ep = irradiance_at_normals(&lp);
    Comparison {
        metrics: Metrics {
            psnr_tm,
            ssim_tm,
            mse_tm,
            log_lum_rmse,
            irradiance_rel_err: irradiance_rel_err(&ep, &truth.irradiance),
            dominant_dir_err_deg: dominant_dir_err_deg(&lp, &truth.lum_sh),
            invalid_pixels,
        },
        irradiance: ep,
    }
}

/// The `eps` of `log_lum_rmse`: `1e-3` of the truth's median luminance (`1e-6`
/// when that median is 0 or not finite).
fn log_epsilon(gt: &HdrImage) -> f64 {
    let mut lums: Vec<f64> = gt.data().chunks_exact(3).map(lum64).collect();
    let n = lums.len();
    let mid = n / 2;
    let (lower, upper_mid, _) = lums.select_nth_unstable_by(mid, f64::total_cmp);
    let mut median = *upper_mid;
    if n % 2 == 0 {
        let below = lower.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        median = 0.5 * (median + below);
    }
    if median > 0.0 && median.is_finite() {
        1e-3 * median
    } else {
        1e-6
    }
}

/// Solid-angle-weighted RMSE of log10 luminance (see the module docs), with the
/// truth's `eps` from [`log_epsilon`].
fn log_lum_rmse(pred: &HdrImage, gt: &HdrImage, eps: f64) -> f64 {
    let (w, h) = (gt.width(), gt.height());
    let rows: Vec<(f64, f64)> = pred
        .data()
        .par_chunks(3 * w)
        .zip(gt.data().par_chunks(3 * w))
        .enumerate()
        .map(|(row, (rp, rg))| {
            let mut s = 0.0f64;
            for (a, b) in rp.chunks_exact(3).zip(rg.chunks_exact(3)) {
                // One logarithm per pixel: log10 of the ratio (both terms >= eps).
                let d = ((lum64(a) + eps) / (lum64(b) + eps)).log10();
                s += d * d;
            }
            let da = crate::sphere::pixel_solid_angle(row, w, h) as f64;
            (s * da, da * w as f64)
        })
        .collect();
    let (num, den) = rows
        .iter()
        .fold((0.0, 0.0), |(n, d), (a, b)| (n + a, d + b));
    if den > 0.0 {
        (num / den).sqrt()
    } else {
        0.0
    }
}

/// The [`IRRADIANCE_NORMALS`] Fibonacci normals in `f64`, made once.
fn irradiance_normals() -> &'static [[f64; 3]] {
    static NORMALS: std::sync::OnceLock<Vec<[f64; 3]>> = std::sync::OnceLock::new();
    NORMALS.get_or_init(|| {
        crate::ibl::fibonacci_directions(IRRADIANCE_NORMALS)
            .into_iter()
            .map(|n| [n.x as f64, n.y as f64, n.z as f64])
            .collect()
    })
}

/// Diffuse irradiance luminance of SH luminance coefficients at each of the
/// [`IRRADIANCE_NORMALS`] Fibonacci normals.
fn irradiance_at_normals(l: &[f64; 9]) -> Vec<f64> {
    irradiance_normals()
        .iter()
        .map(|&n| irradiance_scalar_f64(l, n))
        .collect()
}

/// Relative L2 error of irradiance luminance over the Fibonacci normals.
fn irradiance_rel_err(ep: &[f64], eg: &[f64]) -> f64 {
    let mut diff2 = 0.0f64;
    let mut gt2 = 0.0f64;
    let mut pred2 = 0.0f64;
    for (&ep, &eg) in ep.iter().zip(eg) {
        diff2 += (ep - eg) * (ep - eg);
        gt2 += eg * eg;
        pred2 += ep * ep;
    }
    let r = if gt2 > 0.0 {
        (diff2 / gt2).sqrt()
    } else if pred2 > 0.0 {
        1.0
    } else {
        0.0
    };
    if r.is_finite() {
        r
    } else {
        1.0
    }
}

/// Angle in degrees between the dominant directions (0 / 90 rules in the module
/// docs).
fn dominant_dir_err_deg(lp: &[f64; 9], lg: &[f64; 9]) -> f64 {
    match (dominant_dir_f64(lp), dominant_dir_f64(lg)) {
        (Some(a), Some(b)) => {
            let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
            let cx = a[1] * b[2] - a[2] * b[1];
            let cy = a[2] * b[0] - a[0] * b[2];
            let cz = a[0] * b[1] - a[1] * b[0];
            let cross = (cx * cx + cy * cy + cz * cz).sqrt();
            cross.atan2(dot).to_degrees()
        }
        (None, None) => 0.0,
        _ => 90.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sphere::pixel_to_dir;

    /// A sky-like test probe: bright upper hemisphere, a sun, textured ground.
    fn sunlit(w: usize, h: usize) -> HdrImage {
        let sun = glam::Vec3::new(0.3, 0.6, -0.74).normalize();
        HdrImage::from_fn(w, h, |x, y| {
            let d = pixel_to_dir(x, y, w, h);
            let sky = if d.y > 0.0 {
                [0.4 + 0.6 * d.y, 0.6 + 0.6 * d.y, 1.0 + 0.8 * d.y]
            } else {
                let t = 0.2 + 0.1 * ((x as f32 * 0.7).sin() * (y as f32 * 0.5).cos());
                [t, 0.8 * t, 0.6 * t]
            };
            if d.dot(sun) > 0.999 {
                [5e4, 4.5e4, 4e4]
            } else {
                sky
            }
        })
    }

    fn noisy(img: &HdrImage, amp: f32, seed: u64) -> HdrImage {
        let mut s = seed;
        let mut out = img.clone();
        for v in out.data_mut() {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let r = (s >> 40) as f32 / (1u64 << 24) as f32 - 0.5;
            *v *= 1.0 + amp * r;
        }
        out
    }

    #[test]
    fn identical_images_score_perfectly() {
        let gt = sunlit(128, 64);
        let m = compare(&gt, &gt).unwrap();
        assert_eq!(m.psnr_tm, PSNR_CAP_DB);
        assert_eq!(m.mse_tm, 0.0);
        assert!((m.ssim_tm - 1.0).abs() < 1e-12, "{}", m.ssim_tm);
        assert_eq!(m.log_lum_rmse, 0.0);
        assert_eq!(m.irradiance_rel_err, 0.0);
        assert!(m.dominant_dir_err_deg.abs() < 1e-6);
        assert_eq!(m.invalid_pixels, 0);
    }

    #[test]
    fn noisy_copy_has_high_but_imperfect_ssim() {
        let gt = sunlit(128, 64);
        let pred = noisy(&gt, 0.2, 7);
        let m = compare(&pred, &gt).unwrap();
        assert!(m.ssim_tm < 1.0 && m.ssim_tm > 0.5, "{}", m.ssim_tm);
        assert!(m.psnr_tm < PSNR_CAP_DB && m.psnr_tm > 20.0, "{}", m.psnr_tm);
        assert!(m.mse_tm > 0.0);
    }

    #[test]
    fn doubling_the_prediction() {
        let gt = sunlit(128, 64);
        let mut pred = gt.clone();
        for v in pred.data_mut() {
            *v *= 2.0;
        }
        let m = compare(&pred, &gt).unwrap();
        let want = 2f64.log10();
        assert!((m.log_lum_rmse - want).abs() < 1e-3, "{}", m.log_lum_rmse);
        assert!(
            (m.irradiance_rel_err - 1.0).abs() < 1e-9,
            "{}",
            m.irradiance_rel_err
        );
        assert!(m.dominant_dir_err_deg < 1e-3);
        // Same log-average for both tone maps: the exposure error is visible.
        assert!(m.psnr_tm < 40.0, "{}", m.psnr_tm);
    }

    #[test]
    fn constant_prediction_against_sunlit_gt_is_finite() {
        let gt = sunlit(128, 64);
        let pred = HdrImage::from_fn(128, 64, |_, _| [1.0, 1.0, 1.0]);
        let m = compare(&pred, &gt).unwrap();
        assert!(m.values().iter().all(|v| v.is_finite()), "{m:?}");
        assert_eq!(m.dominant_dir_err_deg, 90.0);
        let black = HdrImage::new(128, 64);
        for (p, g) in [(&black, &gt), (&gt, &black), (&black, &black)] {
            let m = compare(p, g).unwrap();
            assert!(m.values().iter().all(|v| v.is_finite()), "{m:?}");
        }
        assert_eq!(compare(&black, &black).unwrap().irradiance_rel_err, 0.0);
        assert_eq!(compare(&gt, &black).unwrap().irradiance_rel_err, 1.0);
    }

    #[test]
    fn invalid_samples_are_counted_and_repaired() {
        let gt = sunlit(64, 32);
        let mut pred = gt.clone();
        pred.set(1, 1, [f32::NAN, 0.0, 0.0]);
        pred.set(2, 1, [f32::INFINITY, f32::NEG_INFINITY, 1.0]);
        pred.set(3, 1, [-1.0, 1.0, 1.0]);
        pred.set(4, 1, [f32::MAX, f32::MAX, f32::MAX]);
        let m = compare(&pred, &gt).unwrap();
        assert_eq!(m.invalid_pixels, 3);
        assert!(m.values().iter().all(|v| v.is_finite()), "{m:?}");
    }

    #[test]
    fn dominant_direction_of_a_spot_is_recovered() {
        let (w, h) = (256, 128);
        let spot = |x: usize, y: usize| {
            let mut img = HdrImage::new(w, h);
            img.set(x, y, [1e3, 1e3, 1e3]);
            img
        };
        // A spot compared with the same spot: 0; with one whose known direction is
        // 40 degrees away: 40, within 2 degrees.
        let a = spot(60, 40);
        let want_a = pixel_to_dir(60, 40, w, h);
        let b_dir = {
            let axis = want_a.cross(glam::Vec3::Y).normalize();
            glam::Quat::from_axis_angle(axis, 40f32.to_radians()) * want_a
        };
        let (u, v) = crate::sphere::dir_to_uv(b_dir);
        let b = spot((u * w as f32) as usize, (v * h as f32) as usize);
        let m = compare(&a, &b).unwrap();
        assert!(
            (m.dominant_dir_err_deg - 40.0).abs() < 2.0,
            "{}",
            m.dominant_dir_err_deg
        );
        let sh = crate::ibl::Sh9::project(&a);
        let got = sh.dominant_direction().unwrap();
        assert!(got.angle_between(want_a).to_degrees() < 2.0);
    }

    #[test]
    fn size_mismatch_is_an_error_unless_resized() {
        let gt = sunlit(128, 64);
        let small = sunlit(64, 32);
        assert!(compare(&small, &gt).is_err());
        assert!(compare(&HdrImage::new(0, 0), &HdrImage::new(0, 0)).is_err());
        let m = compare_resized(&small, &gt).unwrap();
        assert!(m.values().iter().all(|v| v.is_finite()));
        assert!(m.ssim_tm > 0.5, "{}", m.ssim_tm);
        assert!(m.irradiance_rel_err < 0.1, "{}", m.irradiance_rel_err);
    }

    #[test]
    fn results_do_not_depend_on_thread_count() {
        let gt = sunlit(96, 48);
        let pred = noisy(&gt, 0.3, 3);
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| compare(&pred, &gt).unwrap());
        let two = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap()
            .install(|| compare(&pred, &gt).unwrap());
        assert_eq!(one, two);
    }

    #[test]
    fn mean_over_frames() {
        let gt = sunlit(64, 32);
        let a = compare(&gt, &gt).unwrap();
        let b = compare(&noisy(&gt, 0.2, 1), &gt).unwrap();
        let m = Metrics::mean(&[a, b]).unwrap();
        assert!((m.ssim_tm - 0.5 * (a.ssim_tm + b.ssim_tm)).abs() < 1e-12);
        assert!(Metrics::mean(&[]).is_none());
    }
}

#[cfg(test)]
mod timing {
    use super::*;

    /// `cargo test --release --lib eval::timing -- --ignored --nocapture`
    #[test]
    #[ignore]
    fn compare_512x256_timing() {
        let gt = HdrImage::from_fn(512, 256, |x, y| {
            let v = 0.1 + ((x * 7 + y * 13) % 97) as f32 / 50.0;
            [v, 0.9 * v, 0.8 * v]
        });
        let pred = HdrImage::from_fn(512, 256, |x, y| {
            let v = 0.12 + ((x * 5 + y * 11) % 89) as f32 / 45.0;
            [v, 0.9 * v, 0.8 * v]
        });
        println!("{:?}", compare(&pred, &gt).unwrap());
        let n = 20;
        let t = std::time::Instant::now();
        for _ in 0..n {
            std::hint::black_box(compare(&pred, &gt).unwrap());
        }
        let per = t.elapsed().as_secs_f64() * 1e3 / n as f64;
        let t2 = std::time::Instant::now();
        for _ in 0..n {
            std::hint::black_box(crate::tonemap::reinhard_global(&gt, 0.18, None, Some(0.5)));
        }
        let tm = t2.elapsed().as_secs_f64() * 1e3 / n as f64;
        let l: Vec<f32> = gt.pixels().map(|p| p[1] / 3.0).collect();
        let t3 = std::time::Instant::now();
        for _ in 0..n {
            std::hint::black_box(ssim(&l, &l, 512, 256));
        }
        let ss = t3.elapsed().as_secs_f64() * 1e3 / n as f64;
        let t4 = std::time::Instant::now();
        for _ in 0..n {
            std::hint::black_box(project_f64(&gt));
        }
        let sh = t4.elapsed().as_secs_f64() * 1e3 / n as f64;
        let t5 = std::time::Instant::now();
        for _ in 0..n {
            std::hint::black_box(log_lum_rmse(&pred, &gt, log_epsilon(&gt)));
        }
        let ll = t5.elapsed().as_secs_f64() * 1e3 / n as f64;
        println!("compare {per:.2} ms; tonemap {tm:.2}; ssim {ss:.2}; sh {sh:.2}; loglum {ll:.2}");
    }
}
