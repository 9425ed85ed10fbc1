//! Real spherical harmonics up to order 2 (bands `l = 0, 1, 2`, nine coefficients
//! per colour channel) and the diffuse irradiance they imply.
//!
//! Source: R. Ramamoorthi and P. Hanrahan, "An efficient representation for
//! irradiance environment maps", SIGGRAPH 2001. Irradiance `E(n)` is the
//! convolution of radiance with the clamped cosine `max(0, n.d)`; in SH that
//! convolution multiplies band `l` by `A_l` with `A_0 = pi`, `A_1 = 2 pi / 3`,
//! `A_2 = pi / 4` (and the paper shows bands `l <= 2` capture irradiance to a few
//! percent on average).
//!
//! Basis: the usual real, orthonormal SH in Cartesian form, written in the crate's
//! camera axes (x right, y up, z backward; see [`crate::sphere`]). Coefficient `k`
//! holds `(l, m)` with `k = l (l + 1) + m`:
//!
//! | k | (l, m) | `Y_k(x, y, z)` |
//! |---|--------|----------------|
//! | 0 | (0, 0) | `0.282095` |
//! | 1 | (1,-1) | `0.488603 y` |
//! | 2 | (1, 0) | `0.488603 z` |
//! | 3 | (1, 1) | `0.488603 x` |
//! | 4 | (2,-2) | `1.092548 x y` |
//! | 5 | (2,-1) | `1.092548 y z` |
//! | 6 | (2, 0) | `0.315392 (3 z^2 - 1)` |
//! | 7 | (2, 1) | `1.092548 x z` |
//! | 8 | (2, 2) | `0.546274 (x^2 - y^2)` |
//!
//! Which axis plays the paper's polar `z` does not matter: irradiance, rotation and
//! the evaluation metrics are all independent of that choice.

use crate::image::{luminance, HdrImage};
use glam::{Mat3, Vec3};
use rayon::prelude::*;
use std::f64::consts::PI;

/// Number of coefficients per channel for bands `l <= 2`.
pub const SH_COUNT: usize = 9;

/// `1 / (2 sqrt(pi))`.
const K00: f64 = 0.282_094_791_773_878_14;
/// `sqrt(3 / (4 pi))`.
const K1: f64 = 0.488_602_511_902_919_9;
/// `sqrt(15 / (4 pi))`.
const K2: f64 = 1.092_548_430_592_079_2;
/// `sqrt(5 / (16 pi))`.
const K20: f64 = 0.315_391_565_252_520_05;
/// `sqrt(15 / (16 pi))`.
const K22: f64 = 0.546_274_215_296_039_6;

/// Band `l` of each coefficient index.
pub const BAND_OF: [usize; SH_COUNT] = [0, 1, 1, 1, 2, 2, 2, 2, 2];

/// Clamped-cosine convolution factors `A_l` for bands 0, 1, 2 (Ramamoorthi &
/// Hanrahan 2001, eq. 8): irradiance is radiance with band `l` scaled by `A_l`.
pub const COSINE_LOBE: [f32; 3] = [
    std::f32::consts::PI,
    2.0 * std::f32::consts::PI / 3.0,
    std::f32::consts::PI / 4.0,
];

const COSINE_LOBE_F64: [f64; 3] = [PI, 2.0 * PI / 3.0, PI / 4.0];

/// The nine basis functions at a unit direction `(x, y, z)`, in `f64`.
#[inline]
pub(crate) fn basis_f64(x: f64, y: f64, z: f64) -> [f64; SH_COUNT] {
    [
        K00,
        K1 * y,
        K1 * z,
        K1 * x,
        K2 * x * y,
        K2 * y * z,
        K20 * (3.0 * z * z - 1.0),
        K2 * x * z,
        K22 * (x * x - y * y),
    ]
}

/// The nine real SH basis functions `Y_k(d)` (table in the module docs). `d` is
/// normalised first; a zero or non-finite `d` gives only the constant term.
pub fn sh_basis(d: Vec3) -> [f32; SH_COUNT] {
    let (x, y, z) = unit_f64(d);
    basis_f64(x, y, z).map(|v| v as f32)
}

