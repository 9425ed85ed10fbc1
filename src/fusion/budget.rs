//! Phase 2 of the fusion: the power each clipped region receives — from the
//! lights placed in 3-D that fall in it, else from the estimate's light
//! attributed to it ([`super::regions`]).

use super::lights::SkyView;
use super::regions::{Disc, Far, Kind, Pixels, Region};
use super::{Fallback, FrameLight, FusionParams, LightReport};
use crate::sphere::dir_to_uv;

/// Assigns each placed light to the region its direction falls in, or to the
/// region nearest in direction within `max_angle_deg` whose estimate holds a
/// power within `max_move_ratio` of the light's; reports where each went.
pub(super) fn assign_placed<'v>(
    px: &Pixels,
    regions: &mut [Region<'v>],
    placed: &'v [FrameLight<'v>],
    sky: Option<&SkyView>,
    p: &FusionParams,
    fallbacks: &mut Vec<Fallback>,
) -> Vec<LightReport> {
    let (w, h) = (px.w, px.h);
    let cos_max = p.max_angle_deg.min(p.max_move_deg).to_radians().cos();
    let mut report = Vec::with_capacity(placed.len());
    let mut far: Option<Vec<bool>> = None;
    for light in placed {
        let (d, pw) = (light.dir, light.power);
        if !(pw.is_finite() && pw > 0.0) || !d.is_finite() {
            continue;
        }
        let (u, v) = dir_to_uv(d);
        let (x, y) = (
            ((u * w as f32) as usize).min(w - 1),
            ((v * h as f32) as usize).min(h - 1),
        );
        let mut target = px.region(y * w + x);
        if light.extra {
            // A light of a farther probe pair: only a clipped region within
            // reach of its direction, only one no nearer light went to, and
            // only one the probes' far lookup does not cover (a window's sky
            // is its far source's, looked up pixel by pixel: shared flat's
            // window lost a third of its light to a farther pair's light).
            target = target.or_else(|| nearest_clipped(px, d, p.extra_reach_deg));
            let free = target.is_some_and(|o| {
                let covered = far.get_or_insert_with(|| far_covered(px, sky, p));
                !regions[o].placed.any && !covered.get(o).copied().unwrap_or(false)
            });
            if !free {
                continue;
            }
        } else if target.is_none() {
            let dn = d.normalize_or_zero();
            let mut best = cos_max;
            for (b, r) in regions.iter().enumerate() {
                let c = dn.dot(r.dir.normalize_or_zero());
                if c >= best {
                    best = c;
                    target = Some(b);
                }
            }
        }
        let moved_deg = match target {
            Some(o) if px.region(y * w + x).is_none() => {
                let c = d
                    .normalize_or_zero()
                    .dot(regions[o].dir.normalize_or_zero());
                c.clamp(-1.0, 1.0).acos().to_degrees()
            }
            _ => 0.0,
        };
        // A light moved into a region is that region's light only if the
        // estimate's light there, when it has any, is of its size: else it is
        // another light. (An estimate with no light there says nothing.)
        if let Some(o) = target {
            let e = regions[o].estimate.power;
            let k = p.max_move_ratio;
            if moved_deg > 0.0 && e > 0.0 && !(e * k > pw && e < k * pw) {
                fallbacks.push(Fallback::MoveRefused {
                    light: report.len(),
                    region: o,
                    power: pw,
                    estimate_power: e,
                });
                target = None;
            }
        }
        report.push(LightReport {
            at_px: (u * w as f32, v * h as f32),
            power: pw,
            region: target,
            moved_deg,
            probe_power: light.seen,
            distance: light.distance,
            facing: light.view.as_ref().and_then(|v| v.facing()),
        });
        let Some(o) = target else { continue };
        let a = &mut regions[o].placed;
        a.power += pw;
        a.any = true;
        if let Some(v) = &light.view {
            if a.view.map_or(true, |(p0, _)| pw > p0) {
                a.view = Some((pw, v));
            }
        }
        // Its angular radius from the solid angle its power fills at the
        // radiance the probes saw, at least a pixel across.
        let px_angle = std::f32::consts::TAU / w as f32;
        let solid = if light.radiance.is_finite() && light.radiance > 0.0 {
            pw / light.radiance
        } else {
            0.0
        };
        let radius = (crate::sphere::disc_radius(solid) as f32).clamp(px_angle, 0.5);
        // Only a light compact against its region is shaped as a disc: a broad
        // source (a window, a panel that fills the region) keeps the estimate's
        // shape.
        let compact = solid > 0.0 && solid < p.disc_max_area * regions[o].area;
        let a = &mut regions[o].placed;
        a.broad |= !compact;
        if compact {
            a.discs.push(Disc {
                dir: d.normalize(),
                radius,
                power: pw as f32,
                norm: 0.0,
            });
        }
        if light.radiance.is_finite() {
            a.radiance = a.radiance.max(light.radiance);
        }
        if light.peak.is_finite() {
            a.peak = a.peak.max(light.peak);
        }
    }
    report
}

