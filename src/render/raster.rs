//! The rasterizer: triangle setup (near-plane and guard-band clipping in camera
//! space, projection to fixed-point sample coordinates), binning into square
//! tiles, and per-tile z-buffered visibility followed by deferred shading.
//!
//! Determinism: setup and binning keep the model's triangle order, each tile is
//! rendered by one thread, depth ties keep the earlier triangle, and edge
//! functions are evaluated exactly in 64-bit integers with a top-left fill rule,
//! so the image does not depend on the thread count and shared edges neither
//! crack nor double-cover.
//!
//! Anti-aliasing: with `ss x ss` supersampling, visibility is resolved per sample
//! but each pixel shades once per distinct visible triangle, at the centroid of
//! the samples that triangle covers (MSAA-style), weighted by their share.

use super::brdf::{eval_brdf_cos, SurfaceParams, DIELECTRIC_F0};
use super::camera::{Camera, CameraFrame};
use super::model::{Material, Mesh, Model, TextureRef};
use super::{Background, Environment, RenderOptions, RenderOutput};
use crate::error::{Error, Result};
use crate::image::HdrImage;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::f32::consts::PI;

/// Tile side in output pixels.
const TILE: usize = 32;
/// Fixed-point subpixel bits of sample-space coordinates.
const SUB_BITS: u32 = 8;
const SUB: f32 = (1 << SUB_BITS) as f32;
/// Guard band: triangles are clipped to this many half-widths around the centre,
/// which bounds fixed-point magnitudes (and so keeps edge functions exact).
const GUARD: f32 = 4.0;
/// Triangles per setup work item.
const SETUP_CHUNK: usize = 4096;

/// A projected triangle (or a piece of a clipped one) ready to rasterize.
#[derive(Clone, Copy, Debug)]
struct ScreenTri {
    /// Fixed-point sample-space vertex coordinates, positively oriented.
    fx: [i64; 3],
    fy: [i64; 3],
    /// Twice the signed area in fixed-point units (> 0).
    area: i64,
    /// `1 / depth` at each vertex, for perspective-correct interpolation.
    inv_z: [f32; 3],
    /// Barycentric coordinates of each vertex in the source triangle.
    bary: [Vec3; 3],
    /// Inclusive sample bounding box, clamped to the image.
    bbox: [i32; 4],
    mesh: u32,
    tri: u32,
    /// The source triangle is seen from its back (only for double-sided ones).
    back: bool,
}

/// Everything shading needs, shared by all tiles.
struct Ctx<'a, E: ?Sized> {
    model: &'a Model,
    env: &'a E,
    opts: &'a RenderOptions,
    eye: Vec3,
    frame: CameraFrame,
    ss: usize,
    width: usize,
    height: usize,
    lights: Vec<(Vec3, [f32; 3])>,
    /// Near clipping distance: 1e-4 of the eye-target distance.
    near: f32,
}

/// A vertex of a polygon being clipped: camera-space position and source
/// barycentrics.
#[derive(Clone, Copy)]
struct ClipVert {
    c: Vec3,
    b: Vec3,
}

