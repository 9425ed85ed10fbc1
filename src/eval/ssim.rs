//! Structural similarity (SSIM) of two single-channel images, after Z. Wang,
//! A. C. Bovik, H. R. Sheikh and E. P. Simoncelli, "Image quality assessment: from
//! error visibility to structural similarity", IEEE TIP 13(4), 2004.
//!
//! Local statistics use the paper's 11x11 Gaussian window (sigma 1.5, normalised),
//! applied as two separable 1-D passes. Panorama borders are handled as on the
//! sphere: columns wrap around the `u = 0/1` seam, and a row beyond a pole is the
//! mirrored row at the opposite longitude (shifted by `w / 2`).

use rayon::prelude::*;

/// SSIM constant `K1` (paper default).
pub const SSIM_K1: f64 = 0.01;
/// SSIM constant `K2` (paper default).
pub const SSIM_K2: f64 = 0.03;
/// Standard deviation of the Gaussian window, in pixels.
pub const SSIM_SIGMA: f64 = 1.5;
/// Half-width of the window: 5, so the window is 11x11.
pub const SSIM_RADIUS: usize = 5;

/// Normalised 1-D Gaussian taps of length `2 radius + 1`.
pub fn gaussian_kernel(sigma: f64, radius: usize) -> Vec<f32> {
    let taps: Vec<f64> = (0..=2 * radius)
        .map(|i| {
            let t = i as f64 - radius as f64;
            (-(t * t) / (2.0 * sigma * sigma)).exp()
        })
        .collect();
    let s: f64 = taps.iter().sum();
    taps.iter().map(|v| (v / s) as f32).collect()
}

/// Number of local statistics blurred: a, b, a^2, b^2, a b.
const PLANES: usize = 5;

/// Source row and whether it was reached across a pole (then read at the opposite
/// longitude) for a possibly out-of-range row index.
#[inline]
fn source_row(mut r: isize, h: isize) -> (usize, bool) {
    let mut crossed = false;
    while r < 0 || r >= h {
        r = if r < 0 { -r - 1 } else { 2 * h - r - 1 };
        crossed = !crossed;
    }
    (r as usize, crossed)
}

