//! Light sources as sources: bright regions of two probes, matched by triangulation,
//! placed in 3-D and carried to a frame with the power they have at the frame's
//! position (radiance is invariant along rays; a small source's solid angle scales
//! with the inverse square of its distance).

use super::{components, FrameLight, FusionParams};
use crate::image::{luminance, HdrImage};
use crate::scene::{distance_m, Pose};
use crate::sphere::{pixel_to_dir, row_solid_angles};
use glam::Vec3;

/// A bright region of one panorama.
#[derive(Clone, Copy, Debug)]
pub struct Light {
    /// Power-weighted mean direction, world axes, unit length.
    pub dir: Vec3,
    /// Power above the threshold (luminance x solid angle).
    pub power: f64,
    /// Solid angle of the region in steradians.
    pub solid_angle: f64,
}

/// A light seen by two probes and placed in the world.
#[derive(Clone, Copy, Debug)]
pub struct PlacedLight {
    /// World position (far away for sources at infinity).
    pub position: Vec3,
    /// True when the two rays were parallel: only the direction is known.
    pub at_infinity: bool,
    /// Direction when at infinity (world axes).
    pub dir: Vec3,
    /// `(power, distance)` as seen from each probe.
    pub seen: [(f64, f32); 2],
    /// Mean radiance above the threshold as each probe saw it (power over solid
    /// angle). Radiance does not change along rays, so no part of the source can
    /// look brighter than this from anywhere, unless a probe did not resolve it.
    pub radiance: [f64; 2],
}

impl Light {
    /// Mean radiance above the threshold (power over solid angle; 0 for an empty
    /// region).
    pub fn radiance(&self) -> f64 {
        if self.solid_angle > 0.0 {
            self.power / self.solid_angle
        } else {
            0.0
        }
    }
}

impl PlacedLight {
    /// True when the two probes agree on the light's intensity (power times squared
    /// distance, constant for a compact source) within a factor `max_ratio`. A
    /// source at infinity must show the same power to both.
    pub fn consistent(&self, max_ratio: f64) -> bool {
        let i = |k: usize| self.seen[k].0 * (self.seen[k].1 as f64).powi(2);
        let (a, b) = (i(0), i(1));
        if !(a.is_finite() && b.is_finite() && a > 0.0 && b > 0.0) {
            return false;
        }
        a.max(b) <= max_ratio * a.min(b)
    }

    /// Direction (world axes) and power of the light as seen from `p`.
    pub fn seen_from(&self, p: Vec3) -> (Vec3, f64) {
        if self.at_infinity {
            return (self.dir, 0.5 * (self.seen[0].0 + self.seen[1].0));
        }
        let v = self.position - p;
        let d = v.length().max(1e-3);
        // Each probe's inverse-square extrapolation, weighted by how little it
        // extrapolates: the probe whose distance to the light is nearest the
        // frame's saw it most as the frame does (the inverse-square law is only
        // approximate for an extended source). Measured: kitchen irradiance error
        // 0.065 -> 0.052 against the plain mean; flat 0.073 -> 0.072.
        let (mut sum, mut norm) = (0.0, 0.0);
        for &(pw, dist) in &self.seen {
            let ratio = dist as f64 / d as f64;
            let wt = 1.0 / (ratio.ln().abs() + 0.05);
            sum += wt * pw * ratio * ratio;
            norm += wt;
        }
        let power = sum / norm;
        (v / d, power)
    }
}

/// Bright regions (luminance above `threshold`) of a probe taken with `pose`, with at
/// least `min_px` pixels; regions closer than `join_deg` degrees count as one.
pub fn find_lights(
    img: &HdrImage,
    pose: &Pose,
    threshold: f32,
    min_px: usize,
    join_deg: f32,
) -> Vec<Light> {
    let (w, h) = (img.width(), img.height());
    let sa = row_solid_angles(w, h);
    let bright: Vec<bool> = img.pixels().map(|p| luminance(p) > threshold).collect();
    let r = (w as f32 * join_deg.max(0.0) / 360.0).round() as usize;
    let joined = super::dilate(&bright, w, h, r);
    let (lab, n) = components(&joined, w, h);
    let mut acc = vec![(Vec3::ZERO, 0.0f64, 0usize, 0.0f64); n];
    for (i, &l) in lab.iter().enumerate() {
        if l == u32::MAX || !bright[i] {
            continue;
        }
        let (x, y) = (i % w, i / w);
        let m = ((luminance(img.get(x, y)) - threshold) as f64) * sa[y] as f64;
        let a = &mut acc[l as usize];
        a.0 += pose.world_from_camera * pixel_to_dir(x, y, w, h) * m as f32;
        a.1 += m;
        a.2 += 1;
        a.3 += sa[y] as f64;
    }
    acc.into_iter()
        .filter(|a| a.2 >= min_px && a.1 > 0.0 && a.0.length() > 0.0)
        .map(|a| Light {
            dir: a.0.normalize(),
            power: a.1,
            solid_angle: a.3,
        })
        .collect()
}

