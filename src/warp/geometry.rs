//! Geometry that depends only on sizes and settings, computed once and shared by
//! every frame: where each matched-face pixel samples the panorama, and which cube
//! faces (with which cross-fade weight) cover each output pixel.

use super::px_to_fc;
use crate::sphere::{dir_to_uv, pixel_to_dir, CubeFace, FACES};
use glam::{Mat3, Vec3};
use std::sync::{Arc, Mutex, OnceLock};

/// One face's contribution to an output pixel.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Tap {
    /// Face index in [`FACES`].
    pub face: u8,
    /// Face coordinates of the pixel's direction on that face's plane.
    pub a: f32,
    /// See `a`.
    pub b: f32,
    /// Normalised cross-fade weight.
    pub w: f32,
}

/// Per output pixel: its direction and the faces that cover it.
pub(crate) struct StitchMap {
    /// Pixel directions (camera axes), row-major.
    pub dirs: Vec<Vec3>,
    /// `taps[start[i]..start[i + 1]]` belong to pixel `i`.
    pub start: Vec<u32>,
    /// All taps.
    pub taps: Vec<Tap>,
}

type FaceKey = (u8, usize, u32, [u32; 9], usize, usize);
type StitchKey = (usize, usize, u32);

fn face_cache() -> &'static Mutex<Vec<(FaceKey, Arc<Vec<[f32; 2]>>)>> {
    static C: OnceLock<Mutex<Vec<(FaceKey, Arc<Vec<[f32; 2]>>)>>> = OnceLock::new();
    C.get_or_init(|| Mutex::new(Vec::new()))
}

fn stitch_cache() -> &'static Mutex<Vec<(StitchKey, Arc<StitchMap>)>> {
    static C: OnceLock<Mutex<Vec<(StitchKey, Arc<StitchMap>)>>> = OnceLock::new();
    C.get_or_init(|| Mutex::new(Vec::new()))
}

/// Keeps caches small: sizes and settings change rarely within a process.
const CACHE_LIMIT: usize = 64;

/// Panorama pixel positions (for [`crate::sphere::sample_px`]) of each pixel of an
/// `m x m` image of `face` spanning `[-e, e]`, seen by a camera rotated by `rot`,
/// in a `w x h` panorama.
pub(crate) fn face_lookup(
    face: CubeFace,
    m: usize,
    e: f32,
    rot: Mat3,
    w: usize,
    h: usize,
) -> Arc<Vec<[f32; 2]>> {
    let rbits = rot.to_cols_array().map(f32::to_bits);
    let key: FaceKey = (face.index() as u8, m, e.to_bits(), rbits, w, h);
    if let Ok(c) = face_cache().lock() {
        if let Some((_, v)) = c.iter().find(|(k, _)| *k == key) {
            return v.clone();
        }
    }
    let mut v = Vec::with_capacity(m * m);
    for j in 0..m {
        let b = px_to_fc(j as f32, m, e);
        for i in 0..m {
            let a = px_to_fc(i as f32, m, e);
            let (u, vv) = dir_to_uv(rot * face.dir(a, b));
            v.push([u * w as f32, vv * h as f32]);
        }
    }
    let v = Arc::new(v);
    if let Ok(mut c) = face_cache().lock() {
        if c.len() >= CACHE_LIMIT {
            c.remove(0);
        }
        c.push((key, v.clone()));
    }
    v
}

/// The stitch map of a `w x h` output with cross-fade width `blend` (face units).
pub(crate) fn stitch_map(w: usize, h: usize, blend: f32) -> Arc<StitchMap> {
    let key = (w, h, blend.to_bits());
    if let Ok(c) = stitch_cache().lock() {
        if let Some((_, v)) = c.iter().find(|(k, _)| *k == key) {
            return v.clone();
        }
    }
    let blend = blend.max(1e-4);
    let mut dirs = Vec::with_capacity(w * h);
    let mut start = Vec::with_capacity(w * h + 1);
    let mut taps = Vec::with_capacity(w * h * 5 / 4);
    for row in 0..h {
        for col in 0..w {
            let d = pixel_to_dir(col, row, w, h);
            dirs.push(d);
            start.push(taps.len() as u32);
            let first = taps.len();
            let mut wsum = 0.0f32;
            for f in FACES {
                let Some((a, b)) = f.project(d) else { continue };
                let edge = a.abs().max(b.abs());
                // Weight 1 well inside, falling to 0 at `blend` beyond the edge.
                let wgt = ((1.0 + blend - edge) / (2.0 * blend)).clamp(0.0, 1.0);
                if wgt > 0.0 {
                    taps.push(Tap {
                        face: f.index() as u8,
                        a,
                        b,
                        w: wgt,
                    });
                    wsum += wgt;
                }
            }
            if wsum > 0.0 {
                for t in &mut taps[first..] {
                    t.w /= wsum;
                }
            }
        }
    }
    start.push(taps.len() as u32);
    let m = Arc::new(StitchMap { dirs, start, taps });
    if let Ok(mut c) = stitch_cache().lock() {
        if c.len() >= CACHE_LIMIT {
            c.remove(0);
        }
        c.push((key, m.clone()));
    }
    m
}
