//! The energy ledger (issue 35): every unit of light the fusion adds above what
//! the frame measured is booked to a source the probes measured, and bounded by
//! what they measured of it, whatever path of the fill put it there.
//!
//! Two bounds, both computed from the probes' measurements and the geometry
//! before any fill, never from the fill or the base estimate:
//! - **No pixel beyond its source** (a radiance ceiling per channel): radiance is
//!   invariant along rays, so no pixel of the frame can be brighter than the
//!   brightest radiance the probes measured, at the frame's pixel size (a source a
//!   probe does not resolve looks brighter in a smaller pixel). A region holding
//!   a light placed in 3-D may hold that light's power at the frame in one pixel
//!   (a lamp the frame is nearer to than the probes were); any other region
//!   that cannot hold its budget (below) at the peak over its solid angle holds
//!   a source no probe resolved, seen from nearer: its pixels may hold up to the
//!   whole budget in one pixel, and no more.
//! - **Power booked to its evidence** (a budget per clipped region): the light
//!   the region receives is at most the largest of what the probes measured of
//!   the sources in its directions: a placed light's power at the frame (bounded
//!   by the radiance the probes saw over the region's solid angle), the probes'
//!   radiance carried through a light's surface, a far source looked up in the
//!   frame's own directions, or, where no light was placed, the least of the
//!   estimate's power and the power the nearest probe that saw light in the
//!   region's directions measured there (each probe's bright regions booked to
//!   the region nearest in direction). With no distance there is no
//!   inverse-square extrapolation: that probe's power is taken as it is, an
//!   assumption. (The nearest probe's alone, whether or not it saw light there,
//!   was tried earlier: it misses a sun through a window the nearest probe does
//!   not see, dev irradiance error 0.215 -> 0.230; a probe that saw nothing
//!   there is no view of the source.)
//!
//! Enforced at the end over every path at once: each region pixel keeps what the
//! frame measured plus a share of its added light, scaled down to the ceiling and
//! then to the region's budget. Light whose source cannot be named is not added.

use super::regions::{Kind, Pixels, Region};
use super::walk::Mend;
use crate::image::{luminance, HdrImage};
use crate::scene::Pose;
use crate::sphere::{pixel_to_dir, row_solid_angles};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Angular size of the cells a probe's light above the white point is gathered
/// in (degrees): an extended source (a window, the sky) is booked cell by cell
/// to the frame's regions, a compact one lands in one cell.
const CELL_DEG: f32 = 2.0;

/// What one probe measured, found once per probe: its light above the frames'
/// white point gathered in cells of [`CELL_DEG`] (power and power-weighted
/// direction, world axes), its brightest radiance per channel and its size.
#[derive(Clone, Debug, Default)]
pub struct ProbeEvidence {
    /// Light above the white point, per cell: world direction (unit) and power.
    pub cells: Vec<(Vec3, f64)>,
    /// Brightest radiance per channel.
    pub peak: [f32; 3],
    /// Width and height of the probe panorama.
    pub size: (usize, usize),
    /// Where the probe was taken (world).
    pub position: Vec3,
}

impl ProbeEvidence {
    /// The evidence of probe `img` taken with `pose`, light above `white`.
    pub fn new(img: &HdrImage, pose: &Pose, white: f32) -> Self {
        let (w, h) = (img.width(), img.height());
        let sa = row_solid_angles(w, h);
        let (cw, ch) = ((360.0 / CELL_DEG) as usize, (180.0 / CELL_DEG) as usize);
        // Ordered by cell, so the cells' order (and every sum over them) is the
        // same in every process.
        let mut cells: BTreeMap<(usize, usize), (Vec3, f64)> = BTreeMap::new();
        let mut peak = [0.0f32; 3];
        for (i, p) in img.pixels().enumerate() {
            for k in 0..3 {
                if p[k].is_finite() {
                    peak[k] = peak[k].max(p[k]);
                }
            }
            let l = luminance(p);
            if !(l.is_finite() && l > white) {
                continue;
            }
            let (x, y) = (i % w, i / w);
            let e = (l - white) as f64 * sa[y] as f64;
            let c = cells.entry((x * cw / w, y * ch / h)).or_default();
            c.0 += pose.world_from_camera * pixel_to_dir(x, y, w, h) * e as f32;
            c.1 += e;
        }
        let mut cells: Vec<(Vec3, f64)> = cells
            .into_values()
            .filter(|c| c.1 > 0.0)
            .map(|(d, e)| (d.normalize_or_zero(), e))
            .filter(|c| c.0 != Vec3::ZERO)
            .collect();
        cells.sort_by(|a, b| b.1.total_cmp(&a.1));
        ProbeEvidence {
            cells,
            peak,
            size: (w, h),
            position: pose.position,
        }
    }
}

