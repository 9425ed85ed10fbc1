//! Spherical geometry of equirectangular panoramas and cube maps.
//!
//! Conventions (those of the evaluation data): pixel `(col, row)` of a `W x H`
//! panorama has `u = (col + 0.5) / W`, `v = (row + 0.5) / H`, longitude
//! `phi = (u - 0.5) * 2 pi` (positive to the right), latitude
//! `theta = (0.5 - v) * pi` (positive up), and camera direction
//! `d = (cos theta sin phi, sin theta, -cos theta cos phi)`: x right, y up,
//! -z forward, so the image centre looks forward.

pub mod cube;
pub mod mask;

pub use cube::{CubeFace, FACES};

use crate::image::HdrImage;
use glam::{Mat3, Vec3};
use std::f32::consts::PI;

/// Camera direction of the panorama point at normalised coordinates `(u, v)`.
#[inline]
pub fn uv_to_dir(u: f32, v: f32) -> Vec3 {
    let phi = (u - 0.5) * 2.0 * PI;
    let theta = (0.5 - v) * PI;
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    Vec3::new(ct * sp, st, -ct * cp)
}

/// Camera direction through the centre of pixel `(col, row)` of a `w x h` panorama.
#[inline]
pub fn pixel_to_dir(col: usize, row: usize, w: usize, h: usize) -> Vec3 {
    uv_to_dir((col as f32 + 0.5) / w as f32, (row as f32 + 0.5) / h as f32)
}

/// Angular radius (radians) of a small disc that fills `solid_angle` steradians
/// (`solid_angle = pi r^2`; the small-angle cap). Zero for no solid angle.
pub fn disc_radius(solid_angle: f64) -> f64 {
    (solid_angle.max(0.0) / std::f64::consts::PI).sqrt()
}

/// Normalised panorama coordinates `(u, v)` of a direction (need not be unit length).
/// `u` is in `[0, 1)`, `v` in `[0, 1]`.
#[inline]
pub fn dir_to_uv(d: Vec3) -> (f32, f32) {
    let r = d.length();
    if r == 0.0 || !r.is_finite() {
        return (0.5, 0.5);
    }
    let theta = (d.y / r).clamp(-1.0, 1.0).asin();
    let phi = d.x.atan2(-d.z);
    let mut u = phi / (2.0 * PI) + 0.5;
    if u >= 1.0 {
        u -= 1.0;
    }
    if u < 0.0 {
        u += 1.0;
    }
    (u, 0.5 - theta / PI)
}

/// Solid angle in steradians covered by one pixel of row `row` of a `w x h` panorama.
/// Summed over the image it gives exactly `4 pi`.
#[inline]
pub fn pixel_solid_angle(row: usize, w: usize, h: usize) -> f32 {
    let dphi = 2.0 * std::f64::consts::PI / w as f64;
    let t0 = (0.5 - row as f64 / h as f64) * std::f64::consts::PI;
    let t1 = (0.5 - (row + 1) as f64 / h as f64) * std::f64::consts::PI;
    (dphi * (t0.sin() - t1.sin())) as f32
}

/// Per-row solid angles of a `w x h` panorama (every pixel in a row has the same).
pub fn row_solid_angles(w: usize, h: usize) -> Vec<f32> {
    (0..h).map(|r| pixel_solid_angle(r, w, h)).collect()
}

/// Bilinear sample of a panorama at continuous pixel coordinates, wrapping across the
/// `u = 0/1` seam and across the poles (a row above the top is the top row seen from
/// the opposite longitude), so there is no discontinuity anywhere on the sphere.
#[inline]
pub fn sample_px(img: &HdrImage, x: f32, y: f32) -> [f32; 3] {
    let d = img.data();
    sample_px_by(img.width(), img.height(), x, y, |i| {
        [d[3 * i], d[3 * i + 1], d[3 * i + 2]]
    })
}

