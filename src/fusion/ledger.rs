//! The energy ledger (issue 35): every unit of light the fusion adds above what
//! the frame measured is booked to a source the probes measured, and bounded by
//! what they measured of it, whatever path of the fill put it there.
//!
//! Two bounds, both computed from the probes' measurements and the geometry
//! before any fill, never from the fill or the base estimate:
//! - **No pixel beyond its source** (a radiance ceiling per channel): radiance is
//!   invariant along rays, so no pixel of the frame can be brighter than the
//!   brightest radiance the probes measured, at the frame's pixel size (a source a
//!   probe does not resolve looks brighter in a smaller pixel). A pixel of a
//!   region holding a light placed in 3-D may also hold that light's power at the
//!   frame in one pixel (a lamp the frame is nearer to than the probes were).
//! - **Power booked to its evidence** (a budget per clipped region): the light
//!   the region receives is at most the largest of what the probes measured of
//!   the sources in its directions: a placed light's power at the frame (bounded
//!   by the radiance the probes saw over the region's solid angle), the probes'
//!   radiance carried through a light's surface, a far source looked up in the
//!   frame's own directions, or, where no light was placed, the least of the
//!   estimate's power and the power the nearest probe that saw light in the
//!   region's directions measured there (each probe's bright regions booked to
//!   the region nearest in direction). With no distance there is no
//!   inverse-square extrapolation: the nearest probe's power is taken as it is,
//!   an assumption (on the CI corpus scene, four probes saw one lamp with 20.6
//!   to 46.0 units; the nearest one's 20.6 was nearest the frame's true 24).
//!
//! Enforced at the end over every path at once: each region pixel keeps what the
//! frame measured plus a share of its added light, scaled down to the ceiling and
//! then to the region's budget. Light whose source cannot be named is not added.

use super::lights::Light;
use super::regions::{Kind, Pixels, Region};
use crate::image::{luminance, HdrImage};
use crate::scene::Pose;
use glam::Vec3;
use serde::{Deserialize, Serialize};

/// What one probe measured, found once per probe: its bright regions above the
/// frames' white point (world axes), its brightest radiance per channel and its size.
#[derive(Clone, Debug, Default)]
pub struct ProbeEvidence {
    /// Bright regions (power above the white point, world direction).
    pub lights: Vec<Light>,
    /// Brightest radiance per channel.
    pub peak: [f32; 3],
    /// Width and height of the probe panorama.
    pub size: (usize, usize),
}

impl ProbeEvidence {
    /// The evidence of probe `img` taken with `pose`, lights above `white`, joined
    /// within `join_deg` ([`super::lights::find_lights`]).
    pub fn new(img: &HdrImage, pose: &Pose, white: f32, join_deg: f32) -> Self {
        let mut peak = [0.0f32; 3];
        for p in img.pixels() {
            for k in 0..3 {
                if p[k].is_finite() {
                    peak[k] = peak[k].max(p[k]);
                }
            }
        }
        ProbeEvidence {
            lights: super::lights::find_lights(img, pose, white, join_deg),
            peak,
            size: (img.width(), img.height()),
        }
    }
}

/// A bright region one probe measured, as the frame sees it.
#[derive(Clone, Copy, Debug)]
pub struct SeenLight {
    /// Direction in the frame's camera axes (unit).
    pub dir: Vec3,
    /// Power above the white point the probe measured.
    pub power: f64,
    /// Which of the frame's probes saw it.
    pub probe: usize,
}

/// What the frame's probes measured, in the frame's axes and at its pixel size:
/// the evidence the ledger books light to.
#[derive(Clone, Debug, Default)]
pub struct Evidence {
    /// Per channel, the brightest radiance any probe measured, scaled to the
    /// frame's pixel size where the frame's pixels are smaller than the probe's.
    pub peak: [f32; 3],
    /// The probes' bright regions.
    pub seen: Vec<SeenLight>,
}