/// Matches the lights of two probes (at `pa` and `pb`) whose rays nearly meet (gap
/// below `max_gap`, in the poses' unit, in front of both) or are parallel (sources at infinity),
/// best pairs first, each light used once.
pub fn triangulate(a: &[Light], pa: Vec3, b: &[Light], pb: Vec3, max_gap: f32) -> Vec<PlacedLight> {
    let mut pairs = Vec::new();
    for (i, la) in a.iter().enumerate() {
        for (j, lb) in b.iter().enumerate() {
            let cos = la.dir.dot(lb.dir);
            if cos > 0.9998 {
                // Parallel within about a degree: a source at infinity.
                pairs.push((0.0f32, i, j, None));
                continue;
            }
            // Closest points of the rays pa + s da and pb + t db.
            let (da, db, r) = (la.dir, lb.dir, pa - pb);
            let (bb, d, e) = (da.dot(db), da.dot(r), db.dot(r));
            let denom = 1.0 - bb * bb;
            if denom < 1e-8 {
                continue;
            }
            let s = (bb * e - d) / denom;
            let t = (e - bb * d) / denom;
            if s <= 0.05 || t <= 0.05 {
                continue;
            }
            let (qa, qb) = (pa + da * s, pb + db * t);
            let gap = qa.distance(qb);
            if gap <= max_gap {
                pairs.push((gap, i, j, Some((qa + qb) * 0.5)));
            }
        }
    }
    pairs.sort_by(|x, y| x.0.total_cmp(&y.0));
    let (mut used_a, mut used_b) = (vec![false; a.len()], vec![false; b.len()]);
    let mut out = Vec::new();
    for (_, i, j, pos) in pairs {
        if used_a[i] || used_b[j] {
            continue;
        }
        used_a[i] = true;
        used_b[j] = true;
        let radiance = [a[i].radiance(), b[j].radiance()];
        out.push(match pos {
            Some(x) => PlacedLight {
                position: x,
                at_infinity: false,
                dir: Vec3::ZERO,
                seen: [(a[i].power, x.distance(pa)), (b[j].power, x.distance(pb))],
                radiance,
            },
            None => PlacedLight {
                position: Vec3::ZERO,
                at_infinity: true,
                dir: (a[i].dir + b[j].dir).normalize(),
                seen: [(a[i].power, 1.0), (b[j].power, 1.0)],
                radiance,
            },
        });
    }
    out
}