/// `d` normalised in `f64`; the zero vector maps to the origin (only `Y_00` survives).
#[inline]
fn unit_f64(d: Vec3) -> (f64, f64, f64) {
    let (x, y, z) = (d.x as f64, d.y as f64, d.z as f64);
    let r = (x * x + y * y + z * z).sqrt();
    if r > 0.0 && r.is_finite() {
        (x / r, y / r, z / r)
    } else {
        (0.0, 0.0, 0.0)
    }
}

/// Ringing-suppression window applied per band (Sloan, "Stupid spherical harmonics
/// tricks", 2008). Truncating to order 2 makes a bright sun ring into negative
/// lobes; damping the higher bands trades that for blur. Off by default, and off in
/// the evaluation metrics.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum ShWindow {
    /// No windowing: every band kept as projected.
    #[default]
    None,
    /// Hanning window of width `w`: band `l` scaled by `(1 + cos(pi l / w)) / 2`
    /// for `l < w`, else 0. `w = 3` gives factors `1, 0.75, 0.25`.
    Hanning(f32),
    /// Lanczos (sinc) window of width `w`: band `l` scaled by
    /// `sin(pi l / w) / (pi l / w)` for `l < w` (1 at `l = 0`), else 0.
    Lanczos(f32),
}

impl ShWindow {
    /// The per-band factors for bands 0, 1, 2.
    pub fn factors(&self) -> [f32; 3] {
        let mut f = [1.0f32; 3];
        for (l, v) in f.iter_mut().enumerate() {
            let l = l as f64;
            *v = match *self {
                ShWindow::None => 1.0,
                ShWindow::Hanning(w) => {
                    let w = w as f64;
                    if w > 0.0 && l < w {
                        (0.5 * (1.0 + (PI * l / w).cos())) as f32
                    } else {
                        0.0
                    }
                }
                ShWindow::Lanczos(w) => {
                    let w = w as f64;
                    if l == 0.0 {
                        1.0
                    } else if w > 0.0 && l < w {
                        let a = PI * l / w;
                        (a.sin() / a) as f32
                    } else {
                        0.0
                    }
                }
            };
        }
        f
    }
}

/// Order-2 spherical-harmonic coefficients of an RGB function on the sphere
/// (radiance, usually): `coeffs[k][c]` is `int L_c(d) Y_k(d) dOmega`.
///
/// Nine RGB triples are enough to reproduce diffuse irradiance to a few percent
/// (Ramamoorthi & Hanrahan 2001), which is what the evaluation compares and what a
/// renderer needs for diffuse image-based lighting.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sh9 {
    /// Coefficient `k` (see the module table), one value per RGB channel.
    pub coeffs: [[f32; 3]; SH_COUNT],
}

/// Projection of an equirect panorama in `f64`: `sum_px L(d) Y_k(d) dOmega`.
///
/// Rows are summed in parallel and the per-row sums added in row order, so the
/// result does not depend on the number of threads. Pixels with a non-finite
/// sample contribute nothing.
pub(crate) fn project_f64(img: &HdrImage) -> [[f64; 3]; SH_COUNT] {
    let (w, h) = (img.width(), img.height());
    let mut total = [[0.0f64; 3]; SH_COUNT];
    if w == 0 || h == 0 {
        return total;
    }
    let cols = column_sin_cos(w);
    let rows: Vec<[[f64; 3]; SH_COUNT]> = img
        .data()
        .par_chunks_exact(3 * w)
        .enumerate()
        .map(|(row, line)| {
            let (st, ct) = row_sin_cos(row, h);
            let mut acc = [[0.0f64; 3]; SH_COUNT];
            for (px, &(sp, cp)) in line.chunks_exact(3).zip(&cols) {
                let rgb = [px[0] as f64, px[1] as f64, px[2] as f64];
                if !(rgb[0].is_finite() && rgb[1].is_finite() && rgb[2].is_finite()) {
                    continue;
                }
                let y = basis_f64(ct * sp, st, -ct * cp);
                for (a, yk) in acc.iter_mut().zip(y) {
                    a[0] += rgb[0] * yk;
                    a[1] += rgb[1] * yk;
                    a[2] += rgb[2] * yk;
                }
            }
            let d_omega = crate::sphere::pixel_solid_angle(row, w, h) as f64;
            for a in &mut acc {
                for v in a.iter_mut() {
                    *v *= d_omega;
                }
            }
            acc
        })
        .collect();
    for r in &rows {
        for (t, a) in total.iter_mut().zip(r) {
            for c in 0..3 {
                t[c] += a[c];
            }
        }
    }
    total
}

