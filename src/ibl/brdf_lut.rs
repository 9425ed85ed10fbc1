//! The split-sum environment BRDF lookup table (Karis 2013, "Real Shading in
//! Unreal Engine 4").
//!
//! The specular image-based lighting integral is split into the prefiltered
//! environment ([`super::prefilter`]) times the directional albedo of the GGX
//! microfacet BRDF, which depends only on `N.V`, roughness and `F0`. With Schlick's
//! Fresnel `F = F0 + (1 - F0) (1 - V.H)^5` that albedo is `F0 A + B`, with
//!
//! `A = int f/F (1 - (1 - V.H)^5) (N.L) dL`, `B = int f/F (1 - V.H)^5 (N.L) dL`,
//!
//! estimated here by GGX importance sampling on a Hammersley set.
//!
//! **Geometry term:** the height-correlated Smith GGX visibility
//! `Vis = 0.5 / (N.L sqrt(N.V^2 (1 - a^2) + a^2) + N.V sqrt(N.L^2 (1 - a^2) + a^2))`
//! (Heitz 2014, "Understanding the masking-shadowing function"; the form of Lagarde
//! & de Rousiers 2014, "Moving Frostbite to PBR"), with `a = roughness^2`. It is
//! more accurate than Karis's separable Schlick-GGX with `k = a / 2`; direct-light
//! shading should use the same term for consistency.
//!
//! **Layout** (a `size x size` image): column `i` holds `N.V = (i + 0.5) / size`
//! (texel centres, from just above 0 to just below 1); row `j` holds roughness
//! `(j + 0.5) / size`, **row 0 (the top of the image) the smoothest**; channel R is
//! the scale `A`, G the bias `B`, B is 0.

use super::prefilter::{ggx_cos_theta, hammersley};
use crate::image::HdrImage;
use crate::sphere::cube::sample_face;
use rayon::prelude::*;

/// Default LUT size (texels per side).
pub const DEFAULT_LUT_SIZE: usize = 128;

/// Default number of GGX samples per LUT texel: with a Hammersley set the estimate
/// is converged to about 1e-3.
pub const DEFAULT_LUT_SAMPLES: usize = 512;

/// Height-correlated Smith GGX visibility `G / (4 N.L N.V)` for `alpha^2 = a2`
/// (Heitz 2014; Lagarde & de Rousiers 2014, eq. 3 of their notes).
#[inline]
fn smith_ggx_correlated_vis(n_dot_v: f64, n_dot_l: f64, a2: f64) -> f64 {
    let gv = n_dot_l * (n_dot_v * n_dot_v * (1.0 - a2) + a2).sqrt();
    let gl = n_dot_v * (n_dot_l * n_dot_l * (1.0 - a2) + a2).sqrt();
    0.5 / (gv + gl)
}