/// Renders `model` as seen by `camera`; see [`super::render`].
pub(super) fn render_impl<E: Environment + ?Sized>(
    model: &Model,
    env: &E,
    camera: &Camera,
    opts: &RenderOptions,
) -> Result<RenderOutput> {
    camera.validate()?;
    model.validate()?;
    if let Background::Image(img) = &opts.background {
        if img.width() == 0 || img.height() == 0 {
            return Err(Error::Invalid("background image is empty".into()));
        }
    }
    let ss = opts.supersample.clamp(1, 8);
    let (w, h) = (camera.width, camera.height);
    let lights = opts
        .lights
        .iter()
        .filter_map(|l| {
            let d = l.dir.try_normalize()?;
            l.irradiance
                .iter()
                .all(|v| v.is_finite())
                .then_some((d, l.irradiance))
        })
        .collect();
    let ctx = Ctx {
        model,
        env,
        opts,
        eye: camera.eye,
        frame: camera.frame(),
        ss,
        width: w,
        height: h,
        lights,
        near: 1e-4 * (camera.target - camera.eye).length(),
    };
    let tris = setup_all(&ctx);
    let tiles_x = w.div_ceil(TILE);
    let tiles_y = h.div_ceil(TILE);
    let bins = bin(&tris, tiles_x, tiles_y, ss);
    let tile_out: Vec<(Vec<f32>, Vec<f32>)> = (0..tiles_x * tiles_y)
        .into_par_iter()
        .map(|t| render_tile(&ctx, &tris, &bins[t], t % tiles_x, t / tiles_x))
        .collect();
    let mut color = HdrImage::new(w, h);
    let mut alpha = vec![0.0f32; w * h];
    for (t, (c, a)) in tile_out.iter().enumerate() {
        let (x0, y0) = ((t % tiles_x) * TILE, (t / tiles_x) * TILE);
        let tw = TILE.min(w - x0);
        let th = TILE.min(h - y0);
        for y in 0..th {
            let src = y * tw;
            let dst = (y0 + y) * w + x0;
            color.data_mut()[3 * dst..3 * (dst + tw)].copy_from_slice(&c[3 * src..3 * (src + tw)]);
            alpha[dst..dst + tw].copy_from_slice(&a[src..src + tw]);
        }
    }
    Ok(RenderOutput {
        color,
        alpha,
        premultiplied: matches!(opts.background, Background::Transparent),
    })
}

/// Sets up every triangle of every mesh, in model order, in parallel chunks.
fn setup_all<E: Environment + ?Sized>(ctx: &Ctx<E>) -> Vec<ScreenTri> {
    let mut jobs = Vec::new();
    for (mi, m) in ctx.model.meshes.iter().enumerate() {
        let mut s = 0;
        while s < m.indices.len() {
            let e = (s + SETUP_CHUNK).min(m.indices.len());
            jobs.push((mi, s, e));
            s = e;
        }
    }
    let parts: Vec<Vec<ScreenTri>> = jobs
        .into_par_iter()
        .map(|(mi, s, e)| {
            let mut out = Vec::with_capacity(e - s);
            for t in s..e {
                setup_tri(ctx, mi, t, &mut out);
            }
            out
        })
        .collect();
    let mut all = Vec::with_capacity(parts.iter().map(Vec::len).sum());
    for p in parts {
        all.extend(p);
    }
    all
}

