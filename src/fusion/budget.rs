//! Phase 2 of the fusion: the power each clipped region receives — from the
//! lights placed in 3-D that fall in it, else from the estimate's light
//! attributed to it ([`super::regions`]).

use super::ledger::Hidden;
use super::regions::{Disc, Kind, Pixels, Region};
use super::{Fallback, FrameLight, FusionParams, LightReport, Measured};
use crate::sphere::dir_to_uv;

/// Assigns each placed light to the region its direction falls in, or to the
/// region nearest in direction within `max_angle_deg` whose estimate holds a
/// power within `max_move_ratio` of the light's; reports where each went.
pub(super) fn assign_placed<'v>(
    frame: &Measured,
    px: &Pixels,
    regions: &mut [Region<'v>],
    placed: &'v [FrameLight<'v>],
    p: &FusionParams,
    fallbacks: &mut Vec<Fallback>,
    hidden: &mut Vec<Hidden>,
) -> Vec<LightReport> {
    let (w, h) = (px.w, px.h);
    let cos_max = p.max_angle_deg.min(p.max_move_deg).to_radians().cos();
    let full = if placed.is_empty() {
        Vec::new()
    } else {
        let bled = p.censored_lights && p.bled_hold;
        full_pixels(frame, px, regions.len(), bled)
    };
    let mut report = Vec::with_capacity(placed.len());
    for light in placed {
        let (d, pw) = (light.dir, light.power);
        if !(pw.is_finite() && pw > 0.0) || !d.is_finite() {
            continue;
        }
        // The solid angle its power fills at the radiance the probes saw.
        let solid = if light.radiance.is_finite() && light.radiance > 0.0 {
            pw / light.radiance
        } else {
            0.0
        };
        let (u, v) = dir_to_uv(d);
        let (x, y) = (
            ((u * w as f32) as usize).min(w - 1),
            ((v * h as f32) as usize).min(h - 1),
        );
        let mut target = px.region(y * w + x);
        if target.is_none() {
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
        // A compact light whose direction falls on a region's measured pixels
        // (its margin, or partly clipped pixels) lands on the nearest of the
        // region's fully clipped pixels, a move like any other: no farther
        // than `max_move_deg` beyond its own angular radius. Else the frame
        // measured where it would be: it is hidden from the frame. A light
        // carried through its surface lands where the surface does; a region
        // with no fully clipped pixel (a coloured lamp clips only some
        // channels) holds it in its partly clipped pixels.
        let gap_deg = match target {
            Some(o) if px.region(y * w + x) == Some(o) && px.kinds[y * w + x] == Kind::Full => 0.0,
            Some(o) => nearest_deg(px, &full[o].0, d),
            None => 0.0,
        };
        if let Some(o) = target {
            let radius = (crate::sphere::disc_radius(solid) as f32).to_degrees();
            let inside = px.region(y * w + x).is_some();
            let holds = !full[o].0.is_empty();
            // A pixel that measured nothing where the light is (within a pixel:
            // the bleed's size) is where the frame sees it.
            let seen = || within_a_pixel(px, &full[o].1, d);
            if inside
                && holds
                && light.view.is_none()
                && gap_deg > p.max_move_deg + radius
                && !seen()
            {
                fallbacks.push(Fallback::Hidden {
                    light: report.len(),
                    region: o,
                    power: pw,
                    gap_deg,
                });
                if let Some(dist) = light.distance.filter(|d| d.is_finite() && *d > 0.0) {
                    hidden.push(Hidden {
                        at: d.normalize_or_zero() * dist,
                        radius: radius.to_radians() * dist,
                    });
                }
                target = None;
            }
        }
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
            gap_deg,
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
                a.view_moved = moved_deg > 0.0;
            }
        }
        // Its angular radius from that solid angle, at least a pixel across.
        let px_angle = std::f32::consts::TAU / w as f32;
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

/// The fully clipped pixels of each of `n` regions (the pixels that could hold
/// a light), and with `bled` its partly clipped pixels that measured nothing
/// (every channel bleeds).
fn full_pixels(frame: &Measured, px: &Pixels, n: usize, bled: bool) -> Vec<(Vec<u32>, Vec<u32>)> {
    let mut out = vec![(Vec::new(), Vec::new()); n];
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        match px.kinds[i] {
            Kind::Full => out[o].0.push(i as u32),
            Kind::Partial if bled && frame.measured_nothing(i) => out[o].1.push(i as u32),
            _ => {}
        }
    }
    out
}

/// Whether one of `pixels` lies within a pixel (the bleed's size) of
/// direction `d`.
fn within_a_pixel(px: &Pixels, pixels: &[u32], d: glam::Vec3) -> bool {
    let d = d.normalize_or_zero();
    pixels.iter().any(|&i| {
        let i = i as usize;
        let pixel = (px.solid_angle(i) as f32).sqrt();
        px.dir(i).dot(d).clamp(-1.0, 1.0).acos() <= pixel
    })
}

/// The angle (degrees) from direction `d` to the nearest of `pixels`' centres
/// (180 when there are none).
fn nearest_deg(px: &Pixels, pixels: &[u32], d: glam::Vec3) -> f32 {
    let d = d.normalize_or_zero();
    let c = pixels
        .iter()
        .map(|&i| px.dir(i as usize).dot(d))
        .fold(-1.0f32, f32::max);
    c.clamp(-1.0, 1.0).acos().to_degrees()
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
pub(super) fn target_power(
    regions: &mut [Region],
    p: &FusionParams,
    fallbacks: &mut Vec<Fallback>,
) {
    for (o, r) in regions.iter_mut().enumerate() {
        let (e, a) = (&r.estimate, &r.placed);
        let radiance = if p.bound_by_peak {
            a.radiance.max(a.peak)
        } else {
            a.radiance
        };
        r.fill.target = if a.any && a.radiance > 0.0 {
            // No part of a source looks brighter than a probe saw it (radiance
            // is invariant along rays; its peak with `bound_by_peak`, else its
            // mean), so the region can hold at most that radiance over its solid
            // angle: this bounds the inverse-square extrapolation for a frame
            // close to a large source (a window, a lamp shade overhead).
            bounded(a.power, radiance * r.area, fallbacks, |power, held| {
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
