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

type FaceCache = Vec<(FaceKey, Arc<Vec<[f32; 2]>>, usize)>;
type StitchCache = Vec<(StitchKey, Arc<StitchMap>, usize)>;

fn face_cache() -> &'static Mutex<FaceCache> {
    static C: OnceLock<Mutex<FaceCache>> = OnceLock::new();
    C.get_or_init(|| Mutex::new(Vec::new()))
}

fn stitch_cache() -> &'static Mutex<StitchCache> {
    static C: OnceLock<Mutex<StitchCache>> = OnceLock::new();
    C.get_or_init(|| Mutex::new(Vec::new()))
}

/// Keeps caches small: sizes and settings change rarely within a process.
const CACHE_LIMIT: usize = 64;

/// Most bytes a cache holds. Larger entries (faces and panoramas of very wide
/// frames) are made for each use instead, so memory stays bounded at any size:
/// a 7776-pixel-wide stitch map alone would take 1.1 GB.
const CACHE_BYTES: usize = 96 << 20;

/// Adds `v` (of `bytes` bytes) to `cache`, dropping the oldest entries so that at
/// most [`CACHE_LIMIT`] entries and [`CACHE_BYTES`] bytes remain; entries larger
/// than the budget are not kept.
fn insert_bounded<K, V>(cache: &mut Vec<(K, V, usize)>, key: K, v: V, bytes: usize) {
    if bytes > CACHE_BYTES {
        return;
    }
    while !cache.is_empty()
        && (cache.len() >= CACHE_LIMIT
            || cache.iter().map(|e| e.2).sum::<usize>() + bytes > CACHE_BYTES)
    {
        cache.remove(0);
    }
    cache.push((key, v, bytes));
}

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
        if let Some((_, v, _)) = c.iter().find(|(k, _, _)| *k == key) {
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
        insert_bounded(&mut c, key, v.clone(), m * m * 8);
    }
    v
}

/// One row of a stitch map: per pixel its direction and its taps
/// `taps[start[i]..start[i + 1]]`.
#[derive(Default)]
pub(crate) struct RowMap {
    /// Pixel directions.
    pub dirs: Vec<Vec3>,
    /// Tap ranges, `w + 1` entries.
    pub start: Vec<u32>,
    /// The row's taps.
    pub taps: Vec<Tap>,
}

/// Appends the directions, tap starts (offset by the taps already in `taps`) and
/// taps of row `row` of a `w x h` output with cross-fade width `blend`.
fn push_row(
    row: usize,
    w: usize,
    h: usize,
    blend: f32,
    dirs: &mut Vec<Vec3>,
    start: &mut Vec<u32>,
    taps: &mut Vec<Tap>,
) {
    let blend = blend.max(1e-4);
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

/// Row `row` of the stitch map of a `w x h` output (the same values as the row of
/// [`stitch_map`]), into `out`.
pub(crate) fn stitch_row(row: usize, w: usize, h: usize, blend: f32, out: &mut RowMap) {
    out.dirs.clear();
    out.start.clear();
    out.taps.clear();
    push_row(
        row,
        w,
        h,
        blend,
        &mut out.dirs,
        &mut out.start,
        &mut out.taps,
    );
    out.start.push(out.taps.len() as u32);
}

/// The stitch map of a `w x h` output with cross-fade width `blend` (face units),
/// or `None` when it would exceed the cache budget (callers then make it row by
/// row with [`stitch_row`]).
pub(crate) fn stitch_map(w: usize, h: usize, blend: f32) -> Option<Arc<StitchMap>> {
    // Directions, tap starts and about 1.25 taps per pixel.
    let bytes = w * h * (std::mem::size_of::<Vec3>() + 4 + 5 * std::mem::size_of::<Tap>() / 4);
    if bytes > CACHE_BYTES {
        return None;
    }
    let key = (w, h, blend.to_bits());
    if let Ok(c) = stitch_cache().lock() {
        if let Some((_, v, _)) = c.iter().find(|(k, _, _)| *k == key) {
            return Some(v.clone());
        }
    }
    let mut dirs = Vec::with_capacity(w * h);
    let mut start = Vec::with_capacity(w * h + 1);
    let mut taps = Vec::with_capacity(w * h * 5 / 4);
    for row in 0..h {
        push_row(row, w, h, blend, &mut dirs, &mut start, &mut taps);
    }
    start.push(taps.len() as u32);
    let m = Arc::new(StitchMap { dirs, start, taps });
    if let Ok(mut c) = stitch_cache().lock() {
        insert_bounded(&mut c, key, m.clone(), bytes);
    }
    Some(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_made_one_at_a_time_match_the_kept_map() {
        let (w, h, blend) = (64, 32, 0.08);
        let m = stitch_map(w, h, blend).expect("a small map is kept");
        let mut row = RowMap::default();
        let bits = |t: &Tap| (t.face, t.a.to_bits(), t.b.to_bits(), t.w.to_bits());
        for y in 0..h {
            stitch_row(y, w, h, blend, &mut row);
            assert_eq!(row.start.len(), w + 1);
            for x in 0..w {
                let i = y * w + x;
                assert_eq!(row.dirs[x], m.dirs[i]);
                let a = &row.taps[row.start[x] as usize..row.start[x + 1] as usize];
                let b = &m.taps[m.start[i] as usize..m.start[i + 1] as usize];
                assert_eq!(
                    a.iter().map(bits).collect::<Vec<_>>(),
                    b.iter().map(bits).collect::<Vec<_>>()
                );
            }
        }
        // A 7776-pixel-wide map is not kept; callers make it row by row.
        assert!(stitch_map(7776, 3888, blend).is_none());
    }
}
