//! Prefiltered specular cube maps for image-based lighting (the "prefiltered
//! environment" half of the split-sum approximation).
//!
//! Source: B. Karis, "Real Shading in Unreal Engine 4", SIGGRAPH 2013 course notes.
//! Each mip `i` of the output holds, for roughness `r_i = i / (mips - 1)`, the
//! environment convolved with the GGX lobe under the assumption `N = V = R`:
//!
//! `L_pre(R) = sum_s L(l_s) (N.l_s) / sum_s (N.l_s)`,
//!
//! with half vectors `h_s` importance-sampled from the GGX distribution
//! (`alpha = r^2`) using a Hammersley sequence and `l_s = reflect(-V, h_s)`.
//!
//! To keep a bright sun from producing fireflies with only a few hundred samples,
//! each sample reads the source at a blurrier level of a mip pyramid chosen from its
//! PDF (M. Colbert and J. Křivánek, "GPU-Based Importance Sampling", GPU Gems 3,
//! ch. 20): a sample stands for the solid angle `Omega_s = 1 / (N pdf(l))` and is
//! read at `lod = 0.5 log2(Omega_s / Omega_p) + 1`, where `Omega_p = 4 pi / (6 n^2)`
//! is the mean solid angle of a level-0 texel (faces of `n` texels) and `+1` is
//! their bias. `Omega_p` is deliberately the same for every direction: a lod that
//! follows the local texel size (4-5x smaller at face corners) makes the blur level
//! vary across a bright light, and a light read at different levels in different
//! places loses or gains up to 30% of its energy.
//!
//! The source pyramid is a cube map built from the equirect input: level 0 is the
//! solid-angle-weighted average of the equirect pixels around each texel (each
//! pixel is split into sub-pixels finer than the smallest texel and splatted with
//! its exact solid angle and bilinear weights), and each coarser level averages 2x2
//! children weighted by their exact texel solid angles, so every level keeps the
//! source's integral. Face order and orientation are those of
//! [`crate::sphere::cube`] ([`FACES`], [`CubeFace::basis`]).
//!
//! Accuracy: smooth environments are filtered to about 1% and the furnace test is
//! exact. A tiny light thousands of times brighter than the rest has no fireflies
//! and keeps its energy to a few percent, but in its halo at mid roughness the
//! texels show smooth blotches of up to about 2x the exact value at 256 samples,
//! because a coarse box level moves a small light to the centre of its coarse
//! texel; quadrupling the samples (one level finer) roughly halves that. (A tent
//! filtered pyramid keeps the light's position better but loses up to 20% of its
//! energy at the 1-4 texel levels, so the box is used.)

use crate::image::HdrImage;
use crate::sphere::cube::{face_coord_to_pixel, pixel_to_face_coord, sample_face};
use crate::sphere::{CubeFace, FACES};
use glam::Vec3;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Bias added to every sample's source level, as recommended by Colbert & Křivánek
/// (GPU Gems 3, ch. 20): it widens each sample's footprint so neighbouring samples
/// overlap, which removes the remaining aliasing of bright, small lights at the cost
/// of a little extra blur.
pub const LOD_BIAS: f32 = 1.0;

/// Largest face size of the source pyramid's level 0 (unless the output itself is
/// larger): 6 x 1024^2 texels already resolve 0.1° features, enough for any lobe
/// with roughness above zero at the default sample counts.
const MAX_SOURCE_FACE: usize = 1024;

/// How to prefilter the specular cube (see [`prefilter_specular`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct SpecularOptions {
    /// Face size in texels of mip 0; mip `i` has `max(face_size >> i, 1)`.
    pub face_size: usize,
    /// Number of mips; mip `i` holds roughness `i / (mip_count - 1)` (0 and 1 at the
    /// ends, so renderers can map roughness linearly to the mip level).
    pub mip_count: usize,
    /// GGX samples per texel for every mip with roughness above zero.
    pub samples: usize,
}

impl Default for SpecularOptions {
    /// 128-texel faces, 6 mips (roughness 0, 0.2, ..., 1), 256 samples per texel:
    /// with PDF-based source filtering this is noise-free at every roughness.
    fn default() -> Self {
        SpecularOptions {
            face_size: 128,
            mip_count: 6,
            samples: 256,
        }
    }
}

/// Roughness stored in mip `i` of `mip_count`: `i / (mip_count - 1)` (0 when there
/// is a single mip).
pub fn mip_roughness(i: usize, mip_count: usize) -> f32 {
    if mip_count <= 1 {
        0.0
    } else {
        i as f32 / (mip_count - 1) as f32
    }
}