/// `power` bounded by what the region can hold (`held`); a binding bound is
/// reported as the fallback `named` makes of the two.
fn bounded(
    power: f64,
    held: f64,
    fallbacks: &mut Vec<Fallback>,
    named: impl FnOnce(f64, f64) -> Fallback,
) -> f64 {
    if held < power {
        fallbacks.push(named(power, held));
    }
    power.min(held)
}

/// The power each region receives (`fill.target`).
pub(super) fn target_power(regions: &mut [Region], fallbacks: &mut Vec<Fallback>) {
    for (o, r) in regions.iter_mut().enumerate() {
        let (e, a) = (&r.estimate, &r.placed);
        r.fill.target = if a.any && a.radiance > 0.0 {
            // No part of a source looks brighter than a probe saw it on average
            // (radiance is invariant along rays), so the region can hold at most
            // that radiance over its solid angle: this bounds the inverse-square
            // extrapolation for a frame close to a large source (a window, a lamp
            // shade overhead).
            bounded(a.power, a.radiance * r.area, fallbacks, |power, held| {
                Fallback::RadianceBound {
                    region: o,
                    placed_power: power,
                    held,
                }
            })
        } else if a.any {
            a.power
        } else {
            // No pixel of the region is brighter than the brightest pixel of the
            // light attributed to it: a small region (a speck near the pole)
            // cannot hold a whole lamp's power.
            bounded(e.power, e.peak * r.core_area, fallbacks, |power, held| {
                Fallback::PeakBound {
                    region: o,
                    estimate_power: power,
                    held,
                }
            })
        };
    }
}

/// The region of the core clipped pixel nearest to direction `d` within
/// `reach_deg` degrees, if any.
fn nearest_clipped(px: &Pixels, d: glam::Vec3, reach_deg: f32) -> Option<usize> {
    let (w, h) = (px.w, px.h);
    let d = d.normalize_or_zero();
    let (u, v) = dir_to_uv(d);
    let (cx, cy) = ((u * w as f32) as isize, (v * h as f32) as isize);
    let cos_max = reach_deg.to_radians().cos();
    // Rows within reach; columns within reach at the widest of those rows
    // (the whole row near a pole).
    let ry = (reach_deg / 180.0 * h as f32).ceil() as isize;
    let (mut best, mut out) = (cos_max, None);
    for y in (cy - ry).max(0)..=(cy + ry).min(h as isize - 1) {
        let lat = (0.5 - (y as f32 + 0.5) / h as f32) * std::f32::consts::PI;
        let c = (lat.abs() + reach_deg.to_radians())
            .min(std::f32::consts::FRAC_PI_2)
            .cos();
        let rx = if c < 1e-3 {
            w as isize
        } else {
            ((reach_deg / 360.0 * w as f32) / c).ceil() as isize
        }
        .min(w as isize / 2);
        for dx in -rx..=rx {
            let x = (cx + dx).rem_euclid(w as isize) as usize;
            let i = y as usize * w + x;
            if !px.core[i] {
                continue;
            }
            let Some(o) = px.region(i) else { continue };
            let cs = d.dot(px.dir(i));
            if cs >= best {
                best = cs;
                out = Some(o);
            }
        }
    }
    out
}

/// For each region, whether the probes see a far source over at least
/// `min_far_cover` of its fully clipped solid angle (as the fill will decide).
fn far_covered(px: &Pixels, sky: Option<&SkyView>, p: &FusionParams) -> Vec<bool> {
    let Some(sky) = sky else {
        return Vec::new();
    };
    let n = px
        .lab
        .iter()
        .filter(|&&l| l != u32::MAX)
        .map(|&l| l as usize + 1)
        .max()
        .unwrap_or(0);
    let mut cover = vec![(0.0f64, 0.0f64); n];
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        if px.kinds[i] != Kind::Full {
            continue;
        }
        let a = px.solid_angle(i);
        cover[o].1 += a;
        if sky.radiance(px.dir(i)).is_some() {
            cover[o].0 += a;
        }
    }
    cover.into_iter().map(|c| Far::covers(c, p)).collect()
}
