//! Phases 3-5 of the fusion: each clipped region's power spread over its pixels.
//! A light carried through its surface, or a far source the probes see in the
//! same directions, gives the pixels it covers their radiance; partially clipped
//! pixels keep their measured channels; the rest of the region's power goes to
//! the fully clipped pixels the carried light missed, shaped by the estimate.

use super::edges::carry_with_sharp_edges;
use super::ledger::Hidden;
use super::lights::{NearLight, SkyView};
use super::regions::{Far, Kind, Pixels, Region};
use super::{FusionParams, Measured};
use crate::image::{luminance, HdrImage};
use crate::sphere::sample_px;
use std::collections::HashMap;

/// Reprojected radiance above this multiple of the white point marks a light's
/// core. Measured on kitchen and flat: 2, 4 and 8 give irradiance errors within
/// 0.004 of each other.
const LIGHT_CORE_RATIO: f32 = 2.0;

/// What lights give the region pixels, looked up once.
struct Lookups {
    /// Far-source radiance per covered pixel.
    sky: HashMap<usize, [f32; 3]>,
    /// Radiance carried through a light's surface per pixel.
    carried: HashMap<usize, [f32; 3]>,
}

/// The estimate's light moved onto pixel `i`'s region.
fn shifted(estimate: &HdrImage, px: &Pixels, regions: &[Region], i: usize) -> [f32; 3] {
    let o = px.lab[i] as usize;
    let (x, y) = (i % px.w, i / px.w);
    let s = regions[o].estimate.shift;
    sample_px(estimate, x as f32 + 0.5 + s.0, y as f32 + 0.5 + s.1)
}

/// Phase 3: far sources (sky through a window) the probes see in the region's
/// directions, for regions with no light carried through a surface; used in
/// every region with a fully clipped pixel ([`Far::covers`]).
/// Kept per covered pixel only: regions are a few percent of a panorama.
fn far_sources(
    px: &Pixels,
    regions: &mut [Region],
    sky: Option<&SkyView>,
    hidden: &[Hidden],
    p: &FusionParams,
) -> HashMap<usize, [f32; 3]> {
    let mut sky_rad = HashMap::new();
    let Some(sky) = sky else {
        return sky_rad;
    };
    // Lights hidden from the frame, as balls in the world.
    let hidden: Vec<NearLight> = if p.hidden_not_far {
        hidden
            .iter()
            .map(|h| NearLight {
                position: sky.frame.position + sky.frame.world_from_camera * h.at,
                radius: h.radius,
            })
            .collect()
    } else {
        Vec::new()
    };
    let only = if p.far_overlap > 0.0 {
        overlapping_probes(px, regions, sky, &hidden, p.far_overlap.min(1.0))
    } else {
        Vec::new()
    };
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        if regions[o].placed.view.is_some() || px.kinds[i] == Kind::Margin {
            continue;
        }
        let r = sky.radiance_from(px.dir(i), &hidden, only.get(o).map(Vec::as_slice));
        if let Some(r) = r {
            sky_rad.insert(i, r);
        }
        if px.kinds[i] == Kind::Full {
            let a = px.solid_angle(i);
            regions[o].far.cover.1 += a;
            if r.is_some() {
                regions[o].far.cover.0 += a;
            }
        }
    }
    for r in regions.iter_mut() {
        r.far.ok = Far::covers(r.far.cover);
    }
    // The median (by luminance) of each region's covered pixels: the least the
    // others get (a mean would spread a sun's core over them).
    let mut per: Vec<Vec<[f32; 3]>> = vec![Vec::new(); regions.len()];
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        if px.kinds[i] == Kind::Full && regions[o].far.ok {
            if let Some(&r) = sky_rad.get(&i) {
                per[o].push(r);
            }
        }
    }
    for (o, v) in per.iter_mut().enumerate() {
        if !v.is_empty() {
            let mid = v.len() / 2;
            v.select_nth_unstable_by(mid, |a, b| luminance(*a).total_cmp(&luminance(*b)));
            regions[o].far.median = Some(v[mid]);
        }
    }
    sky_rad
}