/// `(sin phi, cos phi)` of each column centre, same convention as
/// [`crate::sphere::pixel_to_dir`] but in `f64`.
pub(crate) fn column_sin_cos(w: usize) -> Vec<(f64, f64)> {
    (0..w)
        .map(|c| {
            let u = (c as f64 + 0.5) / w as f64;
            ((u - 0.5) * 2.0 * PI).sin_cos()
        })
        .collect()
}

/// `(sin theta, cos theta)` of a row centre, same convention as
/// [`crate::sphere::pixel_to_dir`] but in `f64`.
#[inline]
pub(crate) fn row_sin_cos(row: usize, h: usize) -> (f64, f64) {
    let v = (row as f64 + 0.5) / h as f64;
    ((0.5 - v) * PI).sin_cos()
}

/// Luminance (Rec. 709 weights, as [`crate::image::luminance`]) of each RGB
/// coefficient, in `f64`; valid because luminance is linear.
pub(crate) fn luminance_f64(c: &[[f64; 3]; SH_COUNT]) -> [f64; SH_COUNT] {
    c.map(|v| 0.2126 * v[0] + 0.7152 * v[1] + 0.0722 * v[2])
}

/// Irradiance `E(n) = sum_k A_l(k) c_k Y_k(n)` of scalar coefficients, `n` unit.
pub(crate) fn irradiance_scalar_f64(c: &[f64; SH_COUNT], n: [f64; 3]) -> f64 {
    let y = basis_f64(n[0], n[1], n[2]);
    (0..SH_COUNT)
        .map(|k| COSINE_LOBE_F64[BAND_OF[k]] * c[k] * y[k])
        .sum()
}

/// Unit direction of the first moment `m = int L(d) d dOmega` of a scalar function,
/// read off its band-1 coefficients (`c_1m = sqrt(3 / 4 pi) m_axis`). `None` when
/// `|m|` is below `1e-5` of the total `int |L| dOmega` bound implied by band 0 (a
/// constant or perfectly balanced environment has no dominant direction).
pub(crate) fn dominant_dir_f64(c: &[f64; SH_COUNT]) -> Option<[f64; 3]> {
    let m = [c[3] / K1, c[1] / K1, c[2] / K1];
    let len = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
    let flux = (c[0] / K00).abs();
    if !len.is_finite() || len == 0.0 || len < 1e-5 * flux {
        return None;
    }
    Some([m[0] / len, m[1] / len, m[2] / len])
}

/// Degree-5 Lebedev quadrature on the unit sphere (14 points): the 6 octahedron
/// vertices with weight `1/15` and the 8 cube corners with weight `3/40`, times
/// `4 pi`. It integrates every polynomial of degree <= 5 exactly, so products of
/// two order-2 harmonics (degree 4) are integrated exactly.
fn lebedev14() -> [([f64; 3], f64); 14] {
    let a = 4.0 * PI / 15.0;
    let b = 4.0 * PI * 3.0 / 40.0;
    let s = 1.0 / 3f64.sqrt();
    let mut out = [([0.0; 3], 0.0); 14];
    let mut i = 0;
    for axis in 0..3 {
        for sign in [1.0, -1.0] {
            let mut d = [0.0; 3];
            d[axis] = sign;
            out[i] = (d, a);
            i += 1;
        }
    }
    for sx in [s, -s] {
        for sy in [s, -s] {
            for sz in [s, -s] {
                out[i] = ([sx, sy, sz], b);
                i += 1;
            }
        }
    }
    out
}