/// One level of a [`SpecularCube`]: six square faces of one roughness.
#[derive(Clone, Debug, PartialEq)]
pub struct CubeMip {
    /// Perceptual roughness `r` this level was filtered for (GGX `alpha = r^2`).
    pub roughness: f32,
    /// Face size in texels.
    pub size: usize,
    /// The six faces, indexed by [`CubeFace::index`] (order of [`FACES`]).
    pub faces: [HdrImage; 6],
}

impl CubeMip {
    /// Bilinear sample in direction `dir` (need not be unit) within the face it
    /// falls on, clamped at the face border.
    pub fn sample(&self, dir: Vec3) -> [f32; 3] {
        sample_cube(&self.faces, dir)
    }

    /// Solid-angle integral `sum_texels L Omega_texel` per channel, with exact texel
    /// solid angles (see [`cube_texel_solid_angle`]); divide by `4 pi` for the mean.
    /// Used to check that filtering keeps the environment's energy.
    pub fn integral(&self) -> [f64; 3] {
        cube_integral(&self.faces)
    }
}

/// A prefiltered specular environment: mips of increasing roughness.
#[derive(Clone, Debug, PartialEq)]
pub struct SpecularCube {
    /// Mip 0 (roughness 0, largest) first; roughness increases with the index.
    pub mips: Vec<CubeMip>,
}

impl SpecularCube {
    /// Prefiltered radiance in direction `dir` for `roughness`: bilinear within the
    /// face of each mip, linear between the two mips whose roughness brackets
    /// `roughness` (clamped to the stored range; a non-finite roughness reads mip 0).
    pub fn sample(&self, dir: Vec3, roughness: f32) -> [f32; 3] {
        let Some(first) = self.mips.first() else {
            return [0.0; 3];
        };
        let r = if roughness.is_finite() {
            roughness
        } else {
            0.0
        };
        let (face, a, b) = CubeFace::of_dir(dir);
        let at = |m: &CubeMip| sample_face_coords(&m.faces[face.index()], a, b);
        if self.mips.len() == 1 || r <= first.roughness {
            return at(first);
        }
        for pair in self.mips.windows(2) {
            let (lo, hi) = (&pair[0], &pair[1]);
            if r <= hi.roughness {
                let span = hi.roughness - lo.roughness;
                let t = if span > 0.0 {
                    ((r - lo.roughness) / span).clamp(0.0, 1.0)
                } else {
                    1.0
                };
                let (c0, c1) = (at(lo), at(hi));
                return std::array::from_fn(|k| c0[k] + (c1[k] - c0[k]) * t);
            }
        }
        at(self.mips.last().unwrap_or(first))
    }
}

/// Bilinear sample of a six-face cube map (faces in [`FACES`] order) in direction
/// `dir`, within the face `dir` falls on and clamped at its border. Shared by the
/// specular and irradiance cubes.
pub fn sample_cube(faces: &[HdrImage; 6], dir: Vec3) -> [f32; 3] {
    let (face, a, b) = CubeFace::of_dir(dir);
    sample_face_coords(&faces[face.index()], a, b)
}

/// Bilinear sample of one face at face coordinates `(a, b)` in `[-1, 1]`.
#[inline]
fn sample_face_coords(face: &HdrImage, a: f32, b: f32) -> [f32; 3] {
    if face.width() == 0 || face.height() == 0 {
        return [0.0; 3];
    }
    let x = face_coord_to_pixel(a, face.width());
    let y = face_coord_to_pixel(b, face.height());
    sample_face(face, x, y)
}

/// [`sample_face_coords`] for the hot loop of [`filter_mip`]: the same clamped
/// bilinear filter, but it truncates instead of calling `floor` (the clamped
/// coordinates are non-negative) and reads the samples directly, which makes the
/// prefilter about twice as fast.
#[inline(always)]
fn bilinear_fast(face: &HdrImage, a: f32, b: f32) -> [f32; 3] {
    let n = face.width();
    let top = (n - 1) as f32;
    let half = 0.5 * n as f32;
    let x = ((a + 1.0) * half - 0.5).clamp(0.0, top);
    let y = ((b + 1.0) * half - 0.5).clamp(0.0, top);
    let (x0, y0) = (x as usize, y as usize);
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let dx = if x0 + 1 < n { 3 } else { 0 };
    let dy = if y0 + 1 < n { 3 * n } else { 0 };
    let d = face.data();
    let i = 3 * (y0 * n + x0);
    let (p00, p10, p01, p11) = (
        &d[i..i + 3],
        &d[i + dx..i + dx + 3],
        &d[i + dy..i + dy + 3],
        &d[i + dx + dy..i + dx + dy + 3],
    );
    std::array::from_fn(|k| {
        let t = p00[k] + (p10[k] - p00[k]) * fx;
        let u = p01[k] + (p11[k] - p01[k]) * fx;
        t + (u - t) * fy
    })
}