/// Light above the white point one probe measured in one cell, as the frame
/// sees it.
#[derive(Clone, Copy, Debug)]
pub struct SeenLight {
    /// Direction in the frame's camera axes (unit).
    pub dir: Vec3,
    /// Power above the white point the probe measured.
    pub power: f64,
    /// Which of the frame's probes saw it.
    pub probe: usize,
    /// Where that probe was, relative to the frame, in the frame's axes.
    pub at: Vec3,
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
    /// Regions the walk holds to what the neighbouring frames carry to them
    /// ([`super::walk`]).
    pub walk: Vec<Mend>,
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
            for &(dir, power) in &pe.cells {
                let d = (to_frame * dir).normalize_or_zero();
                if d != Vec3::ZERO && power.is_finite() && power > 0.0 {
                    ev.seen.push(SeenLight {
                        dir: d,
                        power,
                        probe: k,
                        at: to_frame * (pe.position - frame.position),
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
    /// None: only the radiance ceiling holds (with its excess spread over the
    /// region), the budgets are reported.
    Ceiling,
    /// Only a region no probe saw light in (no source named) is held: it keeps
    /// what the frame measured. The ceiling holds everywhere.
    Named,
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
    /// The probes' bright regions in the region's directions (no light placed):
    /// what the nearest probe that saw them measured.
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
    /// Direction of the region in the frame's axes (unit), for following it
    /// along the walk.
    #[serde(default)]
    pub dir: [f32; 3],
    /// What the probes' radiance gives the region pixel by pixel (carried
    /// through a light's surface, or a far source where the lookup covers the
    /// pixels), with nothing extrapolated: the part of the budget the walk
    /// never holds the region below.
    #[serde(default)]
    pub measured: f64,
    /// The power the walk held the region to ([`super::walk`]), and what it held
    /// before (`added` is after).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub walk: Option<WalkHeld>,
}

/// A region the walk held.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct WalkHeld {
    /// The power its neighbours carry to it.
    pub power: f64,
    /// What the region held added before.
    pub before: f64,
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
    /// The part of `far` the lookup covers pixel by pixel (no pixel counted at
    /// the covered ones' mean).
    pub far_covered: [f64; 2],
}

/// A placed light hidden from the frame ([`super::Fallback::Hidden`]): where
/// it is, relative to the frame in the frame's axes, and its radius.
#[derive(Clone, Copy, Debug)]
pub(super) struct Hidden {
    pub at: Vec3,
    pub radius: f32,
}

impl Hidden {
    /// Whether probe cell `s` lies on this light as its probe saw it: its
    /// direction within the light's angular radius from that probe, plus a
    /// cell's size.
    fn holds(&self, s: &SeenLight) -> bool {
        let v = self.at - s.at;
        let d = v.length();
        if !(d > 0.0 && d.is_finite()) {
            return false;
        }
        let reach = (self.radius / d).atan() + CELL_DEG.to_radians();
        s.dir.dot(v / d).clamp(-1.0, 1.0).acos() <= reach
    }
}

/// Each region's budget and the source it is booked to.
pub(super) fn budgets(
    regions: &[Region],
    ev: &Evidence,
    max_angle_deg: f32,
    partial: bool,
    hidden: &[Hidden],
) -> Vec<(Source, f64, f64)> {
    let part = |v: [f64; 2]| v[0] + if partial { v[1] } else { 0.0 };
    // Each probe's bright regions go to the clipped region nearest in direction.
    let cos_max = max_angle_deg.to_radians().cos();
    let probes = ev.seen.iter().map(|s| s.probe + 1).max().unwrap_or(0);
    let mut per = vec![vec![0.0f64; probes]; regions.len()];
    // How far each probe stood from the frame; one whose distance is not
    // finite (a broken pose) counts as the farthest.
    let mut dist = vec![f32::MAX; probes];
    for s in &ev.seen {
        dist[s.probe] = Some(s.at.length())
            .filter(|d| d.is_finite())
            .unwrap_or(f32::MAX);
    }
    for s in &ev.seen {
        // A cell of a light the frame measured where it would be is no
        // region's evidence.
        if hidden.iter().any(|l| l.holds(s)) {
            continue;
        }
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
            // A source no light was placed for has no distance to carry its
            // power by: the nearest probe that saw it, the least extrapolated
            // view, gives the budget; the most any probe saw bounds the
            // interval's upper end.
            // (Ties: the first probe.)
            let nearest = seen
                .iter()
                .zip(&dist)
                .filter(|(&v, _)| v > 0.0)
                .fold((f32::INFINITY, 0.0f64), |best, (&v, &d)| {
                    if d < best.0 {
                        (d, v)
                    } else {
                        best
                    }
                })
                .1;
            let probes = seen.iter().copied().fold(0.0f64, f64::max);
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
            } else if nearest > 0.0 {
                (Source::Probes, target.min(nearest))
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

/// What the probes' radiance gives region `r` pixel by pixel, nothing
/// extrapolated.
fn measured(r: &Region, partial: bool) -> f64 {
    let part = |v: [f64; 2]| v[0] + if partial { v[1] } else { 0.0 };
    let v = part(r.booked.carried).max(part(r.booked.far_covered));
    if v.is_finite() {
        v
    } else {
        0.0
    }
}

/// The radiance ceiling per channel of region `r`'s pixels: the probes' peak
/// (radiance is invariant along rays, so a source the probes resolve looks no
/// brighter from anywhere). A light placed in 3-D may be nearer the frame than
/// the probes: its region's pixels may hold the power it is to receive
/// (`r.fill.target`) in one pixel. Any other region is raised only where it
/// cannot hold its sources' power (`power`, its budget) at the peak over its
/// solid angle: a source no probe resolved, seen from nearer; then a pixel may
/// hold up to all of that power, in the region's smallest pixel (`min_sa`).
fn ceiling(r: &Region, ev: &Evidence, min_sa: f64, power: f64) -> [f32; 3] {
    let mut c = ev.peak;
    let lum = luminance(c) as f64;
    let power = if r.placed.any {
        r.fill.target
    } else if power.is_finite() && power > lum * r.area {
        power
    } else {
        0.0
    };
    if power.is_finite() && power > 0.0 && min_sa > 0.0 && lum > 0.0 {
        let m = (power / min_sa / lum).clamp(1.0, f32::MAX as f64) as f32;
        for v in c.iter_mut() {
            *v = (*v * m).min(f32::MAX);
        }
    }
    c
}

/// Books each region's added light (`out` over the frame's `linear`
/// measurement) to its evidence and, when `enforce`, holds it to the bounds:
/// first each region's budget, then the ceiling, whose excess goes to the
/// region's fully clipped pixels with room (so the ceiling alone keeps the
/// region's power where its pixels can hold it).
pub(super) fn apply(
    linear: &HdrImage,
    px: &Pixels,
    regions: &[Region],
    ev: &Evidence,
    max_angle_deg: f32,
    enforce: Option<Budgeted>,
    hidden: &[Hidden],
    bounded: &dyn Fn(usize) -> bool,
    out: &mut HdrImage,
) -> Vec<LedgerEntry> {
    let n = regions.len();
    // A pixel that kept a measured channel takes no light spread to it: the
    // measured bound ([`super::FusionParams::measured_bound`]) set what it may
    // hold, knowing the light's colour, which the ledger does not.
    let open_to = |i: usize| px.kinds[i] == Kind::Full && !bounded(i);
    let partial = enforce != Some(Budgeted::Full);
    let budget = budgets(regions, ev, max_angle_deg, partial, hidden);
    let mut min_sa = vec![f64::INFINITY; n];
    for i in 0..px.w * px.h {
        if let Some(o) = px.region(i) {
            min_sa[o] = min_sa[o].min(px.solid_angle(i));
        }
    }
    let ceil: Vec<[f32; 3]> = budget
        .iter()
        .zip(&min_sa)
        .zip(regions)
        .map(|((&(_, b, _), &m), r)| ceiling(r, ev, m, b))
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
            measured: measured(&regions[o], partial),
            dir: regions[o].dir.normalize_or_zero().to_array(),
            walk: None,
        })
        .collect();
    let added = |v: [f32; 3], s: [f32; 3]| (luminance(v) - luminance(s)).max(0.0) as f64;
    // How far pixel `i`'s added light may be scaled before a channel passes its
    // ceiling (or what the frame measured, when that is higher).
    let room = |o: usize, v: [f32; 3], s: [f32; 3]| {
        let mut g = f32::INFINITY;
        for k in 0..3 {
            if v[k] > s[k] {
                g = g.min(((ceil[o][k].max(s[k]) - s[k]) / (v[k] - s[k])).max(0.0));
            }
        }
        g
    };
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        let (x, y) = (i % px.w, i / px.w);
        let (v, s) = (out.get(x, y), linear.get(x, y));
        entries[o].filled += added(v, s) * px.solid_angle(i);
        if room(o, v, s) < 1.0 {
            entries[o].ceiling_px += 1;
        }
    }
    let Some(mode) = enforce else {
        for e in entries.iter_mut() {
            e.added = e.filled;
        }
        return entries;
    };
    let counted = |i: usize| mode != Budgeted::Full || px.kinds[i] == Kind::Full;
    // The budget, region by region: the added light scaled to it.
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
            let held = match mode {
                Budgeted::Ceiling => false,
                Budgeted::Named => e.source == Source::None,
                Budgeted::Full | Budgeted::All => true,
            };
            if a > e.budget && held {
                (e.budget / a) as f32
            } else {
                1.0
            }
        })
        .collect();
    // Then the ceiling, with what it takes from a pixel given to the region's
    // other fully clipped pixels that have room, in proportion to their share
    // (a light concentrated past what the probes measured is spread, not lost).
    let mut members: Vec<Vec<(usize, f64, f32)>> = vec![Vec::new(); n];
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        let (x, y) = (i % px.w, i / px.w);
        let (mut v, s) = (out.get(x, y), linear.get(x, y));
        if f[o] < 1.0 && counted(i) {
            v = std::array::from_fn(|k| s[k] + f[o] * (v[k] - s[k]).max(0.0));
            out.set(x, y, v);
        }
        let a = added(v, s) * px.solid_angle(i);
        if a > 0.0 {
            members[o].push((i, a, room(o, v, s)));
        }
    }
    for m in &members {
        let lost: f64 = m
            .iter()
            .map(|&(_, a, g)| a * (1.0 - g.min(1.0)) as f64)
            .sum();
        let open: Vec<&(usize, f64, f32)> = m
            .iter()
            .filter(|&&(i, _, g)| g > 1.0 && open_to(i))
            .collect();
        // The largest uniform raise `l` (each open pixel scaled by min(1 + l, g))
        // that places no more than `lost`, by bisection.
        let placed = |l: f64| -> f64 {
            open.iter()
                .map(|&&(_, a, g)| a * ((1.0 + l).min(g as f64) - 1.0))
                .sum()
        };
        let mut raise = 0.0;
        if lost > 0.0 && !open.is_empty() {
            let top = open
                .iter()
                .map(|&&(_, _, g)| g as f64 - 1.0)
                .filter(|g| g.is_finite())
                .fold(lost / open.iter().map(|p| p.1).sum::<f64>(), f64::max);
            let (mut lo, mut hi) = (0.0, top);
            for _ in 0..40 {
                let mid = 0.5 * (lo + hi);
                if placed(mid) > lost {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            raise = lo;
        }
        for &(i, _, g) in m {
            let t = if g < 1.0 {
                g
            } else if open_to(i) {
                (1.0 + raise as f32).min(g)
            } else {
                1.0
            };
            if t != 1.0 {
                let (x, y) = (i % px.w, i / px.w);
                let (v, s) = (out.get(x, y), linear.get(x, y));
                out.set(
                    x,
                    y,
                    std::array::from_fn(|k| s[k] + t * (v[k] - s[k]).max(0.0)),
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

/// Holds the regions the walk names to the power their neighbours carry to
/// them: each region's added light (every clipped pixel, over what the frame
/// measured) scaled down to that power. Never adds light.
pub(super) fn hold_walk(
    linear: &HdrImage,
    px: &Pixels,
    mends: &[Mend],
    entries: &mut [LedgerEntry],
    out: &mut HdrImage,
) {
    let n = entries.len();
    let mut f = vec![1.0f32; n];
    let mut held = vec![None; n];
    for m in mends {
        let Some(e) = entries.get(m.region) else {
            continue;
        };
        if m.power.is_finite() && m.power >= 0.0 && e.added > m.power {
            f[m.region] = (m.power / e.added) as f32;
            held[m.region] = Some(WalkHeld {
                power: m.power,
                before: e.added,
            });
        }
    }
    if held.iter().all(Option::is_none) {
        return;
    }
    let mut now = vec![0.0f64; n];
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        let (x, y) = (i % px.w, i / px.w);
        let (mut v, s) = (out.get(x, y), linear.get(x, y));
        if f[o] < 1.0 {
            v = std::array::from_fn(|k| s[k] + f[o] * (v[k] - s[k]).max(0.0));
            out.set(x, y, v);
        }
        now[o] += (luminance(v) - luminance(s)).max(0.0) as f64 * px.solid_angle(i);
    }
    for (o, e) in entries.iter_mut().enumerate() {
        if held[o].is_some() {
            e.added = now[o];
            e.walk = held[o];
        }
    }
}