impl Evidence {
    /// The evidence of `probes` for a `w` x `h` frame taken with pose `frame`.
    pub fn at_frame(probes: &[&ProbeEvidence], frame: &Pose, w: usize, h: usize) -> Self {
        let to_frame = frame.world_from_camera.transpose();
        let mut ev = Evidence::default();
        for (k, pe) in probes.iter().enumerate() {
            // An unresolved source's pixel holds its power over the pixel's solid
            // angle: a frame with smaller pixels sees it brighter.
            let (pw, ph) = pe.size;
            let scale = ((w * h) as f64 / (pw * ph).max(1) as f64).max(1.0) as f32;
            for c in 0..3 {
                ev.peak[c] = ev.peak[c].max(pe.peak[c] * scale);
            }
            for l in &pe.lights {
                let d = (to_frame * l.dir).normalize_or_zero();
                if d != Vec3::ZERO && l.power.is_finite() && l.power > 0.0 {
                    ev.seen.push(SeenLight {
                        dir: d,
                        power: l.power,
                        probe: k,
                    });
                }
            }
        }
        ev
    }
}

/// Which of a region's pixels its budget holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Budgeted {
    /// The fully clipped pixels (where nothing was measured); partially clipped
    /// ones are held by their measured channels and the ceiling.
    Full,
    /// Every clipped pixel.
    All,
}

/// The evidence a region's budget was taken from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// Lights placed in 3-D from two probes, at the frame's position.
    Placed,
    /// A light's radiance carried through the surface it lies on.
    Carried,
    /// A far source the probes see in the frame's directions.
    Far,
    /// The probes' bright regions in the region's directions (no light placed).
    Probes,
    /// No probe measured a light there: nothing is added.
    None,
}

/// One region's line of the ledger.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LedgerEntry {
    /// Index into the frame's blobs.
    pub region: usize,
    /// The evidence the budget comes from.
    pub source: Source,
    /// Most power (luminance x solid angle) the region may receive above what the
    /// frame measured.
    pub budget: f64,
    /// What the fill added before the ledger's bounds.
    pub filled: f64,
    /// What the region holds added in the end (equal to `filled` when the ledger
    /// only reports).
    pub added: f64,
    /// Pixels the radiance ceiling lowered.
    pub ceiling_px: usize,
    /// The most any one source of evidence gives the region (the probes' bright
    /// regions in its directions, the placed lights' power, the carried or far
    /// lookups): the region's share of the irradiance interval's upper end.
    #[serde(default)]
    pub most: f64,
}

/// Each region's evidence components, gathered before the fill from the lookups.
#[derive(Clone, Debug, Default)]
pub(super) struct Booked {
    /// Power the probes' radiance carries through a light's surface into the
    /// region's fully and partially clipped pixels.
    pub carried: [f64; 2],
    /// Power a far source looked up in the region's directions gives its fully
    /// and partially clipped pixels.
    pub far: [f64; 2],
}

/// Each region's budget and the source it is booked to.
pub(super) fn budgets(
    regions: &[Region],
    ev: &Evidence,
    max_angle_deg: f32,
    partial: bool,
) -> Vec<(Source, f64, f64)> {
    let part = |v: [f64; 2]| v[0] + if partial { v[1] } else { 0.0 };
    // Each probe's bright regions go to the clipped region nearest in direction.
    let cos_max = max_angle_deg.to_radians().cos();
    let probes = ev.seen.iter().map(|s| s.probe + 1).max().unwrap_or(0);
    let mut per = vec![vec![0.0f64; probes]; regions.len()];
    for s in &ev.seen {
        let mut best = (None, cos_max);
        for (o, r) in regions.iter().enumerate() {
            let c = s.dir.dot(r.dir.normalize_or_zero());
            if c >= best.1 {
                best = (Some(o), c);
            }
        }
        if let Some(o) = best.0 {
            per[o][s.probe] += s.power;
        }
    }
    regions
        .iter()
        .zip(&per)
        .map(|(r, seen)| {
            // The nearest probe that saw light there saw it most as the frame
            // does (probes come nearest first).
            let probes = seen.iter().copied().find(|&p| p > 0.0).unwrap_or(0.0);
            let target = if r.fill.target.is_finite() {
                r.fill.target.max(0.0)
            } else {
                0.0
            };
            let mut best = if r.placed.any {
                // The placed lights' power at the frame before the radiance
                // bound: the most their inverse-square extrapolation gives.
                let most = if r.placed.power.is_finite() {
                    r.placed.power
                } else {
                    0.0
                };
                (Source::Placed, target.max(most))
            } else if probes > 0.0 {
                (Source::Probes, target.min(probes))
            } else {
                (Source::None, 0.0)
            };
            let mut most = best.1.max(probes);
            for (s, v) in [
                (Source::Carried, part(r.booked.carried)),
                (Source::Far, part(r.booked.far)),
            ] {
                if v.is_finite() && v > best.1 {
                    best = (s, v);
                }
                if v.is_finite() {
                    most = most.max(v);
                }
            }
            (best.0, best.1, most)
        })
        .collect()
}