impl Lookups {
    /// The radiance a region's light gives pixel `i`: through its surface, or
    /// from the far source where the probes cover it (radiance at infinity depends
    /// on the direction only), also where a placed light shares the region: the
    /// region then holds the larger of the two, since the lights' power goes to
    /// the pixels the far source leaves. Chosen on the development scenes
    /// (irradiance error mean 0.259 -> 0.243, p95 0.664 -> 0.648; s0020's sky
    /// 0.274 -> 0.080); validation 0.142 -> 0.141, p95 0.334 -> 0.332.
    fn light(&self, regions: &[Region], o: usize, i: usize) -> Option<[f32; 3]> {
        let r = &regions[o];
        if r.placed.view.is_some() {
            return self.carried.get(&i).copied();
        }
        if !r.far.ok {
            return None;
        }
        self.sky.get(&i).copied()
    }

    /// The shape of a region's fill at pixel `i`: a placed light with no surface
    /// keeps its power, but a far source the probes see in the same direction
    /// gives it its shape; else the shifted estimate.
    fn shape(
        &self,
        estimate: &HdrImage,
        px: &Pixels,
        regions: &[Region],
        i: usize,
        white: f32,
    ) -> [f32; 3] {
        let r = &regions[px.lab[i] as usize];
        match self.sky.get(&i).copied() {
            Some(s) if r.far.ok && r.placed.any => s,
            _ if r.placed.any
                && r.placed.view.is_none()
                && !r.placed.broad
                && !r.placed.discs.is_empty() =>
            {
                // The placed lights' discs where they point, in the estimate's
                // colour: the estimate's light may sit elsewhere in a region that
                // holds a lamp and the wall it lights.
                let d = px.dir(i);
                let l: f32 = r
                    .placed
                    .discs
                    .iter()
                    .filter(|c| c.norm > 0.0)
                    .map(|c| c.power * c.weight(d) / c.norm)
                    .sum();
                let e = shifted(estimate, px, regions, i);
                let le = luminance(e);
                let t = white + l;
                if le > 1e-12 {
                    [e[0] * t / le, e[1] * t / le, e[2] * t / le]
                } else {
                    [t; 3]
                }
            }
            _ => shifted(estimate, px, regions, i),
        }
    }
}

/// The measured channel of partially clipped codes `c` with the highest radiance
/// in `s` (0 when none is measured).
fn brightest_measured(frame: &Measured, c: &[u8], s: [f32; 3]) -> usize {
    (0..3)
        .filter(|&k| !frame.censor.clipped(c[k]))
        .max_by(|&a, &b| s[a].total_cmp(&s[b]))
        .unwrap_or(0)
}

/// Least width of the ring around a clipped region over which a probe's
/// bright area is compared with the frame's clipped pixels
/// ([`overlapping_probes`]).
const RING_DEG: f32 = 5.0;

/// Widest grid [`overlapping_probes`] compares on.
const OVERLAP_GRID_W: usize = 256;