/// [`sample_px`] of a `w x h` panorama whose pixel `i` (row-major) has the value
/// `px(i)`, computed only at the four pixels sampled: a panorama held in another
/// form (8-bit codes, radiance to be tone-mapped) is sampled exactly as
/// [`sample_px`] would sample it once converted to `f32`, without the converted copy.
#[inline]
pub fn sample_px_by(
    w: usize,
    h: usize,
    x: f32,
    y: f32,
    px: impl Fn(usize) -> [f32; 3],
) -> [f32; 3] {
    let wu = w;
    let w = w as i64;
    let h = h as i64;
    let xf = x - 0.5;
    let yf = y - 0.5;
    let x0 = floor(xf);
    let y0 = floor(yf);
    let fx = xf - x0;
    let fy = yf - y0;
    let x0 = x0 as i64;
    let y0 = y0 as i64;
    if x0 >= 0 && y0 >= 0 && x0 + 1 < w && y0 + 1 < h {
        // Interior: no wrapping needed.
        let (x0, y0) = (x0 as usize, y0 as usize);
        let i = y0 * wu + x0;
        let j = i + wu;
        let (a, b, c, d) = (px(i), px(i + 1), px(j), px(j + 1));
        let mut out = [0.0; 3];
        for k in 0..3 {
            let top = a[k] + (b[k] - a[k]) * fx;
            let bot = c[k] + (d[k] - c[k]) * fx;
            out[k] = top + (bot - top) * fy;
        }
        return out;
    }
    let fetch = |xi: i64, yi: i64| -> [f32; 3] {
        let (mut xi, mut yi) = (xi, yi);
        if yi < 0 {
            yi = -yi - 1;
            xi += w / 2;
        } else if yi >= h {
            yi = 2 * h - yi - 1;
            xi += w / 2;
        }
        let yi = yi.clamp(0, h - 1);
        let xi = xi.rem_euclid(w);
        px(yi as usize * wu + xi as usize)
    };
    let a = fetch(x0, y0);
    let b = fetch(x0 + 1, y0);
    let c = fetch(x0, y0 + 1);
    let d = fetch(x0 + 1, y0 + 1);
    let mut out = [0.0; 3];
    for k in 0..3 {
        let top = a[k] + (b[k] - a[k]) * fx;
        let bot = c[k] + (d[k] - c[k]) * fx;
        out[k] = top + (bot - top) * fy;
    }
    out
}

/// `x.floor()` without the library call (targets without SSE4.1 make `floor` a
/// call into libm, a tenth of a fusion frame's bilinear sampling): the same
/// value for every finite `x` (ties to the sign of zero aside), and `floor`
/// itself beyond 2^23, where every float is an integer, and for NaN.
#[inline(always)]
pub fn floor(x: f32) -> f32 {
    if x.abs() < 8_388_608.0 {
        let t = x as i32 as f32;
        if t > x {
            t - 1.0
        } else {
            t
        }
    } else {
        x.floor()
    }
}

/// Bilinear sample of a panorama in the direction `d` (camera axes).
#[inline]
pub fn sample_dir(img: &HdrImage, d: Vec3) -> [f32; 3] {
    let (u, v) = dir_to_uv(d);
    sample_px(img, u * img.width() as f32, v * img.height() as f32)
}

/// Resamples a panorama so that output direction `d` shows the input in direction
/// `r * d`. To bring a probe with pose `R_p` into a frame with pose `R_f`
/// (both world-from-camera), pass `r = R_p^T R_f`.
pub fn rotate(img: &HdrImage, r: Mat3, out_w: usize, out_h: usize) -> HdrImage {
    use rayon::prelude::*;
    let mut out = HdrImage::new(out_w, out_h);
    // The pixel directions are separable: sines and cosines once per column and
    // per row (the same arithmetic as `pixel_to_dir`, so the same directions).
    let cols: Vec<(f32, f32)> = (0..out_w)
        .map(|col| (((col as f32 + 0.5) / out_w as f32 - 0.5) * 2.0 * PI).sin_cos())
        .collect();
    out.rows_mut()
        .enumerate()
        .par_bridge()
        .for_each(|(row, line)| {
            let (st, ct) = ((0.5 - (row as f32 + 0.5) / out_h as f32) * PI).sin_cos();
            for (col, &(sp, cp)) in cols.iter().enumerate() {
                let d = r * Vec3::new(ct * sp, st, -ct * cp);
                let c = sample_dir(img, d);
                line[3 * col..3 * col + 3].copy_from_slice(&c);
            }
        });
    out
}