/// [`CubeFace::of_dir`] for the hot loop: the same face choice and coordinates
/// (checked against it in the tests) with one division and no basis lookup.
/// Returns the face index. `d` must be non-zero.
#[inline(always)]
fn face_coords(d: Vec3) -> (usize, f32, f32) {
    let (ax, ay, az) = (d.x.abs(), d.y.abs(), d.z.abs());
    if ax >= ay && ax >= az {
        let inv = 1.0 / ax;
        if d.x > 0.0 {
            (CubeFace::Right.index(), d.z * inv, -d.y * inv)
        } else {
            (CubeFace::Left.index(), -d.z * inv, -d.y * inv)
        }
    } else if ay >= az {
        let inv = 1.0 / ay;
        if d.y > 0.0 {
            (CubeFace::Top.index(), d.x * inv, -d.z * inv)
        } else {
            (CubeFace::Bottom.index(), d.x * inv, d.z * inv)
        }
    } else {
        let inv = 1.0 / az;
        if d.z < 0.0 {
            (CubeFace::Front.index(), d.x * inv, -d.y * inv)
        } else {
            (CubeFace::Back.index(), -d.x * inv, -d.y * inv)
        }
    }
}

/// Exact solid angle (steradians) of texel `(x, y)` of an `n x n` cube face.
///
/// A face is the square `[-1, 1]^2` at distance 1, whose area element subtends
/// `dOmega = (1 + a^2 + b^2)^(-3/2) da db`; its integral over `[0, a] x [0, b]` is
/// `F(a, b) = atan(a b / sqrt(1 + a^2 + b^2))`, so a texel's solid angle is the
/// inclusion-exclusion of `F` at its four corners. The six faces sum to `4 pi`.
pub fn cube_texel_solid_angle(x: usize, y: usize, n: usize) -> f64 {
    let f = |a: f64, b: f64| (a * b).atan2((1.0 + a * a + b * b).sqrt());
    let step = 2.0 / n as f64;
    let (a0, b0) = (-1.0 + x as f64 * step, -1.0 + y as f64 * step);
    let (a1, b1) = (a0 + step, b0 + step);
    f(a1, b1) - f(a0, b1) - f(a1, b0) + f(a0, b0)
}

/// Solid angles of every texel of an `n x n` face, row-major (the same for all six).
fn texel_solid_angles(n: usize) -> Vec<f64> {
    (0..n * n)
        .map(|i| cube_texel_solid_angle(i % n, i / n, n))
        .collect()
}

/// `sum L Omega` over the six faces of a cube map, per channel, in `f64`.
pub(crate) fn cube_integral(faces: &[HdrImage; 6]) -> [f64; 3] {
    let mut total = [0.0f64; 3];
    for face in faces {
        let n = face.width();
        if n == 0 || face.height() != n {
            continue;
        }
        let omega = texel_solid_angles(n);
        for (px, w) in face.data().chunks_exact(3).zip(&omega) {
            for k in 0..3 {
                total[k] += px[k] as f64 * w;
            }
        }
    }
    total
}

/// Point `i` of the `n`-point Hammersley set: `(i / n, radical_inverse_2(i))`, a
/// low-discrepancy sequence on the unit square (as used by Karis 2013).
#[inline]
pub fn hammersley(i: usize, n: usize) -> (f32, f32) {
    let bits = (i as u32).reverse_bits();
    let radical = bits as f64 / 4_294_967_296.0;
    ((i as f64 / n.max(1) as f64) as f32, radical as f32)
}

/// Cosine of the angle between a GGX-sampled half vector and the normal, for the
/// uniform number `u` in `[0, 1)` and `alpha^2` (Karis 2013, `ImportanceSampleGGX`).
#[inline]
pub(crate) fn ggx_cos_theta(u: f64, a2: f64) -> f64 {
    ((1.0 - u) / (1.0 + (a2 - 1.0) * u)).clamp(0.0, 1.0).sqrt()
}

/// GGX (Trowbridge-Reitz) normal distribution `D(h)` at `cos theta_h`, for
/// `alpha^2 = a2`: `a2 / (pi ((a2 - 1) cos^2 + 1)^2)`.
#[inline]
pub(crate) fn ggx_d(cos_h: f64, a2: f64) -> f64 {
    let t = (a2 - 1.0) * cos_h * cos_h + 1.0;
    a2 / (PI * t * t)
}

/// Face size of the source pyramid's level 0: a power of two at least `face_size`
/// and at least as fine as the equirect at the equator (`2 h / pi` texels across a
/// face), capped at [`MAX_SOURCE_FACE`] (or the output size if larger).
fn source_face_size(face_size: usize, env_height: usize) -> usize {
    let needed = (2.0 * env_height as f64 / PI).ceil() as usize;
    let cap = MAX_SOURCE_FACE.max(face_size.next_power_of_two());
    face_size.max(needed).next_power_of_two().min(cap)
}