/// Per region, the probes whose far lookups count
/// ([`FusionParams::far_overlap`]): those whose bright area (the samples the
/// far lookup would take, [`SkyView::bright`]) in the region's directions and
/// a ring around it overlaps the frame's clipped pixels, as intersection over
/// union of solid angle, at least `frac` times as well as the best probe's. A
/// far source is where every probe that sees it sees it, in the same
/// directions; a probe whose bright area there is elsewhere (a sunlit patch of
/// floor seen from another place) sees another thing. A region no probe's
/// bright area meets, or too small to hold a point of the grid, keeps them
/// all. The ring is [`RING_DEG`] rounded up to whole grid steps (8-connected,
/// so wider on the diagonals), counted in pixels of the 2:1 grid.
fn overlapping_probes(
    px: &Pixels,
    regions: &[Region],
    sky: &SkyView,
    hidden: &[NearLight],
    frac: f32,
) -> Vec<Vec<bool>> {
    let (n, m) = (regions.len(), sky.probes.len());
    // On a grid at most OVERLAP_GRID_W wide (every `s`-th pixel each way): the
    // overlap is a coarse statistic, and a large panorama would sample every
    // probe at millions of pixels.
    let s = px.w.div_ceil(OVERLAP_GRID_W).max(1);
    let (cw, ch) = (px.w.div_ceil(s), px.h.div_ceil(s));
    let full = |c: usize| (c / cw) * s * px.w + (c % cw) * s;
    let lab: Vec<u32> = (0..cw * ch).map(|c| px.lab[full(c)]).collect();
    // Each grid point within the ring takes the label of a region it reaches
    // (breadth first, 8-connected, wrapping across the seam).
    let steps = (RING_DEG * cw as f32 / 360.0).ceil().max(1.0) as usize;
    let mut near = lab.clone();
    let mut frontier: Vec<usize> = (0..cw * ch).filter(|&c| lab[c] != u32::MAX).collect();
    for _ in 0..steps {
        let mut next = Vec::new();
        for &c in &frontier {
            let (x, y) = ((c % cw) as i64, (c / cw) as i64);
            for dy in -1..=1i64 {
                let yy = y + dy;
                if yy < 0 || yy >= ch as i64 {
                    continue;
                }
                for dx in -1..=1i64 {
                    let xx = (x + dx).rem_euclid(cw as i64);
                    let k = yy as usize * cw + xx as usize;
                    if near[k] == u32::MAX {
                        near[k] = near[c];
                        next.push(k);
                    }
                }
            }
        }
        frontier = next;
    }
    let mut inter = vec![vec![0.0f64; m]; n];
    let mut union = vec![vec![0.0f64; m]; n];
    for (c, &l) in near.iter().enumerate() {
        if l == u32::MAX || regions[l as usize].placed.view.is_some() {
            continue;
        }
        let (o, i) = (l as usize, full(c));
        let clipped = lab[c] == l && px.kinds[i] != Kind::Margin;
        let (a, d) = (px.solid_angle(i), px.dir(i));
        for j in 0..m {
            let bright = sky.bright(j, d, hidden);
            if clipped && bright {
                inter[o][j] += a;
            }
            if clipped || bright {
                union[o][j] += a;
            }
        }
    }
    (0..n)
        .map(|o| {
            let iou: Vec<f64> = (0..m)
                .map(|j| {
                    if union[o][j] > 0.0 {
                        inter[o][j] / union[o][j]
                    } else {
                        0.0
                    }
                })
                .collect();
            let best = iou.iter().copied().fold(0.0, f64::max);
            iou.iter()
                .map(|&v| best == 0.0 || v >= frac as f64 * best)
                .collect()
        })
        .collect()
}

/// Phase 4a: per region and (clipped, measured) channel pair, the estimate's colour
/// ratio: the median over the region's partially clipped pixels where the shifted
/// estimate is bright in the clipped channel. A sunlit wall or a warm lamp has one
/// colour, and an estimate a few pixels off mixes in its darker, differently
/// coloured surroundings (a shadow lit by blue sky), which per-pixel ratios would
/// copy. Measured on the evaluation scenes: flat +0.57 dB, log RMSE 0.0871 ->
/// 0.0848; kitchen and outdoor unchanged to slightly better.
fn colour_ratios(frame: &Measured, estimate: &HdrImage, px: &Pixels, regions: &mut [Region]) {
    let white = frame.white;
    let mut samples: Vec<[[Vec<f32>; 3]; 3]> =
        (0..regions.len()).map(|_| Default::default()).collect();
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        if px.kinds[i] != Kind::Partial {
            continue;
        }
        let e = shifted(estimate, px, regions, i);
        for k in 0..3 {
            for r in 0..3 {
                if k != r && e[k] > white && e[r] > 1e-12 && e[k].is_finite() {
                    samples[o][k][r].push(e[k] / e[r]);
                }
            }
        }
    }
    for (o, rr) in samples.iter_mut().enumerate() {
        for k in 0..3 {
            for r in 0..3 {
                let v = &mut rr[k][r];
                if !v.is_empty() {
                    let mid = v.len() / 2;
                    let (_, m, _) = v.select_nth_unstable_by(mid, f32::total_cmp);
                    regions[o].fill.ratio[k][r] = Some(*m);
                }
            }
        }
    }
}