/// Clips one source triangle and appends its projected pieces to `out`.
fn setup_tri<E: Environment + ?Sized>(ctx: &Ctx<E>, mi: usize, t: usize, out: &mut Vec<ScreenTri>) {
    let mesh = &ctx.model.meshes[mi];
    let mat = &ctx.model.materials[mesh.material];
    let idx = mesh.indices[t];
    let p = idx.map(|i| mesh.positions[i as usize]);
    if !p.iter().all(|v| v.is_finite()) {
        return;
    }
    // Facing in 3D: glTF front faces are counter-clockwise.
    let ng = (p[1] - p[0]).cross(p[2] - p[0]);
    let facing = ng.dot(ctx.eye - p[0]);
    if facing == 0.0 || !facing.is_finite() {
        return;
    }
    let back = facing < 0.0;
    if back && !mat.double_sided {
        return;
    }
    let f = &ctx.frame;
    let cam = p.map(|q| {
        let d = q - ctx.eye;
        Vec3::new(d.dot(f.right), d.dot(f.up), d.dot(f.forward))
    });
    let ws = (ctx.width * ctx.ss) as f32;
    let hs = (ctx.height * ctx.ss) as f32;
    let fs = f.focal_px * ctx.ss as f32;
    // Clip planes as (a, b, c, d) with a x + b y + c z + d >= 0 inside.
    let near = ctx.near;
    let gx = GUARD * 0.5 * ws / fs;
    let gy = GUARD * 0.5 * hs / fs;
    let planes = [
        [0.0, 0.0, 1.0, -near],
        [-1.0, 0.0, gx, 0.0],
        [1.0, 0.0, gx, 0.0],
        [0.0, -1.0, gy, 0.0],
        [0.0, 1.0, gy, 0.0],
    ];
    let dist = |pl: &[f32; 4], c: Vec3| pl[0] * c.x + pl[1] * c.y + pl[2] * c.z + pl[3];
    let mut needs_clip = false;
    for pl in &planes {
        let inside = cam.map(|c| dist(pl, c) >= 0.0);
        if !inside.iter().any(|&i| i) {
            return; // entirely outside one plane
        }
        if !inside.iter().all(|&i| i) {
            needs_clip = true;
        }
    }
    let mut poly: Vec<ClipVert> = vec![
        ClipVert {
            c: cam[0],
            b: Vec3::X,
        },
        ClipVert {
            c: cam[1],
            b: Vec3::Y,
        },
        ClipVert {
            c: cam[2],
            b: Vec3::Z,
        },
    ];
    if needs_clip {
        for pl in &planes {
            let mut next = Vec::with_capacity(poly.len() + 1);
            for i in 0..poly.len() {
                let a = poly[i];
                let b = poly[(i + 1) % poly.len()];
                let da = dist(pl, a.c);
                let db = dist(pl, b.c);
                if da >= 0.0 {
                    next.push(a);
                }
                if (da >= 0.0) != (db >= 0.0) {
                    let s = da / (da - db);
                    next.push(ClipVert {
                        c: a.c + (b.c - a.c) * s,
                        b: a.b + (b.b - a.b) * s,
                    });
                }
            }
            poly = next;
            if poly.len() < 3 {
                return;
            }
        }
    }
    let proj: Vec<(i64, i64, f32)> = poly
        .iter()
        .map(|v| {
            let iz = 1.0 / v.c.z;
            let sx = 0.5 * ws + v.c.x * iz * fs;
            let sy = 0.5 * hs - v.c.y * iz * fs;
            ((sx * SUB).round() as i64, (sy * SUB).round() as i64, iz)
        })
        .collect();
    for k in 1..poly.len() - 1 {
        let mut ids = [0, k, k + 1];
        let e = |i: usize| (proj[i].0, proj[i].1);
        let (a, b, c) = (e(ids[0]), e(ids[1]), e(ids[2]));
        let mut area = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
        if area == 0 {
            continue;
        }
        if area < 0 {
            ids.swap(1, 2);
            area = -area;
        }
        let fx = ids.map(|i| proj[i].0);
        let fy = ids.map(|i| proj[i].1);
        // Samples whose centres (k + 0.5) may lie inside.
        let lo = |v: i64| ((v as f64 / SUB as f64) - 0.5).ceil();
        let hi = |v: i64| ((v as f64 / SUB as f64) - 0.5).floor();
        let x0 = lo(*fx.iter().min().unwrap()).max(0.0);
        let y0 = lo(*fy.iter().min().unwrap()).max(0.0);
        let x1 = hi(*fx.iter().max().unwrap()).min(ws as f64 - 1.0);
        let y1 = hi(*fy.iter().max().unwrap()).min(hs as f64 - 1.0);
        if x0 > x1 || y0 > y1 {
            continue;
        }
        out.push(ScreenTri {
            fx,
            fy,
            area,
            inv_z: ids.map(|i| proj[i].2),
            bary: ids.map(|i| poly[i].b),
            bbox: [x0 as i32, y0 as i32, x1 as i32, y1 as i32],
            mesh: mi as u32,
            tri: t as u32,
            back,
        });
    }
}

/// Lists, per tile, the screen triangles whose bounding box touches it.
fn bin(tris: &[ScreenTri], tiles_x: usize, tiles_y: usize, ss: usize) -> Vec<Vec<u32>> {
    let mut bins = vec![Vec::new(); tiles_x * tiles_y];
    let ts = (TILE * ss) as i32;
    for (i, t) in tris.iter().enumerate() {
        let tx0 = (t.bbox[0] / ts) as usize;
        let ty0 = (t.bbox[1] / ts) as usize;
        let tx1 = ((t.bbox[2] / ts) as usize).min(tiles_x - 1);
        let ty1 = ((t.bbox[3] / ts) as usize).min(tiles_y - 1);
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                bins[ty * tiles_x + tx].push(i as u32);
            }
        }
    }
    bins
}