/// Mean SSIM of two `w x h` single-channel images with dynamic range `L = 1`
/// (values in `[0, 1]`): the per-pixel
/// `((2 mu_a mu_b + C1)(2 s_ab + C2)) / ((mu_a^2 + mu_b^2 + C1)(s_a^2 + s_b^2 + C2))`
/// with `C1 = (K1 L)^2`, `C2 = (K2 L)^2`, averaged over all pixels.
///
/// Identical inputs give exactly 1. Deterministic regardless of the thread count
/// (per-row sums added in row order). Returns 1 for an empty image.
///
/// # Panics
/// When `a` or `b` does not hold `w * h` values.
pub fn ssim(a: &[f32], b: &[f32], w: usize, h: usize) -> f64 {
    assert_eq!(a.len(), w * h, "ssim: first image has the wrong size");
    assert_eq!(b.len(), w * h, "ssim: second image has the wrong size");
    if w == 0 || h == 0 {
        return 1.0;
    }
    let k = gaussian_kernel(SSIM_SIGMA, SSIM_RADIUS);
    let r = SSIM_RADIUS;
    let c1 = SSIM_K1 * SSIM_K1;
    let c2 = SSIM_K2 * SSIM_K2;

    // Horizontal pass: each row holds PLANES segments of w blurred values.
    let wrap: Vec<usize> = (0..w + 2 * r)
        .map(|i| (i as isize - r as isize).rem_euclid(w as isize) as usize)
        .collect();
    let mut hbuf = vec![0.0f32; PLANES * w * h];
    hbuf.par_chunks_mut(PLANES * w)
        .zip(a.par_chunks(w).zip(b.par_chunks(w)))
        .for_each_init(
            || vec![0.0f32; PLANES * (w + 2 * r)],
            |pad, (out, (ra, rb))| {
                let pw = w + 2 * r;
                for (i, &j) in wrap.iter().enumerate() {
                    let (x, y) = (ra[j], rb[j]);
                    pad[i] = x;
                    pad[pw + i] = y;
                    pad[2 * pw + i] = x * x;
                    pad[3 * pw + i] = y * y;
                    pad[4 * pw + i] = x * y;
                }
                for q in 0..PLANES {
                    let src = &pad[q * pw..(q + 1) * pw];
                    let dst = &mut out[q * w..(q + 1) * w];
                    dst.fill(0.0);
                    for (t, &kt) in k.iter().enumerate() {
                        for (d, s) in dst.iter_mut().zip(&src[t..t + w]) {
                            *d += kt * s;
                        }
                    }
                }
            },
        );

    // Vertical pass and the SSIM map, summed per row.
    let shift = w / 2;
    let row_sums: Vec<f64> = (0..h)
        .into_par_iter()
        .map_init(
            || vec![0.0f32; PLANES * w],
            |acc, y| {
                acc.fill(0.0);
                for (t, &kt) in k.iter().enumerate() {
                    let (sr, crossed) =
                        source_row(y as isize + t as isize - r as isize, h as isize);
                    let row = &hbuf[sr * PLANES * w..(sr + 1) * PLANES * w];
                    for q in 0..PLANES {
                        let src = &row[q * w..(q + 1) * w];
                        let dst = &mut acc[q * w..(q + 1) * w];
                        if crossed && shift > 0 {
                            // dst[x] += src[(x + shift) % w], as two contiguous runs.
                            let (lo, hi) = dst.split_at_mut(w - shift);
                            for (d, s) in lo.iter_mut().zip(&src[shift..]) {
                                *d += kt * s;
                            }
                            for (d, s) in hi.iter_mut().zip(&src[..shift]) {
                                *d += kt * s;
                            }
                        } else {
                            for (d, s) in dst.iter_mut().zip(src) {
                                *d += kt * s;
                            }
                        }
                    }
                }
                let mut sum = 0.0f64;
                for x in 0..w {
                    let ma = acc[x] as f64;
                    let mb = acc[w + x] as f64;
                    // E[x^2] - mu^2 in f32 sums can round below zero or break
                    // Cauchy-Schwarz (SSIM above 1 on flat windows): keep the
                    // statistics consistent.
                    let saa = (acc[2 * w + x] as f64 - ma * ma).max(0.0);
                    let sbb = (acc[3 * w + x] as f64 - mb * mb).max(0.0);
                    let lim = (saa * sbb).sqrt();
                    let sab = (acc[4 * w + x] as f64 - ma * mb).clamp(-lim, lim);
                    let num = (2.0 * ma * mb + c1) * (2.0 * sab + c2);
                    let den = (ma * ma + mb * mb + c1) * (saa + sbb + c2);
                    sum += num / den;
                }
                sum
            },
        )
        .collect();
    row_sums.iter().sum::<f64>() / (w * h) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pattern(w: usize, h: usize) -> Vec<f32> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                0.5 + 0.3 * (x * 0.3).sin() * (y * 0.2).cos()
            })
            .collect()
    }

    #[test]
    fn kernel_is_normalised_and_symmetric() {
        let k = gaussian_kernel(SSIM_SIGMA, SSIM_RADIUS);
        assert_eq!(k.len(), 11);
        assert!((k.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        for i in 0..5 {
            assert_eq!(k[i], k[10 - i]);
        }
    }

    #[test]
    fn identical_images_score_one() {
        let a = pattern(40, 20);
        assert_eq!(ssim(&a, &a, 40, 20), 1.0);
        // Tiny images (smaller than the window) still work.
        let t = pattern(3, 2);
        assert_eq!(ssim(&t, &t, 3, 2), 1.0);
    }

    #[test]
    fn mean_shift_and_inversion_lower_the_score() {
        let a = pattern(64, 32);
        let shifted: Vec<f32> = a.iter().map(|v| v + 0.1).collect();
        let inverted: Vec<f32> = a.iter().map(|v| 1.0 - v).collect();
        let s1 = ssim(&a, &shifted, 64, 32);
        let s2 = ssim(&a, &inverted, 64, 32);
        assert!(s1 < 1.0 && s1 > 0.8, "{s1}");
        assert!(s2 < 0.0, "{s2}");
    }

    #[test]
    fn pole_rows_wrap_to_opposite_longitude() {
        assert_eq!(source_row(-1, 8), (0, true));
        assert_eq!(source_row(-3, 8), (2, true));
        assert_eq!(source_row(8, 8), (7, true));
        assert_eq!(source_row(4, 8), (4, false));
        assert_eq!(source_row(-2, 1), (0, false));
    }
}