/// Per-channel value with NaN, infinite and negative samples replaced by zero.
#[inline]
fn sanitize(c: [f32; 3]) -> [f32; 3] {
    c.map(|v| if v.is_finite() && v > 0.0 { v } else { 0.0 })
}

/// A cube-map mip pyramid of the source, every level a solid-angle-weighted box
/// filter of the one below.
struct Pyramid {
    /// Level 0 (finest) first; each level holds six faces in [`FACES`] order.
    levels: Vec<[HdrImage; 6]>,
    /// Face size of level 0.
    n0: usize,
    /// Per-channel maximum of level 0 (no filtered value can exceed it).
    max: [f32; 3],
}

impl Pyramid {
    fn build(env: &HdrImage, n0: usize) -> Self {
        let mut levels = vec![splat_level0(env, n0)];
        while levels.last().map_or(1, |l| l[0].width()) > 1 {
            let next = downsample(levels.last().expect("non-empty"));
            levels.push(next);
        }
        let mut max = [0.0f32; 3];
        for face in &levels[0] {
            for px in face.data().chunks_exact(3) {
                for k in 0..3 {
                    max[k] = max[k].max(px[k]);
                }
            }
        }
        Pyramid { levels, n0, max }
    }

    /// Splits `lod` (clamped to the pyramid) into a level and the weight of the
    /// next coarser level.
    #[inline]
    fn level_of(&self, lod: f32) -> (usize, f32) {
        let top = (self.levels.len() - 1) as f32;
        let lod = if lod.is_finite() {
            lod.clamp(0.0, top)
        } else {
            0.0
        };
        let l0 = lod as usize;
        let t = lod - l0 as f32;
        if t <= 1e-4 || l0 + 1 >= self.levels.len() {
            (l0, 0.0)
        } else {
            (l0, t)
        }
    }

    /// Trilinear lookup on `face` at face coordinates `(a, b)`, level `l0` blended
    /// with level `l0 + 1` by `t` (from [`Pyramid::level_of`]).
    #[inline(always)]
    fn lookup(&self, face: usize, a: f32, b: f32, (l0, t): (usize, f32)) -> [f32; 3] {
        let c0 = bilinear_fast(&self.levels[l0][face], a, b);
        if t == 0.0 {
            return c0;
        }
        let c1 = bilinear_fast(&self.levels[l0 + 1][face], a, b);
        std::array::from_fn(|k| c0[k] + (c1[k] - c0[k]) * t)
    }
}

/// Rows and longitude window of the equirect that can reach `face`, as (row range,
/// optional column window `(first, count)` that may wrap). Side faces span
/// longitudes within 45° of their centre and latitudes within ±45°; the top face
/// lies above latitude 35.26° (the bottom face below -35.26°). One pixel of margin
/// is added; the exact face test happens per sub-pixel.
fn face_window(face: CubeFace, w: usize, h: usize) -> (std::ops::Range<usize>, (i64, usize)) {
    let row_of_lat = |lat_deg: f64| (0.5 - lat_deg / 180.0) * h as f64;
    let clamp_row = |r: f64| (r.max(0.0) as usize).min(h);
    let all_cols = (0i64, w);
    match face {
        CubeFace::Top => (0..clamp_row(row_of_lat(35.0).ceil() + 1.0), all_cols),
        CubeFace::Bottom => (clamp_row(row_of_lat(-35.0).floor() - 1.0)..h, all_cols),
        _ => {
            let rows = clamp_row(row_of_lat(45.0).floor() - 1.0)
                ..clamp_row(row_of_lat(-45.0).ceil() + 1.0);
            let centre = match face {
                CubeFace::Front => 0.0,
                CubeFace::Right => 0.25,
                CubeFace::Back => 0.5,
                _ => -0.25,
            };
            // Column c covers u in [c / w, (c + 1) / w], longitude (u - 0.5) turns.
            let first = ((centre - 0.125 + 0.5) * w as f64).floor() as i64 - 1;
            let last = ((centre + 0.125 + 0.5) * w as f64).ceil() as i64 + 1;
            let count = ((last - first) as usize).min(w);
            (rows, (first, count))
        }
    }
}