/// Whether samples exactly on edge `a -> b` belong to the triangle (top-left
/// rule for positively oriented triangles: exactly one of an edge and its
/// reverse owns it).
#[inline]
fn owns_edge(ax: i64, ay: i64, bx: i64, by: i64) -> bool {
    let dy = by - ay;
    dy > 0 || (dy == 0 && bx - ax < 0)
}

/// Rasterizes and shades one tile; returns its RGB and alpha, row-major.
fn render_tile<E: Environment + ?Sized>(
    ctx: &Ctx<E>,
    tris: &[ScreenTri],
    bin: &[u32],
    tx: usize,
    ty: usize,
) -> (Vec<f32>, Vec<f32>) {
    let ss = ctx.ss;
    let px0 = tx * TILE;
    let py0 = ty * TILE;
    let tw = TILE.min(ctx.width - px0);
    let th = TILE.min(ctx.height - py0);
    let (sw, sh) = (tw * ss, th * ss);
    let (sx0, sy0) = ((px0 * ss) as i32, (py0 * ss) as i32);
    let mut depth = vec![0.0f32; sw * sh];
    let mut ids = vec![u32::MAX; sw * sh];

    for &ti in bin {
        let t = &tris[ti as usize];
        let x0 = t.bbox[0].max(sx0);
        let y0 = t.bbox[1].max(sy0);
        let x1 = t.bbox[2].min(sx0 + sw as i32 - 1);
        let y1 = t.bbox[3].min(sy0 + sh as i32 - 1);
        if x0 > x1 || y0 > y1 {
            continue;
        }
        let (fx, fy) = (t.fx, t.fy);
        // Edge i is opposite vertex i: from vertex i+1 to vertex i+2.
        let mut a = [0i64; 3];
        let mut b = [0i64; 3];
        let mut bias = [0i64; 3];
        let mut c0 = [0i64; 3];
        let px = (x0 as i64) * SUB as i64 + (SUB as i64) / 2;
        let py = (y0 as i64) * SUB as i64 + (SUB as i64) / 2;
        for i in 0..3 {
            let (j, k) = ((i + 1) % 3, (i + 2) % 3);
            // E(p) = (b - a) x (p - a) with a = v_j, b = v_k.
            let ex = fx[k] - fx[j];
            let ey = fy[k] - fy[j];
            a[i] = -ey; // dE/dx per fixed unit
            b[i] = ex; // dE/dy per fixed unit
            c0[i] = ex * (py - fy[j]) - ey * (px - fx[j]);
            bias[i] = if owns_edge(fx[j], fy[j], fx[k], fy[k]) {
                0
            } else {
                1
            };
        }
        let step = SUB as i64;
        let inv_area = 1.0 / t.area as f32;
        for y in y0..=y1 {
            let dyr = (y - y0) as i64 * step;
            let mut e = [0i64; 3];
            for i in 0..3 {
                e[i] = c0[i] + b[i] * dyr;
            }
            let row = (y - sy0) as usize * sw;
            for x in x0..=x1 {
                if e[0] >= bias[0] && e[1] >= bias[1] && e[2] >= bias[2] {
                    let iz = (e[0] as f32 * t.inv_z[0]
                        + e[1] as f32 * t.inv_z[1]
                        + e[2] as f32 * t.inv_z[2])
                        * inv_area;
                    let s = row + (x - sx0) as usize;
                    if iz > depth[s] {
                        depth[s] = iz;
                        ids[s] = ti;
                    }
                }
                for i in 0..3 {
                    e[i] += a[i] * step;
                }
            }
        }
    }

    // Resolve: shade once per distinct triangle per pixel.
    let n = ss * ss;
    let mut color = vec![0.0f32; tw * th * 3];
    let mut alpha = vec![0.0f32; tw * th];
    let mut group: Vec<(u32, usize, f32, f32)> = Vec::with_capacity(n);
    for py in 0..th {
        for px in 0..tw {
            group.clear();
            for j in 0..ss {
                for i in 0..ss {
                    let s = (py * ss + j) * sw + px * ss + i;
                    let id = ids[s];
                    if id == u32::MAX {
                        continue;
                    }
                    let cx = ((px0 + px) * ss + i) as f32 + 0.5;
                    let cy = ((py0 + py) * ss + j) as f32 + 0.5;
                    match group.iter_mut().find(|g| g.0 == id) {
                        Some(g) => {
                            g.1 += 1;
                            g.2 += cx;
                            g.3 += cy;
                        }
                        None => group.push((id, 1, cx, cy)),
                    }
                }
            }
            let mut acc = [0.0f32; 3];
            let mut covered = 0usize;
            for &(id, cnt, sx, sy) in &group {
                let c = shade(ctx, &tris[id as usize], sx / cnt as f32, sy / cnt as f32);
                for k in 0..3 {
                    acc[k] += c[k] * cnt as f32;
                }
                covered += cnt;
            }
            if covered < n {
                let bg = background(ctx, px0 + px, py0 + py);
                for k in 0..3 {
                    acc[k] += bg[k] * (n - covered) as f32;
                }
            }
            let o = py * tw + px;
            for k in 0..3 {
                color[3 * o + k] = sanitize(acc[k] / n as f32);
            }
            alpha[o] = covered as f32 / n as f32;
        }
    }
    (color, alpha)
}