/// Split-sum scale and bias `[A, B]` for one `N.V` and roughness (Karis 2013,
/// `IntegrateBRDF`), from `samples` GGX-importance-sampled half vectors. With
/// `pdf(L) = D (N.H) / (4 V.H)` each sample contributes
/// `4 Vis (N.L) (V.H) / (N.H)` times `1 - Fc` to `A` and `Fc` to `B`,
/// `Fc = (1 - V.H)^5`. `N.V` is clamped to `[1e-4, 1]`, roughness to `[0, 1]`.
pub fn integrate_brdf(n_dot_v: f32, roughness: f32, samples: usize) -> [f32; 2] {
    let nv = if n_dot_v.is_finite() {
        (n_dot_v as f64).clamp(1e-4, 1.0)
    } else {
        1.0
    };
    let r = if roughness.is_finite() {
        (roughness as f64).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let a2 = r.powi(4);
    let v = [(1.0 - nv * nv).max(0.0).sqrt(), 0.0, nv];
    let n = samples.max(1);
    let (mut sa, mut sb) = (0.0f64, 0.0f64);
    for i in 0..n {
        let (u1, u2) = hammersley(i, n);
        let cos_h = ggx_cos_theta(u2 as f64, a2);
        let sin_h = (1.0 - cos_h * cos_h).max(0.0).sqrt();
        let (sp, cp) = (2.0 * std::f64::consts::PI * u1 as f64).sin_cos();
        let h = [sin_h * cp, sin_h * sp, cos_h];
        let v_dot_h = v[0] * h[0] + v[1] * h[1] + v[2] * h[2];
        // L = 2 (V.H) H - V; only its z (N.L) is needed.
        let n_dot_l = 2.0 * v_dot_h * h[2] - v[2];
        if n_dot_l <= 0.0 || v_dot_h <= 0.0 || cos_h <= 0.0 {
            continue;
        }
        let g_vis = 4.0 * smith_ggx_correlated_vis(nv, n_dot_l, a2) * n_dot_l * v_dot_h / cos_h;
        let fc = (1.0 - v_dot_h).powi(5);
        sa += (1.0 - fc) * g_vis;
        sb += fc * g_vis;
    }
    [(sa / n as f64) as f32, (sb / n as f64) as f32]
}

/// The split-sum BRDF lookup table (Karis 2013): `size x size`, x = `N.V`,
/// y = roughness with row 0 the smoothest, R = scale `A`, G = bias `B`, B = 0
/// (layout and geometry term in the module docs). A renderer computes specular
/// IBL as `prefiltered(R, roughness) * (F0 A + B)`. Rows are filled in parallel;
/// zero `size` or `samples` are treated as 1.
pub fn brdf_lut(size: usize, samples: usize) -> HdrImage {
    let n = size.max(1);
    let mut img = HdrImage::new(n, n);
    img.data_mut()
        .par_chunks_mut(3 * n)
        .enumerate()
        .for_each(|(j, row)| {
            let r = (j as f32 + 0.5) / n as f32;
            for i in 0..n {
                let nv = (i as f32 + 0.5) / n as f32;
                let [a, b] = integrate_brdf(nv, r, samples);
                row[3 * i..3 * i + 3].copy_from_slice(&[a, b, 0.0]);
            }
        });
    img
}

/// Bilinear lookup of `[A, B]` in a table made by [`brdf_lut`] (texel-centre
/// mapping, clamped at the borders; non-finite inputs read as 0). Any image size
/// works, the axes are scaled to it.
pub fn brdf_lookup(lut: &HdrImage, n_dot_v: f32, roughness: f32) -> [f32; 2] {
    if lut.width() == 0 || lut.height() == 0 {
        return [0.0; 2];
    }
    let fin = |v: f32| {
        if v.is_finite() {
            v.clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    let x = fin(n_dot_v) * lut.width() as f32 - 0.5;
    let y = fin(roughness) * lut.height() as f32 - 0.5;
    let c = sample_face(lut, x, y);
    [c[0], c[1]]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smooth_surfaces_reflect_everything() {
        for nv in [0.1f32, 0.5, 1.0] {
            let [a, b] = integrate_brdf(nv, 0.0, 64);
            assert!((a + b - 1.0).abs() < 1e-4, "{nv}: {a} {b}");
        }
        // Normal incidence: Fc = 0, so B = 0.
        assert!(integrate_brdf(1.0, 0.0, 16)[1].abs() < 1e-6);
    }

    #[test]
    fn rough_grazing_loses_energy_and_fresnel_rises() {
        let [a, b] = integrate_brdf(0.1, 1.0, 1024);
        assert!(a + b < 0.9 && a + b > 0.2, "{a} {b}");
        let [_, b_grazing] = integrate_brdf(0.05, 0.3, 512);
        let [_, b_normal] = integrate_brdf(0.95, 0.3, 512);
        assert!(b_grazing > 5.0 * b_normal);
    }

    #[test]
    fn lookup_hits_texel_centres() {
        let lut = brdf_lut(8, 64);
        let [a, b] = brdf_lookup(&lut, 2.5 / 8.0, 5.5 / 8.0);
        let px = lut.get(2, 5);
        assert!((a - px[0]).abs() < 1e-6 && (b - px[1]).abs() < 1e-6);
        assert_eq!(px[2], 0.0);
        let c = brdf_lookup(&lut, f32::NAN, 2.0);
        assert!(c[0].is_finite() && c[1].is_finite());
    }
}