/// Phase 4b: partially clipped pixels. The measured channels are kept; each
/// clipped channel follows the colour of the light carried there, or of the
/// estimate (its region's ratio to the brightest measured channel), never below
/// the clipped value. Margin pixels stay as measured.
fn fill_partial(
    frame: &Measured,
    estimate: &HdrImage,
    px: &Pixels,
    regions: &mut [Region],
    look: &Lookups,
    out: &mut HdrImage,
) {
    let white = frame.white;
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        if px.kinds[i] != Kind::Partial {
            continue;
        }
        let (x, y) = (i % px.w, i / px.w);
        let c = &frame.codes.data()[3 * i..3 * i + 3];
        let s = frame.radiance.get(x, y);
        let r = brightest_measured(frame, c, s);
        let mut v = s;
        // A light carried through its surface gives the clipped channels directly.
        match look.light(regions, o, i) {
            Some(rad) if rad[r] > 1e-12 => {
                // Inside a light's core, JPEG's chroma subsampling bleeds the clipped
                // channels into the others: a pixel coded (249, 255, 255) can be a
                // lamp at 200x white. There, bled channels are not measurements and
                // the probes' radiance is taken as it is; elsewhere (a light's glow)
                // the clipped channels follow the probes' colour from the brightest
                // measured one.
                let core = luminance(rad) > LIGHT_CORE_RATIO * white;
                for k in 0..3 {
                    if core && frame.censor.bleeds(c[k]) {
                        v[k] = rad[k].max(s[k]);
                    } else if frame.censor.clipped(c[k]) {
                        v[k] = (s[r] * rad[k] / rad[r]).max(s[k]);
                    }
                }
            }
            _ => {
                let e = shifted(estimate, px, regions, i);
                for k in 0..3 {
                    if frame.censor.clipped(c[k]) && e[r] > 1e-12 && e[k].is_finite() {
                        let q = regions[o].fill.ratio[k][r].unwrap_or(e[k] / e[r]);
                        v[k] = (s[r] * q).max(s[k]);
                    }
                }
            }
        }
        regions[o].fill.partial += (luminance(v) as f64 - white as f64).max(0.0) * px.sa[y] as f64;
        out.set(x, y, v);
    }
}

/// Phase 4c: a region with light left to place but no fully clipped pixel (a
/// light every pixel of which kept a channel, e.g. through JPEG chroma bleeding)
/// places it in its partially clipped pixels where the shifted estimate is bright
/// (all of them if none is), so the light is not lost. Such a promoted pixel keeps
/// its measured channels ([`keep_measured`]): a sunlit wall clipped in red only
/// must not take the light's colour; the part of the light those channels would
/// have held is dropped, since the frame measured that it is not there (with
/// [`FusionParams::measured_bound`], the light itself is scaled down until
/// those channels could have measured it).
fn promote(
    frame: &Measured,
    estimate: &HdrImage,
    px: &mut Pixels,
    regions: &mut [Region],
    out: &HdrImage,
    look: &Lookups,
    p: &FusionParams,
) -> Vec<bool> {
    let white = frame.white;
    let under = if p.censored_lights {
        promote_under_discs(frame, px, regions, out, look)
    } else {
        Vec::new()
    };
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        match px.kinds[i] {
            Kind::Full => regions[o].fill.has_full = true,
            Kind::Partial if luminance(shifted(estimate, px, regions, i)) > white => {
                regions[o].fill.has_bright_partial = true
            }
            _ => {}
        }
    }
    for r in regions.iter_mut() {
        r.fill.promote = !r.fill.has_full && r.fill.target > 1.05 * r.fill.partial;
    }
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        let f = &regions[o].fill;
        if px.kinds[i] == Kind::Partial
            && f.promote
            && (!f.has_bright_partial || luminance(shifted(estimate, px, regions, i)) > white)
        {
            px.kinds[i] = Kind::Full;
            // What the pixel carried as a partial pixel (its value in `out`).
            let v = out.get(i % px.w, i / px.w);
            regions[o].fill.partial -=
                (luminance(v) as f64 - white as f64).max(0.0) * px.solid_angle(i);
        }
        if px.kinds[i] == Kind::Full {
            regions[o].fill.full_area += px.solid_angle(i);
        }
    }
    under
}