/// A panorama at most `max_w` wide, each output pixel the solid-angle weighted
/// mean radiance of a `k` x `k` block (the smallest `k` that divides both sides
/// and brings the width to `max_w` or under): every block's power (radiance x
/// solid angle) is kept, so a sun a pixel wide keeps its light. `None` when no
/// such `k` exists (sides with no common divisor in range); the image itself
/// when it is narrow enough.
pub fn downsample_box(img: &HdrImage, max_w: usize) -> Option<HdrImage> {
    let (w, h) = (img.width(), img.height());
    if w <= max_w || w == 0 || h == 0 {
        return Some(img.clone());
    }
    let k = (w.div_ceil(max_w.max(1))..=w.min(h)).find(|k| w % k == 0 && h % k == 0)?;
    let (ow, oh) = (w / k, h / k);
    let sa = row_solid_angles(w, h);
    let mut out = HdrImage::new(ow, oh);
    for oy in 0..oh {
        let rows = oy * k..(oy + 1) * k;
        let weight: f64 = rows.clone().map(|y| sa[y] as f64).sum::<f64>() * k as f64;
        for ox in 0..ow {
            let mut acc = [0.0f64; 3];
            for y in rows.clone() {
                for x in ox * k..(ox + 1) * k {
                    let c = img.get(x, y);
                    for ch in 0..3 {
                        acc[ch] += c[ch] as f64 * sa[y] as f64;
                    }
                }
            }
            out.set(
                ox,
                oy,
                acc.map(|a| {
                    if weight > 0.0 {
                        (a / weight) as f32
                    } else {
                        0.0
                    }
                }),
            );
        }
    }
    Some(out)
}

/// Resamples a panorama to a new size (bilinear, seam- and pole-aware).
pub fn resize(img: &HdrImage, out_w: usize, out_h: usize) -> HdrImage {
    if img.width() == out_w && img.height() == out_h {
        return img.clone();
    }
    rotate(img, Mat3::IDENTITY, out_w, out_h)
}

/// Rotation matrix from yaw (about +y, to the right positive), pitch (about +x, up
/// positive) and roll (about -z, clockwise positive), all in degrees, applied in
/// that order: `R = Ry(yaw) * Rx(pitch) * Rz(roll)`.
pub fn ypr_to_mat(yaw_deg: f32, pitch_deg: f32, roll_deg: f32) -> Mat3 {
    let y = Mat3::from_rotation_y(-yaw_deg.to_radians());
    let p = Mat3::from_rotation_x(pitch_deg.to_radians());
    let r = Mat3::from_rotation_z(-roll_deg.to_radians());
    y * p * r
}

/// Nearest proper rotation to a 3x3 matrix (polar decomposition by Newton iteration),
/// so poses with slightly non-orthonormal rotations still give a rigid motion.
/// Returns `None` for a singular or non-finite matrix and for a mirror
/// (determinant < 0): no rotation is near a reflection, and negating it would
/// turn the camera by 180 degrees instead.
pub fn orthonormalize(m: Mat3) -> Option<Mat3> {
    if !m.is_finite() || m.determinant() < 1e-6 {
        return None;
    }
    let mut x = m;
    for _ in 0..30 {
        let inv_t = x.inverse().transpose();
        let next = (x + inv_t) * 0.5;
        let diff = (next - x).abs_diff_eq(Mat3::ZERO, 1e-7);
        x = next;
        if diff {
            break;
        }
    }
    if x.is_finite() && (x.determinant() - 1.0).abs() < 1e-3 {
        Some(x)
    } else {
        None
    }
}

#[cfg(test)]
mod box_tests {
    use super::*;

    fn power(img: &HdrImage) -> f64 {
        let sa = row_solid_angles(img.width(), img.height());
        (0..img.height())
            .flat_map(|y| (0..img.width()).map(move |x| (x, y)))
            .map(|(x, y)| crate::image::luminance(img.get(x, y)) as f64 * sa[y] as f64)
            .sum()
    }

