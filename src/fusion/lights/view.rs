//! A placed light and far sources as one frame sees them.

use super::{Surface, View};
use crate::image::{luminance, HdrImage, SdrImage};
use crate::scene::Pose;
use crate::sphere::sample_dir;
use glam::Vec3;

/// A placed light as a frame sees it through its [`Surface`], pixel by pixel.
#[derive(Clone, Copy, Debug)]
pub struct LightView<'a> {
    /// The surface the light lies on.
    pub surface: Surface,
    /// The two probes that saw it.
    pub probes: [View<'a>; 2],
    /// The frame's pose.
    pub frame: Pose,
}

impl LightView<'_> {
    /// The unit normal of the plane the light lies on, in the frame's camera
    /// axes, turned to the frame's side; `None` for a light at infinity or a
    /// frame in the plane.
    pub fn facing(&self) -> Option<[f32; 3]> {
        let Surface::Plane { point, normal } = self.surface else {
            return None;
        };
        let side = normal.dot(self.frame.position - point);
        if !(side.is_finite() && side.abs() > 1e-6) {
            return None;
        }
        let n =
            (self.frame.world_from_camera.transpose() * normal * side.signum()).normalize_or_zero();
        (n != Vec3::ZERO && n.is_finite()).then(|| n.to_array())
    }

    /// Radiance the frame sees in direction `d` (its camera axes) through the
    /// light's surface ([`LightView::sample`] without the magnification).
    pub fn radiance(&self, d: Vec3) -> Option<[f32; 3]> {
        self.sample(d, 1).map(|(r, _)| r)
    }

    /// What the frame (`frame_width` pixels wide) sees in direction `d` (its camera
    /// axes) through the light's surface, and how sharply.
    ///
    /// The radiance is the probes' samples of the same surface point, the probe
    /// that sees it from nearest the frame's viewpoint weighing most (a window's
    /// sky or a glossy patch changes with the viewpoint).
    ///
    /// The magnification is how many frame pixels one pixel of that probe spans
    /// along a line at the point: the ratio of the two views' linear angular
    /// scales of a small patch there (distance ratio times the square root of the
    /// foreshortening ratio), times the ratio of the panoramas' widths. Above 1,
    /// the probe's samples are that many times blurrier than the frame's pixels.
    /// For sources at infinity only the widths count.
    ///
    /// `None` when the ray misses the surface.
    pub fn sample(&self, d: Vec3, frame_width: usize) -> Option<([f32; 3], f32)> {
        let dw = self.frame.world_from_camera * d;
        let widths = |img: &HdrImage| frame_width as f32 / img.width().max(1) as f32;
        let (mut sum, mut norm) = ([0.0f64; 3], 0.0f64);
        let mut add = |img: &HdrImage, pose: &Pose, v: Vec3, wt: f64| {
            let c = sample_dir(img, pose.world_from_camera.transpose() * v);
            for k in 0..3 {
                sum[k] += wt * c[k] as f64;
            }
            norm += wt;
        };
        let magnification = match self.surface {
            // The same direction from both: the nearer probe weighs more.
            Surface::Infinity => {
                for (img, pose) in self.probes {
                    let wt = 1.0 / (pose.position.distance(self.frame.position) as f64 + 1e-3);
                    add(img, pose, dw, wt);
                }
                widths(self.probes[0].0)
            }
            Surface::Plane { normal, .. } => {
                let (x, t) = self.surface.meet(self.frame.position, dw)?;
                let along = normal.dot(dw).abs();
                // (angle between the probe's and the frame's rays, magnification)
                let mut nearest: Option<(f32, f32)> = None;
                for (img, pose) in self.probes {
                    let v = x - pose.position;
                    let dp = v.length();
                    if !(dp > 0.0 && dp.is_finite()) {
                        return None;
                    }
                    let u = v / dp;
                    let angle = u.dot(dw).clamp(-1.0, 1.0).acos();
                    add(img, pose, u, 1.0 / (angle as f64 + 0.02));
                    let cos_p = (normal.dot(v) / dp).abs().max(1e-3);
                    let m = dp / t * (along / cos_p).sqrt() * widths(img);
                    if nearest.map_or(true, |(a, _)| angle < a) {
                        nearest = Some((angle, m));
                    }
                }
                nearest?.1
            }
        };
        (norm > 0.0).then(|| (sum.map(|s| (s / norm) as f32), magnification))
    }
}

