//! The glTF 2.0 metallic-roughness BRDF (glTF 2.0 specification, Appendix B) and
//! the split-sum environment BRDF table of Karis 2013 ("Real Shading in Unreal
//! Engine 4", SIGGRAPH course notes).
//!
//! Conventions: `roughness` is the glTF perceptual roughness; the GGX width is
//! `alpha = roughness^2`. The visibility term is the height-correlated Smith form
//! `V = 0.5 / (NL sqrt(NV^2 (1 - a^2) + a^2) + NV sqrt(NL^2 (1 - a^2) + a^2))`
//! (Heitz 2014), as used by the Khronos glTF sample viewer; Appendix B spells out
//! the separable Smith variant, which differs by a few percent at grazing angles.
//! The same `V` is used for direct lights and for the split-sum table, so the two
//! paths agree.

use glam::Vec3;
use std::f32::consts::PI;
use std::sync::OnceLock;

/// Fresnel reflectance at normal incidence of a glTF dielectric (IOR 1.5):
/// `((1.5 - 1) / (1.5 + 1))^2 = 0.04` (Appendix B).
pub const DIELECTRIC_F0: f32 = 0.04;

/// GGX / Trowbridge-Reitz normal distribution `D = a^2 / (pi ((n.h)^2 (a^2 - 1) + 1)^2)`
/// with `a = alpha = roughness^2` (Appendix B, "Specular BRDF").
#[inline]
pub fn ggx_d(n_dot_h: f32, alpha: f32) -> f32 {
    let a2 = alpha * alpha;
    let nh = n_dot_h.max(0.0);
    let d = nh * nh * (a2 - 1.0) + 1.0;
    a2 / (PI * d * d).max(1e-30)
}

/// Height-correlated Smith visibility `V = G / (4 |n.l| |n.v|)` for GGX width
/// `alpha` (see the module notes for why this and not the separable form).
#[inline]
pub fn smith_v(n_dot_v: f32, n_dot_l: f32, alpha: f32) -> f32 {
    let a2 = alpha * alpha;
    let nv = n_dot_v.max(0.0);
    let nl = n_dot_l.max(0.0);
    let gv = nl * (nv * nv * (1.0 - a2) + a2).sqrt();
    let gl = nv * (nl * nl * (1.0 - a2) + a2).sqrt();
    let s = gv + gl;
    if s > 0.0 {
        0.5 / s
    } else {
        0.0
    }
}

/// Schlick's Fresnel weight `(1 - |v.h|)^5`, so that `F = f0 + (1 - f0) * w`.
#[inline]
pub fn schlick_weight(v_dot_h: f32) -> f32 {
    let m = (1.0 - v_dot_h.abs()).clamp(0.0, 1.0);
    let m2 = m * m;
    m2 * m2 * m
}

/// The surface parameters the BRDF needs at one point (after texturing).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceParams {
    /// Linear base colour (glTF `baseColor`).
    pub base_color: [f32; 3],
    /// Metalness in `[0, 1]`.
    pub metallic: f32,
    /// Perceptual roughness in `[0, 1]`.
    pub roughness: f32,
    /// Dielectric specular weight in `[0, 1]` (KHR_materials_specular
    /// `specularFactor`, 1 without the extension): scales the dielectric Fresnel
    /// term, so 0 turns a dielectric into a pure Lambertian surface.
    pub specular: f32,
}

/// Smallest roughness used for analytic (delta-direction) lights: below it the
/// GGX lobe is narrower than float precision can represent usefully.
pub const MIN_DIRECT_ROUGHNESS: f32 = 0.03;

/// The full glTF metallic-roughness BRDF `f(v, l)` times `n.l` (Appendix B):
/// `mix(dielectric, metal, metallic)` with
/// `dielectric = (1 - s F_d) c / pi + s F_d D V`, `F_d = schlick(f0 = 0.04)`,
/// `metal = F_m D V`, `F_m = schlick(f0 = baseColor)`, `s` the specular weight.
/// `n`, `v`, `l` are unit vectors (v and l pointing away from the surface).
/// Returns the reflected radiance per unit irradiance at normal incidence.
pub fn eval_brdf_cos(p: &SurfaceParams, n: Vec3, v: Vec3, l: Vec3) -> [f32; 3] {
    let nl = n.dot(l);
    if nl <= 0.0 {
        return [0.0; 3];
    }
    let nv = n.dot(v).max(1e-4);
    let h = (v + l).normalize_or_zero();
    if h == Vec3::ZERO {
        return [0.0; 3];
    }
    let nh = n.dot(h);
    let vh = v.dot(h);
    let rough = p.roughness.clamp(MIN_DIRECT_ROUGHNESS, 1.0);
    let alpha = rough * rough;
    let dv = ggx_d(nh, alpha) * smith_v(nv, nl, alpha);
    let w = schlick_weight(vh);
    let s = p.specular.clamp(0.0, 1.0);
    let f_d = s * (DIELECTRIC_F0 + (1.0 - DIELECTRIC_F0) * w);
    let m = p.metallic.clamp(0.0, 1.0);
    let mut out = [0.0; 3];
    for (k, o) in out.iter_mut().enumerate() {
        let c = p.base_color[k];
        let dielectric = (1.0 - f_d) * c / PI + f_d * dv;
        let f_m = c + (1.0 - c) * w;
        let metal = f_m * dv;
        *o = ((1.0 - m) * dielectric + m * metal) * nl;
    }
    out
}