/// NaN and negative values become 0, +inf the largest finite float.
#[inline]
fn sanitize(v: f32) -> f32 {
    if v.is_nan() || v <= 0.0 {
        0.0
    } else {
        v.min(f32::MAX)
    }
}

/// Background radiance behind pixel `(x, y)`.
fn background<E: Environment + ?Sized>(ctx: &Ctx<E>, x: usize, y: usize) -> [f32; 3] {
    match &ctx.opts.background {
        Background::Transparent => [0.0; 3],
        Background::Color(c) => *c,
        Background::Environment => {
            let f = &ctx.frame;
            let dx = x as f32 + 0.5 - 0.5 * ctx.width as f32;
            let dy = 0.5 * ctx.height as f32 - (y as f32 + 0.5);
            let d = (f.forward * f.focal_px + f.right * dx + f.up * dy).normalize();
            ctx.env.background(d)
        }
        Background::Image(img) => {
            // Stretch to the output size, bilinear, clamped at the borders.
            let u = (x as f32 + 0.5) / ctx.width as f32 * img.width() as f32 - 0.5;
            let v = (y as f32 + 0.5) / ctx.height as f32 * img.height() as f32 - 0.5;
            let (x0, y0) = (u.floor(), v.floor());
            let (tx, ty) = (u - x0, v - y0);
            let cx = |i: f32| (i.max(0.0) as usize).min(img.width() - 1);
            let cy = |i: f32| (i.max(0.0) as usize).min(img.height() - 1);
            let (xa, xb, ya, yb) = (cx(x0), cx(x0 + 1.0), cy(y0), cy(y0 + 1.0));
            let (p00, p10, p01, p11) = (
                img.get(xa, ya),
                img.get(xb, ya),
                img.get(xa, yb),
                img.get(xb, yb),
            );
            let mut out = [0.0; 3];
            for k in 0..3 {
                let top = p00[k] + (p10[k] - p00[k]) * tx;
                let bot = p01[k] + (p11[k] - p01[k]) * tx;
                out[k] = top + (bot - top) * ty;
            }
            out
        }
    }
}