/// Partly clipped pixels that measured nothing (every channel bleeds) under a
/// region's compact placed light become fully clipped, so the light's power can
/// land on them ([`FusionParams::censored_lights`]); a pixel a light's surface
/// is carried into above the white point shows that surface, not the light.
/// Returns the pixels under a light (empty when the setting is off).
fn promote_under_discs(
    frame: &Measured,
    px: &mut Pixels,
    regions: &mut [Region],
    out: &HdrImage,
    look: &Lookups,
) -> Vec<bool> {
    let white = frame.white;
    let mut under = vec![false; px.w * px.h];
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        let r = &regions[o];
        if !matches!(px.kinds[i], Kind::Partial | Kind::Full) || r.placed.discs.is_empty() {
            continue;
        }
        if !frame.measured_nothing(i) {
            continue;
        }
        if matches!(look.light(regions, o, i), Some(c) if luminance(c) > white) {
            continue;
        }
        let d = px.dir(i);
        let pixel = (px.solid_angle(i) as f32).sqrt();
        let on = r
            .placed
            .discs
            .iter()
            .any(|c| c.dir.dot(d).clamp(-1.0, 1.0).acos() <= c.radius + pixel);
        if !on {
            continue;
        }
        under[i] = true;
        regions[o].fill.under_light += px.solid_angle(i);
        if px.kinds[i] == Kind::Partial {
            px.kinds[i] = Kind::Full;
            let v = out.get(i % px.w, i / px.w);
            regions[o].fill.partial -=
                (luminance(v) as f64 - white as f64).max(0.0) * px.solid_angle(i);
        }
    }
    under
}

/// A promoted pixel's channels that are measurements (below the bleed code) stay
/// as measured. Only promoted pixels have such channels: the other fully clipped
/// pixels clipped in every channel.
///
/// With `bound` ([`FusionParams::measured_bound`]) a measured channel also
/// bounds the light written there: it recorded less than the clip radiance
/// `white`, so a light of `v`'s colour that would put more than that in it is
/// not at this pixel at that strength, and `v` is scaled down until no measured
/// channel passes `white` (never below what the frame measured). A lamp's
/// mirror image that a probe sees on a floor the frame also sees, unlit, must
/// not land there with the lamp's colour: the frame's blue said otherwise.
fn keep_measured(frame: &Measured, v: &mut [f32; 3], i: usize, bound: bool) {
    let w = frame.codes.width();
    let s = frame.radiance.get(i % w, i / w);
    let codes = &frame.codes.data()[3 * i..3 * i + 3];
    // A pixel with a channel at the top code is left alone
    // ([`Measured::bounds_light`]).
    if bound && frame.bounds_light(i) {
        let g = (0..3)
            .filter(|&k| !frame.censor.bleeds(codes[k]) && v[k] > frame.white)
            .map(|k| frame.white / v[k])
            .fold(1.0f32, f32::min);
        if g < 1.0 {
            for k in 0..3 {
                v[k] = (v[k] * g).max(s[k]);
            }
        }
    }
    for k in 0..3 {
        if !frame.censor.bleeds(codes[k]) {
            v[k] = s[k];
        }
    }
}