/// Split-sum directional-albedo table `(A, B)` of Karis 2013: for a GGX lobe of
/// the given roughness seen at `n.v`, the hemispherical integral of
/// `f(v, l) n.l` with Schlick Fresnel is `f0 * A + B` (for `f0` in `[0, 1]`).
///
/// Grid node `(i, j)` holds `n.v = i / (size - 1)` (at least 1e-3) and
/// `roughness = j / (size - 1)`, integrated with `samples` GGX importance samples
/// on a Hammersley set; lookups interpolate bilinearly between nodes.
#[derive(Clone, Debug)]
pub struct SplitSumLut {
    size: usize,
    data: Vec<[f32; 2]>,
}

/// Radical inverse in base 2 (van der Corput), for the Hammersley point set.
#[inline]
fn radical_inverse(i: u32) -> f32 {
    (i.reverse_bits() as f64 / 4_294_967_296.0) as f32
}

impl SplitSumLut {
    /// Computes the table on a `size x size` grid with `samples` samples per node
    /// (`size` at least 2, `samples` at least 1). `new(64, 256)` takes a few ms.
    pub fn new(size: usize, samples: usize) -> Self {
        let size = size.max(2);
        let samples = samples.max(1);
        let mut data = vec![[0.0f32; 2]; size * size];
        let den = (size - 1) as f32;
        for j in 0..size {
            let rough = j as f32 / den;
            for i in 0..size {
                let nv = (i as f32 / den).max(1e-3);
                data[j * size + i] = integrate_split_sum(nv, rough, samples);
            }
        }
        SplitSumLut { size, data }
    }

    /// A process-wide `64 x 64` table with 512 samples per node, computed once on
    /// first use, for environments that do not want to carry their own.
    pub fn shared() -> &'static SplitSumLut {
        static LUT: OnceLock<SplitSumLut> = OnceLock::new();
        LUT.get_or_init(|| SplitSumLut::new(64, 512))
    }

    /// Grid size per axis.
    pub fn size(&self) -> usize {
        self.size
    }

    /// `(A, B)` at `n.v` and roughness (both clamped to `[0, 1]`), bilinear.
    pub fn lookup(&self, n_dot_v: f32, roughness: f32) -> [f32; 2] {
        let den = (self.size - 1) as f32;
        let fx = if n_dot_v.is_finite() {
            n_dot_v.clamp(0.0, 1.0) * den
        } else {
            0.0
        };
        let fy = if roughness.is_finite() {
            roughness.clamp(0.0, 1.0) * den
        } else {
            den
        };
        let x0 = (fx.floor() as usize).min(self.size - 2);
        let y0 = (fy.floor() as usize).min(self.size - 2);
        let tx = fx - x0 as f32;
        let ty = fy - y0 as f32;
        let at = |x: usize, y: usize| self.data[y * self.size + x];
        let (a, b, c, d) = (
            at(x0, y0),
            at(x0 + 1, y0),
            at(x0, y0 + 1),
            at(x0 + 1, y0 + 1),
        );
        let mut out = [0.0; 2];
        for (k, o) in out.iter_mut().enumerate() {
            let top = a[k] + (b[k] - a[k]) * tx;
            let bot = c[k] + (d[k] - c[k]) * tx;
            *o = top + (bot - top) * ty;
        }
        out
    }
}