/// The lights two probes (image and pose each) both see, placed in 3-D and carried
/// to a frame with pose `frame`: direction in the frame's camera axes, power at
/// its position and the brightest mean radiance a probe saw, for
/// [`super::fuse_with_lights`]. `white` is the radiance at which the frame clips.
pub fn lights_at_frame(
    a: (&HdrImage, &Pose),
    b: (&HdrImage, &Pose),
    frame: &Pose,
    white: f32,
    p: &FusionParams,
) -> Vec<FrameLight> {
    let find = |img: &HdrImage, pose: &Pose| {
        find_lights(img, pose, white, p.min_core_px, p.light_join_deg)
    };
    let (la, lb) = (find(a.0, a.1), find(b.0, b.1));
    let (pa, pb) = (a.1.position, b.1.position);
    let to_frame = frame.world_from_camera.transpose();
    let mut placed = Vec::new();
    for l in triangulate(&la, pa, &lb, pb, p.max_gap_rel * pa.distance(pb)) {
        // Two probes that disagree on the light's intensity (power times squared
        // distance) saw different parts of it or different lights: the
        // inverse-square model does not hold, the estimate decides.
        if !l.consistent(p.max_intensity_ratio) {
            continue;
        }
        let (d, mut pw) = l.seen_from(frame.position);
        // A frame taken at a probe (within 1 mm) sees the light exactly as that
        // probe did: no extrapolation from the other one.
        let at = |q: Vec3| distance_m(q, frame.position) < 1e-3;
        if at(pa) {
            pw = l.seen[0].0;
        } else if at(pb) {
            pw = l.seen[1].0;
        }
        placed.push(FrameLight {
            dir: to_frame * d,
            power: pw,
            radiance: l.radiance[0].max(l.radiance[1]),
        });
    }
    placed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lamp_seen_by_two_probes_is_placed_and_scaled() {
        let lamp = Vec3::new(1.0, 0.5, 2.6);
        let (pa, pb) = (Vec3::new(0.0, 0.0, 1.5), Vec3::new(2.0, 0.0, 1.5));
        let la = Light {
            dir: (lamp - pa).normalize(),
            power: 2.0,
            solid_angle: 0.01,
        };
        let lb = Light {
            dir: (lamp - pb).normalize(),
            power: 2.0,
            solid_angle: 0.01,
        };
        let far = Light {
            dir: Vec3::new(0.0, -1.0, 0.0),
            power: 1.0,
            solid_angle: 0.01,
        };
        let placed = triangulate(&[la, far], pa, &[far, lb], pb, 0.2);
        assert_eq!(placed.len(), 2);
        let lamp_light = placed.iter().find(|p| !p.at_infinity).unwrap();
        assert!(lamp_light.position.distance(lamp) < 1e-3);
        // Halfway between, closer to the lamp: more power than either probe saw.
        let frame = Vec3::new(1.0, 0.5, 1.6);
        let (dir, power) = lamp_light.seen_from(frame);
        assert!(dir.dot(Vec3::Z) > 0.999);
        let expect = 2.0 * (lamp.distance(pa) as f64 / 1.0).powi(2);
        assert!(
            (power - expect).abs() / expect < 1e-3,
            "{power} vs {expect}"
        );
        let sun = placed.iter().find(|p| p.at_infinity).unwrap();
        assert!((sun.seen_from(frame).1 - 1.0).abs() < 1e-9);
    }

    #[test]
    fn lights_at_a_frame_do_not_depend_on_the_poses_unit() {
        // A lamp seen by two probes, drawn as a bright disc of 4 degrees around
        // its direction from each; the same walk in metres and in centimetres.
        let (w, h) = (256, 128);
        let lamp = Vec3::new(1.0, 0.4, 2.5);
        // Probe b sees the lamp 10 cm higher (the centroids of an extended lamp
        // seen from two sides): the rays miss by about 0.1 m, within a tenth of
        // the 2 m between the probes, but 10 units once the walk is in cm.
        let probe = |at: Vec3, lamp: Vec3| {
            let to = (lamp - at).normalize();
            let img = HdrImage::from_fn(w, h, |x, y| {
                if pixel_to_dir(x, y, w, h).dot(to) > 4f32.to_radians().cos() {
                    [50.0, 40.0, 30.0]
                } else {
                    [0.2, 0.2, 0.2]
                }
            });
            let pose = Pose {
                position: at,
                world_from_camera: glam::Mat3::IDENTITY,
            };
            (img, pose)
        };
        let a = probe(Vec3::new(0.0, 0.0, 1.5), lamp);
        let b = probe(Vec3::new(2.0, 0.0, 1.5), lamp + Vec3::new(0.0, 0.0, 0.1));
        let frame = Pose {
            position: Vec3::new(0.8, 0.3, 1.5),
            world_from_camera: glam::Mat3::IDENTITY,
        };
        let p = FusionParams::default();
        let metres = lights_at_frame((&a.0, &a.1), (&b.0, &b.1), &frame, 1.0, &p);
        assert_eq!(metres.len(), 1);
        let scaled = |q: &Pose| Pose {
            position: q.position * 100.0,
            ..*q
        };
        let (sa, sb, sf) = (scaled(&a.1), scaled(&b.1), scaled(&frame));
        let centimetres = lights_at_frame((&a.0, &sa), (&b.0, &sb), &sf, 1.0, &p);
        assert_eq!(centimetres.len(), 1);
        let (m, d) = (metres[0], centimetres[0]);
        assert!(m.dir.dot(d.dir) > 0.99999);
        assert!(
            (m.power - d.power).abs() < 1e-4 * m.power,
            "{} vs {}",
            m.power,
            d.power
        );
        assert!((m.radiance - d.radiance).abs() < 1e-9 * m.radiance);
        // Nearer the lamp than either probe: more power than either saw.
        assert!(m.power > metres_power_seen(&a.0, &a.1) && m.power > metres_power_seen(&b.0, &b.1));
    }

    fn metres_power_seen(img: &HdrImage, pose: &Pose) -> f64 {
        find_lights(img, pose, 1.0, 3, 0.7)
            .iter()
            .map(|l| l.power)
            .sum()
    }

    #[test]
    fn fragments_of_one_lamp_closer_than_the_join_angle_are_one_light() {
        // Two bright patches two pixels apart (one dark column between them) on a
        // 512-wide panorama (0.7 degrees per pixel).
        let (w, h) = (512, 256);
        let img = HdrImage::from_fn(w, h, |x, y| {
            let lit =
                (100..=102).contains(&y) && ((200..=203).contains(&x) || (205..=208).contains(&x));
            if lit {
                [10.0, 10.0, 10.0]
            } else {
                [0.1, 0.1, 0.1]
            }
        });
        let pose = Pose {
            position: Vec3::ZERO,
            world_from_camera: glam::Mat3::IDENTITY,
        };
        let apart = find_lights(&img, &pose, 1.0, 3, 0.0);
        assert_eq!(apart.len(), 2);
        let joined = find_lights(&img, &pose, 1.0, 3, 0.7);
        assert_eq!(joined.len(), 1);
        // Joining adds no power and no solid angle: only the bright pixels count.
        let sum = |v: &[Light], f: fn(&Light) -> f64| v.iter().map(f).sum::<f64>();
        assert!((sum(&joined, |l| l.power) - sum(&apart, |l| l.power)).abs() < 1e-9);
        assert!((sum(&joined, |l| l.solid_angle) - sum(&apart, |l| l.solid_angle)).abs() < 1e-12);
    }

    #[test]
    fn the_probe_that_extrapolates_least_weighs_most() {
        let light = PlacedLight {
            position: Vec3::ZERO,
            at_infinity: false,
            dir: Vec3::ZERO,
            seen: [(4.0, 1.0), (0.3, 3.0)],
            radiance: [1.0, 1.0],
        };
        // Seen from 1.1 m: probe A (at 1 m) predicts 4 / 1.21, probe B (at 3 m)
        // 0.3 * 9 / 1.21.
        let (_, p) = light.seen_from(Vec3::new(1.1, 0.0, 0.0));
        let (a, b) = (4.0 / 1.21, 2.7 / 1.21);
        assert!(p > b && p < a, "{p}");
        assert!((p - a).abs() < 0.25 * (a - b), "{p} should be near {a}");
        // Where both extrapolate as much, both count the same.
        let (_, p) = light.seen_from(Vec3::new(3.0f32.sqrt(), 0.0, 0.0));
        assert!((p - 0.5 * (4.0 / 3.0 + 0.3 * 3.0)).abs() < 1e-4, "{p}");
    }

    #[test]
    fn probes_that_disagree_on_a_lights_intensity_are_inconsistent() {
        let lamp = Vec3::new(1.0, 0.5, 2.6);
        let (pa, pb) = (Vec3::new(0.0, 0.0, 1.5), Vec3::new(3.0, 0.0, 1.5));
        let (da, db) = (lamp.distance(pa) as f64, lamp.distance(pb) as f64);
        let light = |pw_a: f64, pw_b: f64| {
            let la = Light {
                dir: (lamp - pa).normalize(),
                power: pw_a,
                solid_angle: 0.01,
            };
            let lb = Light {
                dir: (lamp - pb).normalize(),
                power: pw_b,
                solid_angle: 0.01,
            };
            triangulate(&[la], pa, &[lb], pb, 0.2)[0]
        };
        // A compact source: power falls with the squared distance, same intensity.
        assert!(light(1.0, (da / db).powi(2)).consistent(2.0));
        // One probe sees ten times the intensity (a window seen whole by one probe,
        // as a sliver by the other).
        assert!(!light(1.0, 0.1 * (da / db).powi(2)).consistent(2.0));
        assert!(!light(0.0, 1.0).consistent(2.0));
        // Radiance is power over solid angle.
        assert!((light(1.0, 1.0).radiance[0] - 100.0).abs() < 1e-9);
    }
}