/// Level 0 of the pyramid: each texel is the solid-angle-weighted mean of the
/// equirect under a tent (bilinear) footprint one texel wide on each side. Every
/// equirect pixel is split into sub-pixels no wider than the smallest texel side
/// (so each texel's two-texel-wide tent catches several), and each sub-pixel adds
/// its radiance times its exact solid angle to the four texels around its centre
/// with bilinear weights.
/// Normalising by the accumulated weight makes a constant input exactly constant,
/// and because the tent weights sum to one everywhere, the weight a texel gathers
/// matches its solid angle to second order, so the integral is kept even for a
/// single bright pixel (a nearest-texel splat errs by several percent there). A
/// texel that still receives nothing (only possible for extreme sizes) takes a
/// bilinear sample of the equirect instead.
fn splat_level0(env: &HdrImage, n0: usize) -> [HdrImage; 6] {
    let (w, h) = (env.width(), env.height());
    // Smallest angular texel side: 2/n times the minimum metric factor
    // sqrt(1 + b^2) / (1 + a^2 + b^2) = sqrt(2)/3 at a face corner.
    let t_min = 2.0 / n0 as f64 * (2f64.sqrt() / 3.0);
    let s = t_min;
    let dlat = PI / h as f64;
    let dlon = 2.0 * PI / w as f64;
    let k_lat = ((dlat / s).ceil() as usize).clamp(1, 16);
    // Per-channel maximum of the input: a weighted mean cannot exceed it, but the
    // f32 sums can by a rounding step, so texels are clamped to it.
    let mut max = [0.0f32; 3];
    for px in env.data().chunks_exact(3) {
        let c = sanitize([px[0], px[1], px[2]]);
        for k in 0..3 {
            max[k] = max[k].max(c[k]);
        }
    }
    let faces: Vec<HdrImage> = FACES
        .par_iter()
        .map(|&face| {
            let mut acc = vec![0.0f32; 4 * n0 * n0];
            let (rows, (first_col, n_cols)) = face_window(face, w, h);
            let mut dirs_lon: Vec<(f32, f32)> = Vec::new();
            for row in rows {
                let t0 = (0.5 - row as f64 / h as f64) * PI;
                let t1 = (0.5 - (row + 1) as f64 / h as f64) * PI;
                let cos_max = if t0 >= 0.0 && t1 <= 0.0 {
                    1.0
                } else {
                    t0.cos().max(t1.cos())
                };
                let k_lon = ((dlon * cos_max / s).ceil() as usize).clamp(1, 16);
                // Sub-column longitudes (sin, cos) for the window, reused by sub-rows.
                dirs_lon.clear();
                for ci in 0..n_cols as i64 {
                    let col = first_col + ci;
                    for sj in 0..k_lon {
                        let u = (col as f64 + (sj as f64 + 0.5) / k_lon as f64) / w as f64;
                        let (sp, cp) = ((u - 0.5) * 2.0 * PI).sin_cos();
                        dirs_lon.push((sp as f32, cp as f32));
                    }
                }
                let line: Vec<[f32; 3]> = (0..n_cols as i64)
                    .map(|ci| {
                        let col = (first_col + ci).rem_euclid(w as i64) as usize;
                        sanitize(env.get(col, row))
                    })
                    .collect();
                for si in 0..k_lat {
                    let ta = t0 - (t0 - t1) * si as f64 / k_lat as f64;
                    let tb = t0 - (t0 - t1) * (si + 1) as f64 / k_lat as f64;
                    let d_omega = (dlon / k_lon as f64 * (ta.sin() - tb.sin())) as f32;
                    let (st, ct) = (0.5 * (ta + tb)).sin_cos();
                    let (st, ct) = (st as f32, ct as f32);
                    for (ci, px) in line.iter().enumerate() {
                        for &(sp, cp) in &dirs_lon[ci * k_lon..(ci + 1) * k_lon] {
                            let d = Vec3::new(ct * sp, st, -ct * cp);
                            let (f, a, b) = CubeFace::of_dir(d);
                            if f != face {
                                continue;
                            }
                            let top = (n0 - 1) as f32;
                            let x = ((a + 1.0) * 0.5 * n0 as f32 - 0.5).clamp(0.0, top);
                            let y = ((b + 1.0) * 0.5 * n0 as f32 - 0.5).clamp(0.0, top);
                            let (x0, y0) = (x as usize, y as usize);
                            let (fx, fy) = (x - x0 as f32, y - y0 as f32);
                            let (x1, y1) = ((x0 + 1).min(n0 - 1), (y0 + 1).min(n0 - 1));
                            for (i, j, wgt) in [
                                (x0, y0, (1.0 - fx) * (1.0 - fy)),
                                (x1, y0, fx * (1.0 - fy)),
                                (x0, y1, (1.0 - fx) * fy),
                                (x1, y1, fx * fy),
                            ] {
                                let wd = wgt * d_omega;
                                let cell = &mut acc[4 * (j * n0 + i)..4 * (j * n0 + i) + 4];
                                cell[0] += px[0] * wd;
                                cell[1] += px[1] * wd;
                                cell[2] += px[2] * wd;
                                cell[3] += wd;
                            }
                        }
                    }
                }
            }
            let mut img = HdrImage::new(n0, n0);
            for j in 0..n0 {
                for i in 0..n0 {
                    let cell = &acc[4 * (j * n0 + i)..4 * (j * n0 + i) + 4];
                    let v = if cell[3] > 0.0 {
                        [cell[0] / cell[3], cell[1] / cell[3], cell[2] / cell[3]]
                    } else {
                        let a = pixel_to_face_coord(i as f32, n0);
                        let b = pixel_to_face_coord(j as f32, n0);
                        sanitize(crate::sphere::sample_dir(env, face.dir(a, b)))
                    };
                    let v = sanitize(v);
                    img.set(i, j, std::array::from_fn(|k| v[k].min(max[k])));
                }
            }
            img
        })
        .collect();
    faces.try_into().expect("six faces")
}