impl Sh9 {
    /// All-zero coefficients (a black environment).
    pub fn zero() -> Self {
        Sh9::default()
    }

    /// Projects an equirect panorama onto the basis: `c_k = sum_px L Y_k(d) dOmega`
    /// with the exact per-pixel solid angle, accumulated in `f64`. Deterministic
    /// for any number of threads (per-row sums added in row order). Pixels with a
    /// non-finite sample are skipped; sanitise the image first if they should count.
    pub fn project(img: &HdrImage) -> Self {
        let c = project_f64(img);
        Sh9 {
            coeffs: c.map(|v| v.map(|x| x as f32)),
        }
    }

    /// Radiance reconstructed from the coefficients in direction `d` (normalised
    /// first). May be negative near a strong light (ringing).
    pub fn eval(&self, d: Vec3) -> [f32; 3] {
        self.weighted_sum(d, [1.0; 3])
    }

    /// Diffuse irradiance `E(n) = int L(d) max(0, n.d) dOmega` for surface normal
    /// `n` (normalised first), via the clamped-cosine band factors `A_l` of
    /// Ramamoorthi & Hanrahan 2001. A Lambertian surface of albedo `rho` reflects
    /// radiance `rho E / pi`. May dip below zero for very peaky environments; see
    /// [`Sh9::irradiance_clamped`].
    pub fn irradiance(&self, n: Vec3) -> [f32; 3] {
        self.weighted_sum(n, COSINE_LOBE.map(|a| a as f64))
    }

    /// [`Sh9::irradiance`] clamped at zero per channel, for shading.
    pub fn irradiance_clamped(&self, n: Vec3) -> [f32; 3] {
        self.irradiance(n).map(|v| v.max(0.0))
    }

    /// `sum_k f_l(k) c_k Y_k(d)` in `f64`.
    fn weighted_sum(&self, d: Vec3, band_factor: [f64; 3]) -> [f32; 3] {
        let (x, y, z) = unit_f64(d);
        let yb = basis_f64(x, y, z);
        let mut out = [0.0f64; 3];
        for k in 0..SH_COUNT {
            let f = band_factor[BAND_OF[k]] * yb[k];
            for (o, c) in out.iter_mut().zip(self.coeffs[k]) {
                *o += f * c as f64;
            }
        }
        out.map(|v| v as f32)
    }

    /// Coefficients with band `l` scaled by the window's factor `f_l`
    /// ([`ShWindow::None`] returns an identical copy).
    pub fn windowed(&self, window: ShWindow) -> Self {
        let f = window.factors();
        let mut out = *self;
        for (k, c) in out.coeffs.iter_mut().enumerate() {
            for v in c.iter_mut() {
                *v *= f[BAND_OF[k]];
            }
        }
        out
    }

    /// Luminance (Rec. 709 weights) of each coefficient: the SH of the luminance of
    /// the environment, since luminance is linear in RGB.
    pub fn luminance(&self) -> [f32; SH_COUNT] {
        self.coeffs.map(luminance)
    }

    /// Sum of squared coefficients of band `l` over the three channels (0 for
    /// `l > 2`); rotation leaves it unchanged.
    pub fn band_energy(&self, l: usize) -> f32 {
        (0..SH_COUNT)
            .filter(|&k| BAND_OF[k] == l)
            .map(|k| self.coeffs[k].iter().map(|v| v * v).sum::<f32>())
            .sum()
    }