/// One node of the split-sum table: importance-samples `h` from GGX
/// (`cos th = sqrt((1 - u) / (1 + (a^2 - 1) u))`), reflects `v` about it and
/// accumulates `G_vis = V 4 (n.l)(v.h) / (n.h)` weighted by `1 - Fc` (into A) and
/// `Fc = (1 - v.h)^5` (into B) — Karis 2013, "Environment BRDF".
fn integrate_split_sum(nv: f32, roughness: f32, samples: usize) -> [f32; 2] {
    let alpha = roughness * roughness;
    let a2 = alpha * alpha;
    let v = Vec3::new((1.0 - nv * nv).max(0.0).sqrt(), 0.0, nv);
    let (mut sa, mut sb) = (0.0f64, 0.0f64);
    for i in 0..samples {
        let u1 = (i as f32 + 0.5) / samples as f32;
        let u2 = radical_inverse(i as u32);
        let phi = 2.0 * PI * u1;
        let cos_t = ((1.0 - u2) / (1.0 + (a2 - 1.0) * u2)).max(0.0).sqrt();
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let h = Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t);
        let vh = v.dot(h);
        let l = 2.0 * vh * h - v;
        let nl = l.z;
        let nh = h.z;
        if nl > 0.0 && nh > 0.0 && vh > 0.0 {
            let g_vis = smith_v(nv, nl, alpha) * 4.0 * nl * vh / nh;
            let fc = schlick_weight(vh);
            sa += ((1.0 - fc) * g_vis) as f64;
            sb += (fc * g_vis) as f64;
        }
    }
    [(sa / samples as f64) as f32, (sb / samples as f64) as f32]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lut_is_one_for_a_mirror_and_bounded() {
        let lut = SplitSumLut::new(32, 256);
        for i in 0..=10 {
            let nv = i as f32 / 10.0;
            let [a, b] = lut.lookup(nv.max(0.05), 0.0);
            assert!((a + b - 1.0).abs() < 0.02, "nv {nv}: {a} {b}");
        }
        for j in 0..=10 {
            for i in 0..=10 {
                let [a, b] = lut.lookup(i as f32 / 10.0, j as f32 / 10.0);
                assert!(a >= 0.0 && b >= 0.0 && a + b <= 1.001, "{a} {b}");
            }
        }
        // Rough surfaces lose energy to single scattering (known split-sum property).
        let [a, b] = lut.lookup(0.5, 1.0);
        assert!(a + b > 0.35 && a + b < 0.8, "{a} {b}");
    }

    #[test]
    fn lut_matches_direct_brdf_integration() {
        // Integrate the analytic metal BRDF (f0 = 1 and f0 = 0) over the
        // hemisphere by brute force and compare with A + B and B.
        let lut = SplitSumLut::new(64, 1024);
        for &(nv, rough) in &[(0.9f32, 0.5f32), (0.5, 0.3), (0.3, 0.8)] {
            let n = Vec3::Z;
            let v = Vec3::new((1.0 - nv * nv).sqrt(), 0.0, nv);
            let (mut s1, mut s0) = (0.0f64, 0.0f64);
            let steps = 400;
            for it in 0..steps {
                let ct = (it as f32 + 0.5) / steps as f32;
                let st = (1.0 - ct * ct).sqrt();
                for ip in 0..2 * steps {
                    let ph = (ip as f32 + 0.5) / (2 * steps) as f32 * 2.0 * PI;
                    let l = Vec3::new(st * ph.cos(), st * ph.sin(), ct);
                    let dw = (1.0 / steps as f32) * (2.0 * PI / (2 * steps) as f32);
                    let one = SurfaceParams {
                        base_color: [1.0, 0.0, 0.0],
                        metallic: 1.0,
                        roughness: rough,
                        specular: 1.0,
                    };
                    let f = eval_brdf_cos(&one, n, v, l);
                    s1 += (f[0] * dw) as f64;
                    s0 += (f[1] * dw) as f64;
                }
            }
            let [a, b] = lut.lookup(nv, rough);
            assert!(
                (s1 as f32 - (a + b)).abs() < 0.02,
                "{nv} {rough}: {s1} vs {}",
                a + b
            );
            assert!((s0 as f32 - b).abs() < 0.01, "{nv} {rough}: {s0} vs {b}");
        }
    }

    #[test]
    fn lambert_part_integrates_to_albedo() {
        let p = SurfaceParams {
            base_color: [0.5, 0.5, 0.5],
            metallic: 0.0,
            roughness: 1.0,
            specular: 0.0,
        };
        let n = Vec3::Z;
        let v = Vec3::Z;
        let f = eval_brdf_cos(&p, n, v, Vec3::new(0.6, 0.0, 0.8));
        assert!((f[0] - 0.5 / PI * 0.8).abs() < 1e-6);
    }
}