/// Next pyramid level: each parent texel is the mean of its 2x2 children weighted
/// by their exact solid angles, so `sum L Omega` is unchanged.
fn downsample(level: &[HdrImage; 6]) -> [HdrImage; 6] {
    let n = level[0].width();
    let m = (n / 2).max(1);
    let omega = texel_solid_angles(n);
    let faces: Vec<HdrImage> = level
        .par_iter()
        .map(|src| {
            let mut out = HdrImage::new(m, m);
            for y in 0..m {
                for x in 0..m {
                    let mut acc = [0.0f64; 3];
                    let mut wsum = 0.0f64;
                    for cy in (2 * y)..(2 * y + 2).min(n) {
                        for cx in (2 * x)..(2 * x + 2).min(n) {
                            let wgt = omega[cy * n + cx];
                            let c = src.get(cx, cy);
                            for k in 0..3 {
                                acc[k] += c[k] as f64 * wgt;
                            }
                            wsum += wgt;
                        }
                    }
                    out.set(x, y, acc.map(|v| (v / wsum) as f32));
                }
            }
            out
        })
        .collect();
    faces.try_into().expect("six faces")
}

/// One importance sample in the tangent frame of `N = V`: light direction, its
/// weight `N.l`, and the pyramid level it is read at.
#[derive(Clone, Copy)]
struct LobeSample {
    l: Vec3,
    weight: f32,
    /// Pyramid level and weight of the next one (see [`Pyramid::level_of`]).
    level: (usize, f32),
}

/// The GGX samples for `roughness` with their Colbert–Křivánek levels.
///
/// With `N = V`, `pdf(l) = D(h) (N.h) / (4 V.h) = D(h) / 4`, so
/// `Omega_s = 4 / (N D(h))`, and `lod = 0.5 log2(Omega_s / Omega_p) + LOD_BIAS`
/// with the mean level-0 texel solid angle `Omega_p = 4 pi / (6 n0^2)`.
fn lobe_samples(roughness: f32, samples: usize, pyr: &Pyramid) -> Vec<LobeSample> {
    let n0 = pyr.n0;
    let alpha = (roughness as f64).powi(2);
    let a2 = (alpha * alpha).max(1e-12);
    let omega_p0 = 4.0 * PI / (6.0 * (n0 * n0) as f64);
    (0..samples)
        .filter_map(|i| {
            let (u1, u2) = hammersley(i, samples);
            let cos_h = ggx_cos_theta(u2 as f64, a2);
            let sin_h = (1.0 - cos_h * cos_h).max(0.0).sqrt();
            let (sp, cp) = (2.0 * PI * u1 as f64).sin_cos();
            // l = 2 (V.h) h - V with V = N = +z.
            let n_dot_l = 2.0 * cos_h * cos_h - 1.0;
            if n_dot_l <= 0.0 {
                return None;
            }
            let l = Vec3::new(
                (2.0 * cos_h * sin_h * cp) as f32,
                (2.0 * cos_h * sin_h * sp) as f32,
                n_dot_l as f32,
            );
            let pdf = ggx_d(cos_h, a2) / 4.0;
            let omega_s = 1.0 / (samples as f64 * pdf);
            let lod = 0.5 * (omega_s / omega_p0).log2() as f32 + LOD_BIAS;
            Some(LobeSample {
                l: l.normalize(),
                weight: n_dot_l as f32,
                level: pyr.level_of(lod),
            })
        })
        .collect()
}

/// The mip for `roughness > 0`: GGX-importance-sampled convolution of the pyramid.
fn filter_mip(pyr: &Pyramid, roughness: f32, size: usize, samples: usize) -> [HdrImage; 6] {
    let lobe = lobe_samples(roughness, samples, pyr);
    let faces: Vec<HdrImage> = FACES
        .iter()
        .map(|&face| {
            let mut out = HdrImage::new(size, size);
            out.data_mut()
                .par_chunks_mut(3 * size)
                .enumerate()
                .for_each(|(y, line)| {
                    let b = pixel_to_face_coord(y as f32, size);
                    for x in 0..size {
                        let a = pixel_to_face_coord(x as f32, size);
                        let n = face.dir(a, b).normalize();
                        let (t, bt) = n.any_orthonormal_pair();
                        let mut acc = [0.0f32; 3];
                        let mut wsum = 0.0f32;
                        for s in &lobe {
                            let l = t * s.l.x + bt * s.l.y + n * s.l.z;
                            let (f, fa, fb) = face_coords(l);
                            let c = pyr.lookup(f, fa, fb, s.level);
                            for k in 0..3 {
                                acc[k] += c[k] * s.weight;
                            }
                            wsum += s.weight;
                        }
                        for k in 0..3 {
                            // The clamp only removes rounding excess: a weighted
                            // mean of pyramid texels cannot exceed their maximum.
                            let v = if wsum > 0.0 { acc[k] / wsum } else { 0.0 };
                            line[3 * x + k] = if v.is_finite() {
                                v.clamp(0.0, pyr.max[k])
                            } else {
                                0.0
                            };
                        }
                    }
                });
            out
        })
        .collect();
    faces.try_into().expect("six faces")
}