/// Phase 5: fully clipped pixels. A light carried pixel by pixel gives the
/// probes' radiance of the same surface point (never below the white point the
/// frame saw it clip at); the pixels it does not cover receive the rest of the
/// region's power: the white point plus the shape's excess, rescaled to that
/// power, spread evenly when the shape misses them, and bounded by `missed_cap`;
/// the compact lights' share (`lamp_rest`) goes evenly to the pixels under them
/// first, and what the capped pixels could not take raises the carried ones
/// ([`top_up_carried`]). A region with no fully clipped pixel keeps what its
/// partial pixels carry.
fn fill_full(
    frame: &Measured,
    estimate: &HdrImage,
    px: &Pixels,
    regions: &mut [Region],
    look: &Lookups,
    under: &[bool],
    p: &FusionParams,
    out: &mut HdrImage,
) {
    let white = frame.white;
    // The most radiance above white a pixel of a light carried through its surface
    // can hold: the brightest a probe saw in the light or the lookup carries into
    // the region (radiance is invariant along rays). Without that bound, a
    // region's rest landing on a few missed pixels made them 20x too bright (flat,
    // frame 16). No bound elsewhere: a far source's covered part need not hold its
    // sun.
    for r in regions.iter_mut() {
        r.fill.missed_cap =
            (r.placed.view.is_some() && r.placed.peak > 0.0).then_some(r.placed.peak);
    }
    // Each disc's weight over the pixels that share the region's power.
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        if px.kinds[i] != Kind::Full
            || regions[o].placed.discs.is_empty()
            || regions[o].placed.broad
        {
            continue;
        }
        if matches!(look.light(regions, o, i), Some(r) if luminance(r) > white) {
            continue;
        }
        let (d, a) = (px.dir(i), px.solid_angle(i) as f32);
        for c in regions[o].placed.discs.iter_mut() {
            c.norm += c.weight(d) * a;
        }
    }
    let mut full_radiance: HashMap<usize, [f32; 3]> = HashMap::new();
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        if px.kinds[i] != Kind::Full {
            continue;
        }
        let a = px.solid_angle(i);
        // A carried radiance at or below the white point contradicts the frame,
        // which saw the pixel clip: the surface lookup missed the light there (a
        // pose or placement error, larger for a frame far from the probes), so the
        // pixel takes a share of the region's remaining power instead.
        match look.light(regions, o, i) {
            Some(r) if luminance(r) > white => {
                full_radiance.insert(i, r);
                let e = luminance(r) as f64 - white as f64;
                let f = &mut regions[o].fill;
                f.carried += e * a;
                if let Some(c) = &mut f.missed_cap {
                    *c = c.max(e);
                }
            }
            _ => {
                let e = look.shape(estimate, px, regions, i, white);
                let f = &mut regions[o].fill;
                f.inside += (luminance(e) as f64 - white as f64).max(0.0) * a;
                f.missed_area += a;
            }
        }
    }
    for r in regions.iter_mut() {
        // A light placed at infinity has a power the probes measured; a region
        // without one has only the estimate's, which the far lookup overrules.
        let measured = r.placed.any && r.placed.view.is_none();
        let f = &mut r.fill;
        f.rest = (f.target - f.partial - f.carried).max(0.0);
        // Energy kept: with no pixel left to take the rest of a measured light's
        // power, the carried pixels do. Where the power is only the estimate's
        // (its transport may miscount a window's extent), the far lookup that
        // covers every fully clipped pixel is the evidence and the rest is
        // dropped (flat, frame 6: 1.39 estimated, 0.77 looked up, 0.77 true).
        f.carried_gain = if measured && f.missed_area == 0.0 && f.carried > 0.0 {
            1.0 + f.rest / f.carried
        } else {
            1.0
        };
        // Where the region's shape is not its discs' (a surface carried, a broad
        // source), the compact lights' power goes to the pixels under them.
        f.lamp_rest = if f.under_light > 0.0 && (r.placed.view.is_some() || r.placed.broad) {
            let discs: f64 = r.placed.discs.iter().map(|c| c.power as f64).sum();
            discs.min(f.rest)
        } else {
            0.0
        };
    }
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        if px.kinds[i] != Kind::Full {
            continue;
        }
        let (x, y) = (i % px.w, i / px.w);
        let s = frame.radiance.get(x, y);
        if let Some(&r) = full_radiance.get(&i) {
            let lr = luminance(r).max(0.0);
            let (colour, lc) = if lr > 1e-12 {
                (r, lr)
            } else {
                (s, luminance(s).max(1e-12))
            };
            let gain = regions[o].fill.carried_gain as f32;
            let target = white + (lr - white).max(0.0) * gain;
            let mut v = [0.0f32; 3];
            for k in 0..3 {
                v[k] = (colour[k] * target / lc).max(s[k]);
            }
            keep_measured(frame, &mut v, i, p.measured_bound);
            out.set(x, y, v);
            continue;
        }
        let reg = &regions[o];
        let e = look.shape(estimate, px, regions, i, white);
        let le = luminance(e).max(0.0);
        let excess = (le - white).max(0.0) as f64;
        let f = &reg.fill;
        let rest = f.rest - f.lamp_rest;
        let lamp = if f.lamp_rest > 0.0 && under.get(i) == Some(&true) {
            f.lamp_rest / f.under_light
        } else {
            0.0
        };
        let add = lamp
            + if f.inside > 0.0 {
                excess * rest / f.inside
            } else if f.full_area > 0.0 {
                rest / f.full_area
            } else {
                0.0
            };
        let target = white as f64 + f.missed_cap.map_or(add, |c| add.min(c));
        // Colour from the estimate where it has one, else from the SDR pixel.
        let colour = if le > 1e-12 { e } else { s };
        let lc = luminance(colour).max(1e-12) as f64;
        let mut v = [0.0f32; 3];
        for k in 0..3 {
            // Never below what the SDR frame measured (clipping only lowers values).
            v[k] = ((colour[k] as f64 * target / lc) as f32).max(s[k]);
        }
        // A far source's pixels the probes do not cover are at least as bright as
        // its median, also where a placed light shares the region (a window's
        // aperture triangulated as a light: shared flat frame 3 held 2.39 units
        // where the truth is 6.1, 4.18 with the floor). Development 0.2018 ->
        // 0.1999, validation 0.1319 -> 0.1316, shared unchanged.
        if let (Some(m), true) = (reg.far.median, reg.far.ok) {
            if luminance(m) > luminance(v) {
                v = m;
            }
        }
        keep_measured(frame, &mut v, i, p.measured_bound);
        out.set(x, y, v);
        regions[o].fill.missed_placed +=
            (luminance(v) as f64 - white as f64).max(0.0) * px.solid_angle(i);
    }
    if p.fill_to_peak {
        top_up_carried(frame, px, regions, &full_radiance, p.measured_bound, out);
    }
}