/// Texture lookup through a material's texture reference (white if absent).
#[inline]
fn tex(model: &Model, r: &Option<TextureRef>, uv: [Vec2; 2], srgb: bool) -> [f32; 3] {
    match r {
        None => [1.0; 3],
        Some(r) => {
            let uv = if r.tex_coord == 1 { uv[1] } else { uv[0] };
            model.textures[r.texture].sample(uv, r.wrap_s, r.wrap_t, srgb)
        }
    }
}

/// Interpolates a per-vertex attribute with barycentrics `b` (or `None` if absent).
#[inline]
fn interp<T>(v: &[T], idx: [u32; 3], b: Vec3) -> Option<T>
where
    T: Copy + std::ops::Mul<f32, Output = T> + std::ops::Add<Output = T>,
{
    if v.is_empty() {
        return None;
    }
    let [i0, i1, i2] = idx.map(|i| i as usize);
    Some(v[i0] * b.x + v[i1] * b.y + v[i2] * b.z)
}

/// Per-triangle tangent `dP/du` and handedness from the UV derivatives, or
/// `None` when the UV mapping is degenerate.
fn triangle_tangent(p: [Vec3; 3], uv: [Vec2; 3], n: Vec3) -> Option<(Vec3, f32)> {
    let (dp1, dp2) = (p[1] - p[0], p[2] - p[0]);
    let (d1, d2) = (uv[1] - uv[0], uv[2] - uv[0]);
    let det = d1.x * d2.y - d2.x * d1.y;
    if det.abs() < 1e-20 || !det.is_finite() {
        return None;
    }
    let t = (dp1 * d2.y - dp2 * d1.y) / det;
    let bv = (dp2 * d1.x - dp1 * d2.x) / det;
    // glTF: bitangent = cross(n, t) * w points "up" in the image, i.e. towards
    // decreasing v.
    let w = if n.cross(t).dot(bv) < 0.0 { 1.0 } else { -1.0 };
    t.is_finite().then_some((t, w))
}