/// Mip of roughness 0: a plain area-weighted resample of the source (no sampling),
/// read from the pyramid at the level whose texels match the output's
/// (`log2(n0 / size)`, an exact level when sizes are powers of two).
fn resample_mip(pyr: &Pyramid, size: usize) -> [HdrImage; 6] {
    let lod = (pyr.n0 as f32 / size as f32).log2().max(0.0);
    let faces: Vec<HdrImage> = FACES
        .par_iter()
        .map(|&face| {
            HdrImage::from_fn(size, size, |x, y| {
                let a = pixel_to_face_coord(x as f32, size);
                let b = pixel_to_face_coord(y as f32, size);
                let c = pyr.lookup(face.index(), a, b, pyr.level_of(lod));
                std::array::from_fn(|k| c[k].clamp(0.0, pyr.max[k]))
            })
        })
        .collect();
    faces.try_into().expect("six faces")
}

/// Prefilters an equirect, linear-radiance environment into a GGX specular cube
/// (Karis 2013 split sum, `N = V = R`; see the module docs).
///
/// Mip `i` has faces of `max(face_size >> i, 1)` texels and roughness
/// [`mip_roughness`]`(i, mip_count)`. Roughness 0 is an area-weighted resample of
/// the source; every other mip averages `samples` GGX samples (Hammersley sequence,
/// weighted by `N.l`), each read from a source pyramid level chosen from its PDF
/// (Colbert & Křivánek, GPU Gems 3 ch. 20) so that small, very bright lights blur
/// instead of producing fireflies. Faces are filled in parallel rows.
///
/// Zero sizes in `opts` are treated as 1. NaN, infinite and negative input samples
/// count as zero (validate the input first if they should be errors); an empty
/// image gives a black cube. No output texel exceeds the input's per-channel
/// maximum and none is NaN or infinite.
pub fn prefilter_specular(env: &HdrImage, opts: &SpecularOptions) -> SpecularCube {
    let face_size = opts.face_size.max(1);
    let mip_count = opts.mip_count.max(1);
    let samples = opts.samples.max(1);
    let sizes: Vec<usize> = (0..mip_count)
        .map(|i| (face_size >> i.min(usize::BITS as usize - 1)).max(1))
        .collect();
    if env.width() == 0 || env.height() == 0 {
        let mips = sizes
            .iter()
            .enumerate()
            .map(|(i, &size)| CubeMip {
                roughness: mip_roughness(i, mip_count),
                size,
                faces: std::array::from_fn(|_| HdrImage::new(size, size)),
            })
            .collect();
        return SpecularCube { mips };
    }
    let n0 = source_face_size(face_size, env.height());
    let pyr = Pyramid::build(env, n0);
    let mips = sizes
        .iter()
        .enumerate()
        .map(|(i, &size)| {
            let roughness = mip_roughness(i, mip_count);
            let faces = if roughness <= 0.0 {
                resample_mip(&pyr, size)
            } else {
                filter_mip(&pyr, roughness, size, samples)
            };
            CubeMip {
                roughness,
                size,
                faces,
            }
        })
        .collect();
    SpecularCube { mips }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sphere::{pixel_solid_angle, pixel_to_dir};

    fn equirect_integral(img: &HdrImage) -> [f64; 3] {
        let (w, h) = (img.width(), img.height());
        let mut t = [0.0f64; 3];
        for y in 0..h {
            let da = pixel_solid_angle(y, w, h) as f64;
            for x in 0..w {
                let c = img.get(x, y);
                for k in 0..3 {
                    t[k] += c[k] as f64 * da;
                }
            }
        }
        t
    }

    #[test]
    fn texel_solid_angles_sum_to_four_pi() {
        for n in [1, 3, 16] {
            let s: f64 = texel_solid_angles(n).iter().sum::<f64>() * 6.0;
            assert!((s - 4.0 * PI).abs() < 1e-9, "n={n}: {s}");
        }
        // The centre texel of a large face is nearly flat: (2/n)^2.
        let n = 256;
        let c = cube_texel_solid_angle(128, 128, n);
        assert!((c / (2.0 / n as f64).powi(2) - 1.0).abs() < 1e-3);
    }

    #[test]
    fn face_coords_match_of_dir() {
        let mut dirs: Vec<Vec3> = crate::ibl::fibonacci_directions(2000);
        for f in FACES {
            for &(a, b) in &[(1.0f32, 1.0f32), (-1.0, 0.3), (0.0, -1.0), (0.99, -0.99)] {
                dirs.push(f.dir(a, b));
            }
        }
        for d in dirs {
            let (f, a, b) = CubeFace::of_dir(d);
            let (g, a2, b2) = face_coords(d);
            assert_eq!(f.index(), g, "{d}");
            assert!((a - a2).abs() < 1e-5 && (b - b2).abs() < 1e-5, "{d}");
        }
    }

    #[test]
    fn hammersley_is_stratified() {
        let n = 64;
        let mut seen = vec![false; n];
        for i in 0..n {
            let (u, v) = hammersley(i, n);
            assert!((0.0..1.0).contains(&u) && (0.0..1.0).contains(&v));
            seen[(v * n as f32) as usize] = true;
        }
        assert!(
            seen.iter().all(|&s| s),
            "radical inverse fills every stratum"
        );
    }

    #[test]
    fn ggx_sampling_pdf_integrates_to_one() {
        // int D(h) cos(h) dOmega_h = 1 for a normalised NDF.
        for r in [0.2f64, 0.5, 1.0] {
            let a2 = r.powi(4);
            let steps = 20000;
            let mut s = 0.0;
            for i in 0..steps {
                let t = (i as f64 + 0.5) / steps as f64 * PI / 2.0;
                s += ggx_d(t.cos(), a2) * t.cos() * t.sin() * 2.0 * PI * (PI / 2.0 / steps as f64);
            }
            assert!((s - 1.0).abs() < 1e-3, "r={r}: {s}");
        }
    }

    #[test]
    fn pyramid_levels_keep_the_integral() {
        let (w, h) = (128, 64);
        let img = HdrImage::from_fn(w, h, |x, y| {
            let d = pixel_to_dir(x, y, w, h);
            [1.0 + d.x.max(0.0) * 5.0, (3.0 * d.y).exp(), 0.5 + 0.5 * d.z]
        });
        let want = equirect_integral(&img);
        let pyr = Pyramid::build(&img, 64);
        assert_eq!(pyr.levels.len(), 7);
        for (l, level) in pyr.levels.iter().enumerate() {
            let got = cube_integral(level);
            for k in 0..3 {
                let rel = (got[k] - want[k]).abs() / want[k];
                assert!(
                    rel < 0.01,
                    "level {l} channel {k}: {} vs {}",
                    got[k],
                    want[k]
                );
            }
        }
        // Coarser levels are exact averages of the finer ones.
        let a = cube_integral(&pyr.levels[1]);
        let b = cube_integral(&pyr.levels[5]);
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() < 1e-4 * a[k]);
        }
    }

    #[test]
    fn splat_keeps_a_single_bright_pixel() {
        let (w, h) = (256, 128);
        let mut img = HdrImage::from_fn(w, h, |_, _| [1.0; 3]);
        img.set(40, 30, [1e6, 1e6, 1e6]);
        let want = equirect_integral(&img);
        let got = cube_integral(&splat_level0(&img, 128));
        assert!(
            (got[0] - want[0]).abs() < 0.01 * want[0],
            "{got:?} vs {want:?}"
        );
    }

    #[test]
    fn source_face_size_follows_the_input() {
        assert_eq!(source_face_size(128, 256), 256);
        assert_eq!(source_face_size(128, 64), 128);
        assert_eq!(source_face_size(100, 64), 128);
        assert_eq!(source_face_size(128, 8192), 1024);
        assert_eq!(source_face_size(4096, 8192), 4096);
    }

    #[test]
    fn sample_interpolates_between_mips() {
        let mk = |r: f32, v: f32| CubeMip {
            roughness: r,
            size: 2,
            faces: std::array::from_fn(|_| HdrImage::from_fn(2, 2, |_, _| [v; 3])),
        };
        let cube = SpecularCube {
            mips: vec![mk(0.0, 1.0), mk(0.5, 3.0), mk(1.0, 7.0)],
        };
        assert_eq!(cube.sample(Vec3::X, 0.25)[0], 2.0);
        assert_eq!(cube.sample(Vec3::Y, 0.75)[0], 5.0);
        assert_eq!(cube.sample(Vec3::Z, 2.0)[0], 7.0);
        assert_eq!(cube.sample(Vec3::Z, -1.0)[0], 1.0);
        assert_eq!(cube.sample(Vec3::ZERO, f32::NAN)[0], 1.0);
    }
}
