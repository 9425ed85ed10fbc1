//! The surface a light lies on, fitted to two probes' views of it.

use super::{Light, View};
use crate::image::luminance;
use crate::sphere::{pixel_to_dir, sample_dir};
use glam::Vec3;

/// The surface a light lies on: what lets the probes' pixels of a light be carried
/// to a frame pixel by pixel (radiance is invariant along rays), not only its power.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Surface {
    /// A plane through `point` with unit `normal`: a ceiling panel and the ceiling
    /// it lights, a window pane, a sunlit patch of floor.
    Plane {
        /// A point of the plane (the triangulated light).
        point: Vec3,
        /// Unit normal.
        normal: Vec3,
    },
    /// Far away, seen in the same direction from everywhere: the sun, the sky.
    Infinity,
}

impl Surface {
    /// The direction in which a camera at `eye` sees the point where the ray from
    /// `origin` along `dir` meets the surface; `None` when the ray misses it (runs
    /// parallel to the plane or meets it behind `origin`).
    pub fn seen_from(&self, origin: Vec3, dir: Vec3, eye: Vec3) -> Option<Vec3> {
        match *self {
            Surface::Infinity => Some(dir),
            Surface::Plane { .. } => {
                let v = self.meet(origin, dir)?.0 - eye;
                let d = v.length();
                (d > 0.0 && d.is_finite()).then(|| v / d)
            }
        }
    }

    /// Where the ray from `origin` along `dir` meets the plane, and how far along
    /// it; `None` when it runs parallel to the plane or meets it behind `origin`,
    /// and for a surface at infinity.
    pub(super) fn meet(&self, origin: Vec3, dir: Vec3) -> Option<(Vec3, f32)> {
        let Surface::Plane { point, normal } = *self else {
            return None;
        };
        let along = normal.dot(dir);
        if along.abs() < 1e-3 {
            return None;
        }
        let t = normal.dot(point - origin) / along;
        (t.is_finite() && t > 0.0).then(|| (origin + dir * t, t))
    }
}

/// Largest log-luminance difference one pixel counts for in [`disagreement`] (a
/// pixel that does not reach the surface counts this much).
const MAX_LOG_DIFF: f64 = 3.0;

/// How badly two probes agree that `pixels` of `src` lie on `surface`: the mean
/// (solid-angle weighted) absolute log-luminance difference between each pixel and
/// where `dst` sees the same surface point.
fn disagreement(src: View, pixels: &[u32], dst: View, surface: &Surface) -> f64 {
    let (img, pose) = src;
    let (w, h) = (img.width(), img.height());
    let to_dst = dst.1.world_from_camera.transpose();
    // At most about 500 pixels: the fit needs the light's shape, not every pixel.
    let step = (pixels.len() / 500).max(1);
    let mut errs: Vec<f64> = pixels
        .iter()
        .step_by(step)
        .map(|&i| {
            let (x, y) = (i as usize % w, i as usize / w);
            let d = pose.world_from_camera * pixel_to_dir(x, y, w, h);
            let here = luminance(img.get(x, y)).max(1e-6) as f64;
            match surface.seen_from(pose.position, d, dst.1.position) {
                Some(v) => {
                    let there = luminance(sample_dir(dst.0, to_dst * v)).max(1e-6) as f64;
                    (here.ln() - there.ln()).abs().min(MAX_LOG_DIFF)
                }
                None => MAX_LOG_DIFF,
            }
        })
        .collect();
    if errs.is_empty() {
        return MAX_LOG_DIFF;
    }
    // The median: the pixels along a light's edge disagree under any surface (a
    // sharp edge sampled between pixels), its inside agrees only under the right one.
    let mid = errs.len() / 2;
    *errs.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The surface through `point` on which two probes' views of a light (`la` seen
/// by `a`, `lb` by `b`) agree best, with its disagreement (the median absolute
/// log-luminance difference, averaged over both ways). Candidates: the plane
/// level with the probes' horizon (ceilings, floors), the upright plane facing the
/// probes (walls, windows), the plane facing them (anything tilted), and infinity.
pub fn fit_surface(a: View, la: &Light, b: View, lb: &Light, point: Vec3) -> (Surface, f64) {
    let up =
        (a.1.world_from_camera * Vec3::Y + b.1.world_from_camera * Vec3::Y).normalize_or_zero();
    let to = 0.5 * (a.1.position + b.1.position) - point;
    let upright = (to - up * to.dot(up)).normalize_or_zero();
    // The triangulated point is the meeting of the two probes' power-weighted
    // centres, which for an extended light lie a little off its surface: each
    // plane is also tried shifted along its normal, by up to 15% of the light's
    // distance.
    let reach = 0.15 * to.length();
    let mut candidates = vec![Surface::Infinity];
    for normal in [up, upright, to.normalize_or_zero()] {
        if normal.length_squared() > 0.5 {
            for k in -6..=6 {
                let point = point + normal * (reach * k as f32 / 6.0);
                candidates.push(Surface::Plane { point, normal });
            }
        }
    }
    candidates
        .into_iter()
        .map(|s| {
            // Both ways: each probe's view of the light must be explained by the
            // other's. One way only, a uniform panel seen small by one probe lands
            // inside the other's view of it under several planes.
            let e = 0.5 * (disagreement(a, &la.pixels, b, &s) + disagreement(b, &lb.pixels, a, &s));
            (s, e)
        })
        .min_by(|x, y| x.1.total_cmp(&y.1))
        .expect("infinity is always a candidate")
}