    /// Coefficients of the rotated environment `g(d) = f(r d)`: the same convention
    /// as [`crate::sphere::rotate`], so `Sh9::project(&rotate(img, r, ..))` matches
    /// `Sh9::project(img).rotate(r)`. `r` should be a rotation.
    ///
    /// Each band is mapped by the `(2l+1) x (2l+1)` matrix
    /// `M_kj = int Y_k(d) Y_j(r d) dOmega`, computed with a 14-point Lebedev rule
    /// that is exact for these degree-4 integrands, so the result is exact up to
    /// rounding.
    pub fn rotate(&self, r: Mat3) -> Self {
        let m = r.to_cols_array_2d();
        // glam is column-major: m[col][row].
        let apply = |d: [f64; 3]| -> [f64; 3] {
            let mut o = [0.0; 3];
            for (row, v) in o.iter_mut().enumerate() {
                *v = (0..3).map(|col| m[col][row] as f64 * d[col]).sum();
            }
            o
        };
        let mut mat = [[0.0f64; SH_COUNT]; SH_COUNT];
        for (d, wgt) in lebedev14() {
            let yd = basis_f64(d[0], d[1], d[2]);
            let rd = apply(d);
            let len = (rd[0] * rd[0] + rd[1] * rd[1] + rd[2] * rd[2]).sqrt();
            let yr = basis_f64(rd[0] / len, rd[1] / len, rd[2] / len);
            for k in 0..SH_COUNT {
                for j in 0..SH_COUNT {
                    if BAND_OF[k] == BAND_OF[j] {
                        mat[k][j] += wgt * yd[k] * yr[j];
                    }
                }
            }
        }
        let mut out = Sh9::zero();
        for (row, dst) in mat.iter().zip(out.coeffs.iter_mut()) {
            for (c, v) in dst.iter_mut().enumerate() {
                let s: f64 = row
                    .iter()
                    .zip(&self.coeffs)
                    .map(|(m, src)| m * src[c] as f64)
                    .sum();
                *v = s as f32;
            }
        }
        out
    }