/// Shades the surface of screen triangle `st` seen through sample-space point
/// `(sx, sy)`: split-sum IBL plus analytic directional lights plus emission.
fn shade<E: Environment + ?Sized>(ctx: &Ctx<E>, st: &ScreenTri, sx: f32, sy: f32) -> [f32; 3] {
    // Screen-space barycentrics at the point (clamped into the triangle), then
    // perspective-correct source barycentrics.
    let inv = 1.0 / SUB as f64;
    let vx = st.fx.map(|v| v as f64 * inv);
    let vy = st.fy.map(|v| v as f64 * inv);
    let (x, y) = (sx as f64, sy as f64);
    let edge = |j: usize, k: usize| (vx[k] - vx[j]) * (y - vy[j]) - (vy[k] - vy[j]) * (x - vx[j]);
    let mut l = [edge(1, 2), edge(2, 0), edge(0, 1)].map(|e| e.max(0.0));
    let sum: f64 = l.iter().sum();
    if sum <= 0.0 {
        l = [1.0 / 3.0; 3];
    } else {
        l = l.map(|e| e / sum);
    }
    let w = [0, 1, 2].map(|i| l[i] as f32 * st.inv_z[i]);
    let ws = w[0] + w[1] + w[2];
    let b = (st.bary[0] * w[0] + st.bary[1] * w[1] + st.bary[2] * w[2]) / ws;

    let model = ctx.model;
    let mesh: &Mesh = &model.meshes[st.mesh as usize];
    let mat: &Material = &model.materials[mesh.material];
    let idx = mesh.indices[st.tri as usize];
    let p3 = idx.map(|i| mesh.positions[i as usize]);
    let pos = p3[0] * b.x + p3[1] * b.y + p3[2] * b.z;
    let ng = (p3[1] - p3[0]).cross(p3[2] - p3[0]).normalize_or_zero();
    let mut n = interp(&mesh.normals, idx, b)
        .and_then(|v| v.try_normalize())
        .unwrap_or(ng);
    let uv0 = interp(&mesh.uv0, idx, b).unwrap_or(Vec2::ZERO);
    let uv1 = interp(&mesh.uv1, idx, b).unwrap_or(uv0);
    let uvs = [uv0, uv1];

    let bc_t = tex(model, &mat.base_color_texture, uvs, true);
    let vc = interp(&mesh.colors, idx, b).unwrap_or(Vec3::ONE);
    let base = [0, 1, 2].map(|k| (mat.base_color[k] * bc_t[k] * vc[k]).max(0.0));
    let mr = tex(model, &mat.metallic_roughness_texture, uvs, false);
    let metallic = (mat.metallic * mr[2]).clamp(0.0, 1.0);
    let roughness = (mat.roughness * mr[1]).clamp(0.0, 1.0);

    // Normal mapping in the front-face frame, then the whole frame flipped for
    // back faces of double-sided materials (glTF 3.9.5).
    if let Some(nt) = &mat.normal_texture {
        let frame = if !mesh.tangents.is_empty() {
            let t = interp(&mesh.tangents, idx, b).unwrap_or_default();
            let hand = if mesh.tangents[idx[0] as usize].w < 0.0 {
                -1.0
            } else {
                1.0
            };
            Some((t.truncate(), hand))
        } else {
            let set = if nt.tex_coord == 1 && !mesh.uv1.is_empty() {
                &mesh.uv1
            } else {
                &mesh.uv0
            };
            if set.is_empty() {
                None
            } else {
                triangle_tangent(p3, idx.map(|i| set[i as usize]), ng)
            }
        };
        if let Some((t, hand)) = frame {
            if let Some(t) = (t - n * n.dot(t)).try_normalize() {
                let bt = n.cross(t) * hand;
                let m = tex(model, &mat.normal_texture, uvs, false);
                let s = mat.normal_scale;
                let tn = Vec3::new(
                    (2.0 * m[0] - 1.0) * s,
                    (2.0 * m[1] - 1.0) * s,
                    2.0 * m[2] - 1.0,
                );
                if let Some(mapped) = (t * tn.x + bt * tn.y + n * tn.z).try_normalize() {
                    n = mapped;
                }
            }
        }
    }
    if st.back {
        n = -n;
    }

    let v = (ctx.eye - pos).normalize_or_zero();
    let nv_raw = n.dot(v);
    let nv = nv_raw.max(1e-4);
    let r = 2.0 * nv_raw * n - v;
    let spec_w = mat.specular.clamp(0.0, 1.0);

    // Split-sum IBL (Karis 2013). The specular layer reflects f0 * A + B of the
    // prefiltered radiance; the dielectric diffuse layer is weighted by one minus
    // the dielectric layer's directional albedo `s (0.04 A + B)` — the split-sum
    // counterpart of glTF's fresnel_mix(base, layer) = base (1 - F) + layer F.
    let [sa, sb] = ctx.env.brdf(nv, roughness);
    let ed = spec_w * (DIELECTRIC_F0 * sa + sb);
    let irr = ctx.env.irradiance(n);
    let pre = ctx.env.specular(r, roughness);
    let ao = match &mat.occlusion_texture {
        None => 1.0,
        Some(_) => {
            1.0 + mat.occlusion_strength * (tex(model, &mat.occlusion_texture, uvs, false)[0] - 1.0)
        }
    };
    let em_t = tex(model, &mat.emissive_texture, uvs, true);
    let mut out = [0.0f32; 3];
    for k in 0..3 {
        let diffuse = base[k] * (1.0 - metallic) * (1.0 - ed) / PI * irr[k];
        let es = (1.0 - metallic) * ed + metallic * (base[k] * sa + sb);
        out[k] = ao * (diffuse + pre[k] * es) + mat.emissive[k] * em_t[k] * mat.emissive_strength;
    }
    if !ctx.lights.is_empty() {
        let params = SurfaceParams {
            base_color: base,
            metallic,
            roughness,
            specular: spec_w,
        };
        for (l, e0) in &ctx.lights {
            let f = eval_brdf_cos(&params, n, v, *l);
            for k in 0..3 {
                out[k] += f[k] * e0[k];
            }
        }
    }
    out
}