/// A region whose missed pixels could not take its rest (each at most
/// `missed_cap`, the region's placed lights' largest peak) raises its carried
/// pixels toward that cap, evenly in the room each has, until the rest is
/// placed or every pixel is at the cap ([`FusionParams::fill_to_peak`]).
/// Only where the light's own direction fell in the region: a light moved
/// into it is less sure of its power than the surface lookup.
fn top_up_carried(
    frame: &Measured,
    px: &Pixels,
    regions: &mut [Region],
    full_radiance: &HashMap<usize, [f32; 3]>,
    bound: bool,
    out: &mut HdrImage,
) {
    let white = frame.white as f64;
    let excess =
        |r: &Region, c: [f32; 3]| (luminance(c) as f64 - white).max(0.0) * r.fill.carried_gain;
    // In pixel order, so the sums (and the output) do not depend on the
    // map's iteration order, which changes from process to process.
    let mut order: Vec<(usize, [f32; 3])> = full_radiance.iter().map(|(&i, &c)| (i, c)).collect();
    order.sort_unstable_by_key(|&(i, _)| i);
    let mut room = vec![0.0f64; regions.len()];
    for &(i, c) in &order {
        let o = px.lab[i] as usize;
        let r = &regions[o];
        if let (Some(cap), false) = (r.fill.missed_cap, r.placed.view_moved) {
            room[o] += (cap - excess(r, c)).max(0.0) * px.solid_angle(i);
        }
    }
    for &(i, c) in &order {
        let o = px.lab[i] as usize;
        let r = &regions[o];
        let (Some(cap), true, false) = (r.fill.missed_cap, room[o] > 0.0, r.placed.view_moved)
        else {
            continue;
        };
        let short = r.fill.rest - r.fill.missed_placed;
        if short <= 0.0 {
            continue;
        }
        let g = (short / room[o]).min(1.0);
        let e = excess(r, c);
        let lc = (luminance(c) as f64).max(1e-12);
        let target = white + e + g * (cap - e).max(0.0);
        let (x, y) = (i % px.w, i / px.w);
        let s = frame.radiance.get(x, y);
        let mut v = [0.0f32; 3];
        for k in 0..3 {
            v[k] = ((c[k] as f64 * target / lc) as f32).max(s[k]);
        }
        keep_measured(frame, &mut v, i, bound);
        out.set(x, y, v);
    }
}