    /// Dominant light direction: the normalised first moment of luminance,
    /// `int L(d) d dOmega`, which is the band-1 luminance vector
    /// `(c_3, c_1, c_2) / sqrt(3 / 4 pi)` in (x, y, z). `None` when that moment is
    /// negligible (below `1e-5` of the total flux), e.g. a constant environment.
    pub fn dominant_direction(&self) -> Option<Vec3> {
        let c = self.coeffs.map(|v| v.map(|x| x as f64));
        dominant_dir_f64(&luminance_f64(&c))
            .map(|d| Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ibl::fibonacci_directions;
    use crate::sphere::{pixel_solid_angle, pixel_to_dir, ypr_to_mat};

    /// Small deterministic generator for test inputs (xorshift64*).
    struct Rng(u64);
    impl Rng {
        fn next_f64(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
        }
        fn dir(&mut self) -> Vec3 {
            loop {
                let v = Vec3::new(
                    self.next_f64() as f32 * 2.0 - 1.0,
                    self.next_f64() as f32 * 2.0 - 1.0,
                    self.next_f64() as f32 * 2.0 - 1.0,
                );
                let l = v.length();
                if l > 0.1 && l <= 1.0 {
                    return v / l;
                }
            }
        }
    }

    #[test]
    fn constants_match_closed_forms() {
        assert!((K00 - 0.5 / PI.sqrt()).abs() < 1e-15);
        assert!((K1 - (3.0 / (4.0 * PI)).sqrt()).abs() < 1e-15);
        assert!((K2 - (15.0 / (4.0 * PI)).sqrt()).abs() < 1e-15);
        assert!((K20 - (5.0 / (16.0 * PI)).sqrt()).abs() < 1e-15);
        assert!((K22 - (15.0 / (16.0 * PI)).sqrt()).abs() < 1e-15);
    }

    #[test]
    fn basis_is_orthonormal_under_lebedev_rule() {
        let q = lebedev14();
        for k in 0..SH_COUNT {
            for j in 0..SH_COUNT {
                let s: f64 = q
                    .iter()
                    .map(|(d, w)| {
                        let y = basis_f64(d[0], d[1], d[2]);
                        w * y[k] * y[j]
                    })
                    .sum();
                let want = if k == j { 1.0 } else { 0.0 };
                assert!((s - want).abs() < 1e-12, "<Y{k},Y{j}> = {s}");
            }
        }
    }

    #[test]
    fn direction_tables_match_pixel_to_dir() {
        let (w, h) = (37, 19);
        let cols = column_sin_cos(w);
        for row in 0..h {
            let (st, ct) = row_sin_cos(row, h);
            for (col, &(sp, cp)) in cols.iter().enumerate() {
                let d = pixel_to_dir(col, row, w, h);
                let e = Vec3::new((ct * sp) as f32, st as f32, (-ct * cp) as f32);
                assert!((d - e).length() < 1e-5);
            }
        }
    }

    #[test]
    fn constant_environment_gives_pi_l_everywhere() {
        let img = HdrImage::from_fn(128, 64, |_, _| [1.0, 2.0, 3.0]);
        let sh = Sh9::project(&img);
        for n in fibonacci_directions(64) {
            let e = sh.irradiance(n);
            for c in 0..3 {
                let want = std::f32::consts::PI * (c + 1) as f32;
                assert!((e[c] - want).abs() < 2e-3 * want, "{n}: {:?}", e);
            }
            let l = sh.eval(n);
            assert!((l[1] - 2.0).abs() < 4e-3, "{:?}", l);
        }
        assert!(sh.dominant_direction().is_none());
    }

    #[test]
    fn linear_environment_lives_only_in_band_one() {
        let (w, h) = (256, 128);
        let img = HdrImage::from_fn(w, h, |x, y| {
            let z = pixel_to_dir(x, y, w, h).z;
            [z, 2.0 * z, -z]
        });
        let sh = Sh9::project(&img);
        // int z^2 dOmega = 4 pi / 3, so c_2 = sqrt(3 / 4 pi) 4 pi / 3.
        let want = (K1 * 4.0 * PI / 3.0) as f32;
        assert!((sh.coeffs[2][0] - want).abs() < 1e-3 * want);
        assert!((sh.coeffs[2][1] - 2.0 * want).abs() < 2e-3 * want);
        let b1 = sh.band_energy(1);
        assert!(sh.band_energy(0) < 1e-8 * b1, "{}", sh.band_energy(0));
        assert!(sh.band_energy(2) < 1e-6 * b1, "{}", sh.band_energy(2));
        // Irradiance of L = z is (2 pi / 3) n.z.
        let e = sh.irradiance(Vec3::Z);
        assert!((e[0] - 2.0 * std::f32::consts::PI / 3.0).abs() < 2e-3);
    }

    #[test]
    fn small_patch_irradiance_is_close_to_brute_force() {
        let (w, h) = (128, 64);
        let mut img = HdrImage::new(w, h);
        for y in 20..23 {
            for x in 80..83 {
                img.set(x, y, [50.0, 40.0, 30.0]);
            }
        }
        let sh = Sh9::project(&img);
        let flux: f64 = (20..23)
            .map(|y| 3.0 * 40.0 * pixel_solid_angle(y, w, h) as f64)
            .sum();
        let mut worst = 0.0f64;
        let mut mean = 0.0f64;
        let normals = fibonacci_directions(256);
        for &n in &normals {
            let mut brute = 0.0f64;
            for y in 0..h {
                let da = pixel_solid_angle(y, w, h) as f64;
                for x in 0..w {
                    let l = img.get(x, y)[1] as f64;
                    if l > 0.0 {
                        let d = pixel_to_dir(x, y, w, h);
                        brute += l * (n.dot(d).max(0.0) as f64) * da;
                    }
                }
            }
            let e = sh.irradiance(n)[1] as f64;
            worst = worst.max((e - brute).abs());
            mean += (e - brute).abs();
        }
        mean /= normals.len() as f64;
        // Order-2 SH of a point light errs by at most 3/32 of its flux (at the
        // terminator), 1/16 at the light and behind it.
        assert!(worst < 0.1 * flux, "worst {worst} flux {flux}");
        assert!(mean < 0.05 * flux, "mean {mean} flux {flux}");
    }

    #[test]
    fn rotation_matches_pointwise_evaluation() {
        let mut rng = Rng(42);
        let mut sh = Sh9::zero();
        for k in 0..SH_COUNT {
            for c in 0..3 {
                sh.coeffs[k][c] = rng.next_f64() as f32 * 2.0 - 1.0;
            }
        }
        let r = ypr_to_mat(33.0, -21.0, 70.0);
        let rot = sh.rotate(r);
        for _ in 0..50 {
            let d = rng.dir();
            let a = rot.eval(d);
            let b = sh.eval(r * d);
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() < 1e-4, "{a:?} vs {b:?}");
            }
        }
        for l in 0..3 {
            assert!((rot.band_energy(l) - sh.band_energy(l)).abs() < 1e-4);
        }
        let same = sh.rotate(Mat3::IDENTITY);
        for k in 0..SH_COUNT {
            for c in 0..3 {
                assert!((same.coeffs[k][c] - sh.coeffs[k][c]).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn rotation_is_equivariant_with_panorama_rotation() {
        let (w, h) = (256, 128);
        let img = HdrImage::from_fn(w, h, |x, y| {
            let d = pixel_to_dir(x, y, w, h);
            [
                2.0 + d.x + 0.5 * d.y * d.z,
                1.0 + 0.7 * d.y - 0.3 * d.x * d.x,
                1.5 + 0.4 * d.z + 0.2 * d.x * d.y,
            ]
        });
        let r = ypr_to_mat(50.0, 25.0, -10.0);
        let a = Sh9::project(&crate::sphere::rotate(&img, r, w, h));
        let b = Sh9::project(&img).rotate(r);
        for k in 0..SH_COUNT {
            for c in 0..3 {
                let (x, y) = (a.coeffs[k][c], b.coeffs[k][c]);
                assert!((x - y).abs() < 5e-3, "k{k} c{c}: {x} vs {y}");
            }
        }
    }

    #[test]
    fn dominant_direction_of_a_spot() {
        let (w, h) = (256, 128);
        let mut img = HdrImage::new(w, h);
        img.set(40, 30, [100.0, 100.0, 100.0]);
        let want = pixel_to_dir(40, 30, w, h);
        let got = Sh9::project(&img).dominant_direction().unwrap();
        assert!(got.angle_between(want).to_degrees() < 0.1);
    }

    #[test]
    fn windows_damp_higher_bands() {
        assert_eq!(ShWindow::None.factors(), [1.0, 1.0, 1.0]);
        let h = ShWindow::Hanning(3.0).factors();
        assert!((h[0] - 1.0).abs() < 1e-6 && (h[1] - 0.75).abs() < 1e-6);
        assert!((h[2] - 0.25).abs() < 1e-6);
        let l = ShWindow::Lanczos(3.0).factors();
        assert!(l[0] == 1.0 && l[1] > l[2] && l[2] > 0.0 && l[1] < 1.0);
        let mut sh = Sh9::zero();
        sh.coeffs = [[1.0; 3]; SH_COUNT];
        assert_eq!(sh.windowed(ShWindow::None), sh);
        let wd = sh.windowed(ShWindow::Hanning(3.0));
        assert!((wd.coeffs[8][0] - 0.25).abs() < 1e-6);
        assert_eq!(wd.coeffs[0][0], 1.0);
        // A clamped irradiance is never negative.
        let mut peaky = Sh9::zero();
        peaky.coeffs[0] = [0.1; 3];
        peaky.coeffs[2] = [1.0; 3];
        assert!(peaky.irradiance(-Vec3::Z)[0] < 0.0);
        assert_eq!(peaky.irradiance_clamped(-Vec3::Z)[0], 0.0);
    }

    #[test]
    fn projection_is_deterministic_and_skips_non_finite() {
        let mut img = HdrImage::from_fn(64, 32, |x, y| [x as f32 * 0.1, y as f32, 1.0]);
        let a = Sh9::project(&img);
        let b = Sh9::project(&img);
        assert_eq!(a, b);
        img.set(3, 3, [f32::NAN, f32::INFINITY, 1.0]);
        let c = Sh9::project(&img);
        assert!(c.coeffs.iter().flatten().all(|v| v.is_finite()));
    }
}