/// The radiance ceiling per channel of region `r`'s pixels: the probes' peak,
/// raised for a region holding a placed light to that light's power in its
/// smallest pixel.
fn ceiling(r: &Region, ev: &Evidence, min_sa: f64) -> [f32; 3] {
    let mut c = ev.peak;
    let lum = luminance(c) as f64;
    if r.placed.any && min_sa > 0.0 && lum > 0.0 && r.fill.target.is_finite() {
        let m = (r.fill.target / min_sa / lum).max(1.0) as f32;
        for v in c.iter_mut() {
            *v *= m;
        }
    }
    c
}

/// Books each region's added light (`out` over the frame's `linear`
/// measurement) to its evidence and, when `enforce`, scales it into the bounds.
pub(super) fn apply(
    linear: &HdrImage,
    px: &Pixels,
    regions: &[Region],
    ev: &Evidence,
    max_angle_deg: f32,
    enforce: Option<Budgeted>,
    out: &mut HdrImage,
) -> Vec<LedgerEntry> {
    let n = regions.len();
    let partial = enforce != Some(Budgeted::Full);
    let budget = budgets(regions, ev, max_angle_deg, partial);
    let mut min_sa = vec![f64::INFINITY; n];
    for i in 0..px.w * px.h {
        if let Some(o) = px.region(i) {
            min_sa[o] = min_sa[o].min(px.solid_angle(i));
        }
    }
    let ceil: Vec<[f32; 3]> = regions
        .iter()
        .zip(&min_sa)
        .map(|(r, &m)| ceiling(r, ev, m))
        .collect();
    let mut entries: Vec<LedgerEntry> = budget
        .iter()
        .enumerate()
        .map(|(o, &(source, b, most))| LedgerEntry {
            region: o,
            source,
            budget: b,
            filled: 0.0,
            added: 0.0,
            ceiling_px: 0,
            most,
        })
        .collect();
    let added = |v: [f32; 3], s: [f32; 3]| (luminance(v) - luminance(s)).max(0.0) as f64;
    // The ceiling, pixel by pixel: the added light is scaled so no channel passes
    // its ceiling (or what the frame measured, when that is higher).
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        let (x, y) = (i % px.w, i / px.w);
        let (v, s) = (out.get(x, y), linear.get(x, y));
        entries[o].filled += added(v, s) * px.solid_angle(i);
        let mut g = 1.0f32;
        for k in 0..3 {
            if v[k] > s[k] {
                let room = (ceil[o][k].max(s[k]) - s[k]) / (v[k] - s[k]);
                g = g.min(room.max(0.0));
            }
        }
        if g < 1.0 {
            entries[o].ceiling_px += 1;
            if enforce.is_some() {
                out.set(
                    x,
                    y,
                    std::array::from_fn(|k| s[k] + g * (v[k] - s[k]).max(0.0)),
                );
            }
        }
    }
    if enforce.is_some() {
        // The budget, region by region: the added light scaled to it.
        let counted = |i: usize| partial || px.kinds[i] == Kind::Full;
        let mut now = vec![0.0f64; n];
        for i in 0..px.w * px.h {
            let Some(o) = px.region(i) else { continue };
            if counted(i) {
                let (x, y) = (i % px.w, i / px.w);
                now[o] += added(out.get(x, y), linear.get(x, y)) * px.solid_angle(i);
            }
        }
        let f: Vec<f32> = entries
            .iter()
            .zip(&now)
            .map(|(e, &a)| {
                if a > e.budget {
                    (e.budget / a) as f32
                } else {
                    1.0
                }
            })
            .collect();
        for i in 0..px.w * px.h {
            let Some(o) = px.region(i) else { continue };
            if f[o] < 1.0 && counted(i) {
                let (x, y) = (i % px.w, i / px.w);
                let (v, s) = (out.get(x, y), linear.get(x, y));
                out.set(
                    x,
                    y,
                    std::array::from_fn(|k| s[k] + f[o] * (v[k] - s[k]).max(0.0)),
                );
            }
        }
    }
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        let (x, y) = (i % px.w, i / px.w);
        entries[o].added += added(out.get(x, y), linear.get(x, y)) * px.solid_angle(i);
    }
    entries
}