/// The most the lookups can give each region, from the probes alone (before
/// any pixel is written), for the ledger: the power carried through a light's
/// surface into its clipped pixels, and for a far source (sky or sun through an
/// aperture) its looked-up radiance where the lookup covers the clipped pixels,
/// and the covered ones' mean in the fully clipped pixels it does not cover.
fn book(px: &Pixels, regions: &mut [Region], look: &Lookups, white: f32) {
    let excess = |r: [f32; 3]| (luminance(r) as f64 - white as f64).max(0.0);
    // Solid angle of the fully clipped pixels the lookup covers, and of those
    // it does not.
    let mut covered = vec![0.0f64; regions.len()];
    let mut uncovered = vec![0.0f64; regions.len()];
    for i in 0..px.w * px.h {
        let Some(o) = px.region(i) else { continue };
        let k = match px.kinds[i] {
            Kind::Margin => continue,
            Kind::Full => 0,
            Kind::Partial => 1,
        };
        let a = px.solid_angle(i);
        let r = &mut regions[o];
        if r.placed.view.is_some() {
            if let Some(&c) = look.carried.get(&i) {
                r.booked.carried[k] += excess(c) * a;
            }
        } else if r.far.ok {
            match look.sky.get(&i) {
                Some(&s) => {
                    r.booked.far[k] += excess(s) * a;
                    r.booked.far_covered[k] += excess(s) * a;
                    if k == 0 {
                        covered[o] += a;
                    }
                }
                None if k == 0 => uncovered[o] += a,
                None => {}
            }
        }
    }
    // The uncovered ones at the covered ones' mean radiance.
    for (o, r) in regions.iter_mut().enumerate() {
        if covered[o] > 0.0 {
            r.booked.far[0] *= 1.0 + uncovered[o] / covered[o];
        }
    }
}

/// Phases 3-5 over the regions, writing `out` (the linearised frame on entry);
/// each region's `fill.filled` is the power above white it holds in the end.
pub(super) fn fill(
    frame: &Measured,
    estimate: &HdrImage,
    px: &mut Pixels,
    regions: &mut [Region],
    sky: Option<&SkyView>,
    hidden: &[Hidden],
    p: &FusionParams,
    out: &mut HdrImage,
) {
    let sky_rad = far_sources(px, regions, sky, hidden, p);
    let look = Lookups {
        sky: sky_rad,
        carried: carry_with_sharp_edges(px, regions, frame.white),
    };
    book(px, regions, &look, frame.white);
    colour_ratios(frame, estimate, px, regions);
    fill_partial(frame, estimate, px, regions, &look, out);
    let under = promote(frame, estimate, px, regions, out, &look, p);
    fill_full(frame, estimate, px, regions, &look, &under, p, out);
    held(px, regions, frame.white, out);
}

/// Each region's `fill.filled`: the power above `white` its pixels hold in `out`.
pub(super) fn held(px: &Pixels, regions: &mut [Region], white: f32, out: &HdrImage) {
    for r in regions.iter_mut() {
        r.fill.filled = 0.0;
    }
    for (i, &l) in px.lab.iter().enumerate() {
        if l != u32::MAX {
            regions[l as usize].fill.filled +=
                (luminance(out.get(i % px.w, i / px.w)) as f64 - white as f64).max(0.0)
                    * px.solid_angle(i);
        }
    }
}