    #[test]
    fn a_box_downsample_keeps_the_power_of_a_one_pixel_sun() {
        let img = HdrImage::from_fn(96, 48, |x, y| {
            if (x, y) == (37, 11) {
                [1e6, 9e5, 8e5]
            } else {
                [
                    0.2 + 0.01 * (x % 7) as f32,
                    0.3,
                    0.1 + 0.02 * (y % 5) as f32,
                ]
            }
        });
        let small = downsample_box(&img, 32).unwrap();
        assert_eq!((small.width(), small.height()), (32, 16));
        let (a, b) = (power(&img), power(&small));
        assert!((b / a - 1.0).abs() < 1e-4, "{b} against {a}");
        // Narrow enough: unchanged; sides with no common divisor: none.
        assert_eq!(downsample_box(&img, 96).unwrap(), img);
        assert!(downsample_box(&HdrImage::new(97, 47), 32).is_none());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_without_the_library_call_is_floor() {
        let mut v: Vec<f32> = vec![
            0.0,
            -0.5,
            0.5,
            -1.0,
            1.0,
            -1.5,
            2.999_999_8,
            -2.999_999_8,
            8_388_607.5,
            -8_388_607.5,
            8_388_608.0,
            1e9,
            -1e9,
            f32::MAX,
            f32::MIN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            1e-30,
            -1e-30,
        ];
        let mut s = 0x9e37_79b9u32;
        for _ in 0..100_000 {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            v.push((s as f32 / u32::MAX as f32 - 0.5) * 2e3);
            v.push(f32::from_bits(s));
        }
        for x in v {
            let (a, b) = (floor(x), x.floor());
            assert!(
                a == b || (a.is_nan() && b.is_nan()),
                "floor({x}) = {a}, not {b}"
            );
        }
        assert!(floor(f32::NAN).is_nan());
    }

    #[test]
    fn centre_looks_forward_and_right_is_three_quarters() {
        let d = uv_to_dir(0.5, 0.5);
        assert!((d - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-6);
        let r = uv_to_dir(0.75, 0.5);
        assert!((r - Vec3::X).length() < 1e-6);
        let up = uv_to_dir(0.3, 0.0);
        assert!((up - Vec3::Y).length() < 1e-6);
    }

    #[test]
    fn dir_uv_round_trip() {
        for &(u, v) in &[(0.1f32, 0.2f32), (0.9, 0.7), (0.5, 0.5), (0.01, 0.99)] {
            let (u2, v2) = dir_to_uv(uv_to_dir(u, v));
            assert!(
                (u - u2).abs() < 1e-5 && (v - v2).abs() < 1e-5,
                "{u},{v} -> {u2},{v2}"
            );
        }
    }

    #[test]
    fn solid_angles_sum_to_four_pi() {
        let s: f64 = row_solid_angles(64, 32)
            .iter()
            .map(|&a| a as f64 * 64.0)
            .sum();
        assert!((s - 4.0 * std::f64::consts::PI).abs() < 1e-4);
    }

    #[test]
    fn seam_sampling_is_continuous() {
        let img = HdrImage::from_fn(8, 4, |x, _| [x as f32, 0.0, 0.0]);
        // Exactly on the seam: halfway between last and first column.
        let s = sample_px(&img, 0.0, 2.0);
        assert!((s[0] - 3.5).abs() < 1e-6);
    }

    #[test]
    fn pole_sampling_uses_opposite_longitude() {
        let img = HdrImage::from_fn(8, 4, |x, _| [x as f32, 0.0, 0.0]);
        // Above the top row centre at column 1: blends row 0 col 1 with row 0 col 5.
        let s = sample_px(&img, 1.5, 0.0);
        assert!((s[0] - 3.0).abs() < 1e-6, "{:?}", s);
    }

    #[test]
    fn rotate_then_inverse_is_identity_away_from_poles() {
        let img = HdrImage::from_fn(128, 64, |x, y| {
            let d = pixel_to_dir(x, y, 128, 64);
            [1.0 + d.x, 1.0 + d.y * d.z, 2.0 + d.z]
        });
        let r = ypr_to_mat(37.0, 12.0, -5.0);
        let back = rotate(&rotate(&img, r, 128, 64), r.transpose(), 128, 64);
        let mut worst = 0.0f32;
        for y in 8..56 {
            for x in 0..128 {
                let a = img.get(x, y);
                let b = back.get(x, y);
                for k in 0..3 {
                    worst = worst.max((a[k] - b[k]).abs());
                }
            }
        }
        assert!(worst < 0.02, "worst {worst}");
    }

    #[test]
    fn yaw_turns_to_the_right() {
        // Yaw +90: output centre (forward) shows what was on the right.
        let r = ypr_to_mat(90.0, 0.0, 0.0);
        let d = r * Vec3::new(0.0, 0.0, -1.0);
        assert!((d - Vec3::X).length() < 1e-6, "{d}");
    }

    #[test]
    fn orthonormalize_repairs_and_rejects() {
        let r = ypr_to_mat(20.0, 5.0, 3.0);
        let noisy = r * 1.02 + Mat3::from_diagonal(Vec3::splat(0.01));
        let fixed = orthonormalize(noisy).unwrap();
        assert!((fixed.determinant() - 1.0).abs() < 1e-4);
        assert!(orthonormalize(Mat3::ZERO).is_none());
        assert!(orthonormalize(Mat3::from_diagonal(Vec3::new(1.0, 1.0, -1.0))).is_none());
    }
}