/// Probe pixels around a near light's ball that still count as that light.
/// Chosen on the corpus's development scenes: irradiance error mean 0.2273,
/// 0.2275, 0.2287 and p95 0.6056, 0.6053, 0.6050 with 1, 2, 4 (flat: the
/// geometry, not this slack, does the work).
const NEAR_SLACK_PX: f32 = 2.0;

/// Bright sources far away (the sky and the sun through a window, and their mirror
/// images in glossy floors), seen by the probes in the same direction as by the
/// frame: radiance at infinity depends only on the direction.
#[derive(Clone, Debug)]
pub struct SkyView<'a> {
    /// Probes that may see the same far source.
    pub probes: Vec<View<'a>>,
    /// The frame's pose.
    pub frame: Pose,
    /// Radiance (luminance) a probe's sample must exceed to count: a probe that sees
    /// a wall in that direction, not the far source, says nothing about it.
    pub floor: f32,
    /// Lights placed at a finite distance: a probe's ray that meets one sees
    /// that light, not a far source, in that direction ([`PairLights::near`]).
    ///
    /// [`PairLights::near`]: super::PairLights::near
    pub near: Vec<NearLight>,
    /// Neighbouring frames of the walk, which see a far source in the same
    /// world direction: where every one of them measured that direction
    /// unclipped, a bright probe sample there is no far source (a lamp or a
    /// patch one probe sees past a corner, not the sky).
    pub witnesses: &'a [Witness],
}

/// A neighbouring frame as a witness of the far sources: which of its pixels
/// clipped, and its pose. Holds one byte per pixel, not the frame's radiance.
#[derive(Clone, Debug)]
pub struct Witness {
    clipped: Vec<bool>,
    width: usize,
    height: usize,
    pose: Pose,
}

impl Witness {
    /// The witness a frame with linearised `radiance`, white point `white` and
    /// `pose` makes: a pixel is clipped when any channel is at 95% of the white
    /// point or above (the clip code's neighbours bleed into it).
    pub fn new(radiance: &HdrImage, white: f32, pose: Pose) -> Self {
        let limit = CLIPPED_FRACTION * white;
        let clipped = radiance
            .data()
            .chunks_exact(3)
            .map(|p| p.iter().any(|&c| !(c < limit)))
            .collect();
        Witness {
            clipped,
            width: radiance.width(),
            height: radiance.height(),
            pose,
        }
    }

    /// [`Witness::new`] for the frame `codes` whose code `c` has the radiance
    /// `radiance[c]`, without the frame's radiance ever being made.
    pub fn from_codes(codes: &SdrImage, radiance: &[f32; 256], white: f32, pose: Pose) -> Self {
        let limit = CLIPPED_FRACTION * white;
        let clips = radiance.map(|v| !(v < limit));
        let clipped = codes
            .data()
            .chunks_exact(3)
            .map(|p| p.iter().any(|&c| clips[c as usize]))
            .collect();
        Witness {
            clipped,
            width: codes.width(),
            height: codes.height(),
            pose,
        }
    }

    /// True when this frame measured world direction `dw` unclipped: neither
    /// the pixel there nor its eight neighbours clipped (a far source brighter
    /// than the white point would clip them, pixel-sized or not; the
    /// neighbours absorb the sampling's half-pixel).
    pub fn unclipped(&self, dw: Vec3) -> bool {
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 {
            return false;
        }
        let (u, v) = crate::sphere::dir_to_uv(self.pose.world_from_camera.transpose() * dw);
        let (cx, cy) = ((u * w as f32) as i64, (v * h as f32) as i64);
        for dy in -1..=1i64 {
            let yy = (cy + dy).clamp(0, h as i64 - 1) as usize;
            for dx in -1..=1i64 {
                let xx = (cx + dx).rem_euclid(w as i64) as usize;
                if self.clipped[yy * w + xx] {
                    return false;
                }
            }
        }
        true
    }
}

/// A channel this close to the white point counts as clipped for a witness (the
/// clip code's neighbours bleed into it).
const CLIPPED_FRACTION: f32 = 0.95;

/// A light placed at a finite distance, as a ball: where it is (world axes) and
/// how large it is (the radius that holds the solid angle a probe saw it fill).
#[derive(Clone, Copy, Debug)]
pub struct NearLight {
    pub position: Vec3,
    pub radius: f32,
}

impl NearLight {
    /// True when the ray from `from` along `d` (unit) passes within the light's
    /// radius, widened by `slack` times its distance (an angle: a probe
    /// pixel's width and the placement's uncertainty).
    pub fn hit(&self, from: Vec3, d: Vec3, slack: f32) -> bool {
        let v = self.position - from;
        let along = v.dot(d);
        if along <= 0.0 {
            return false;
        }
        let off = (v - along * d).length();
        off <= self.radius + slack * v.length()
    }
}

impl SkyView<'_> {
    /// Radiance in direction `d` (the frame's camera axes) from the probes that see
    /// something brighter than `floor` there, nearer probes weighing more; `None`
    /// when none does.
    pub fn radiance(&self, d: Vec3) -> Option<[f32; 3]> {
        self.radiance_past(d, &[])
    }

    /// True when probe `j`'s sample in direction `d` (the frame's camera axes)
    /// counts in the far lookup ([`SkyView::radiance_past`] with `hidden`):
    /// brighter than `floor`, not a light placed nearby or hidden from the
    /// frame, and not a direction the frame's neighbours all measured.
    pub fn bright(&self, j: usize, d: Vec3, hidden: &[NearLight]) -> bool {
        let dw = self.frame.world_from_camera * d;
        self.far_sample(j, dw, hidden).is_some() && !self.witnessed_unclipped(dw)
    }

    /// Probe `j`'s sample in world direction `dw` when it may show a far
    /// source: brighter than `floor`, and its ray meets no light placed
    /// nearby that the frame's ray misses (that light lies elsewhere in the
    /// frame; a window's aperture triangulated as a light is met by both
    /// rays, the sky through it is at infinity) and none of `hidden`.
    fn far_sample(&self, j: usize, dw: Vec3, hidden: &[NearLight]) -> Option<[f32; 3]> {
        let (img, pose) = &self.probes[j];
        let slack = NEAR_SLACK_PX * std::f32::consts::TAU / img.width().max(1) as f32;
        if self
            .near
            .iter()
            .any(|l| l.hit(pose.position, dw, slack) && !l.hit(self.frame.position, dw, slack))
        {
            return None;
        }
        if hidden.iter().any(|l| l.hit(pose.position, dw, slack)) {
            return None;
        }
        let c = sample_dir(img, pose.world_from_camera.transpose() * dw);
        (luminance(c) > self.floor).then_some(c)
    }

    /// True when every neighbouring frame measured world direction `dw`
    /// unclipped (no witnesses: false).
    fn witnessed_unclipped(&self, dw: Vec3) -> bool {
        !self.witnesses.is_empty() && self.witnesses.iter().all(|w| w.unclipped(dw))
    }

    /// [`SkyView::radiance`] without the probe samples whose ray meets one of
    /// `hidden` (lights found hidden from the frame, world axes): what a probe
    /// sees of a light the frame cannot see is no far source for the frame.
    pub fn radiance_past(&self, d: Vec3, hidden: &[NearLight]) -> Option<[f32; 3]> {
        self.radiance_from(d, hidden, None)
    }

    /// [`SkyView::radiance_past`] from the probes `only` marks (all when
    /// `None`).
    pub fn radiance_from(
        &self,
        d: Vec3,
        hidden: &[NearLight],
        only: Option<&[bool]>,
    ) -> Option<[f32; 3]> {
        let dw = self.frame.world_from_camera * d;
        let (mut sum, mut norm) = ([0.0f64; 3], 0.0f64);
        for (j, (_, pose)) in self.probes.iter().enumerate() {
            if only.is_some_and(|o| !o.get(j).copied().unwrap_or(true)) {
                continue;
            }
            let Some(c) = self.far_sample(j, dw, hidden) else {
                continue;
            };
            if self.witnessed_unclipped(dw) {
                return None;
            }
            let wt = 1.0 / (pose.position.distance(self.frame.position) as f64 + 1e-3);
            for k in 0..3 {
                sum[k] += wt * c[k] as f64;
            }
            norm += wt;
        }
        (norm > 0.0).then(|| sum.map(|s| (s / norm) as f32))
    }
}
