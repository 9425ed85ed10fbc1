//! Phase 1 of the fusion: the frame's clipped regions, what the frame measured at
//! each of their pixels, and the estimate's light attributed to each region.

use super::lights::LightView;
use super::{clip_mask, components, FusionParams, Measured};
use crate::image::{luminance, HdrImage};
use crate::sphere::{pixel_to_dir, row_solid_angles};
use glam::Vec3;

/// What the frame measured at a pixel of a clipped region: every channel clipped
/// (nothing measured: the light is placed here), some channels clipped (the others
/// are measurements), or none (a margin pixel, kept as measured).
#[derive(Clone, Copy, PartialEq, Debug)]
pub(super) enum Kind {
    Full,
    Partial,
    Margin,
}

/// The frame's pixels as the fusion sees them.
pub(super) struct Pixels {
    pub w: usize,
    pub h: usize,
    /// Region of each pixel (`u32::MAX`: measured, outside every region).
    pub lab: Vec<u32>,
    /// Clipped pixels, before the margin.
    pub core: Vec<bool>,
    /// `core` grown by the margin: the pixels the fusion may change.
    pub mask: Vec<bool>,
    /// What the frame measured at each pixel (promoted pixels become `Full`).
    pub kinds: Vec<Kind>,
    /// Solid angle of a pixel of each row.
    pub sa: Vec<f32>,
}

impl Pixels {
    /// Direction of pixel `i` (the frame's camera axes).
    pub fn dir(&self, i: usize) -> Vec3 {
        pixel_to_dir(i % self.w, i / self.w, self.w, self.h)
    }

    /// Region of pixel `i`, if any.
    #[inline]
    pub fn region(&self, i: usize) -> Option<usize> {
        (self.lab[i] != u32::MAX).then_some(self.lab[i] as usize)
    }

    /// Solid angle of pixel `i`.
    #[inline]
    pub fn solid_angle(&self, i: usize) -> f64 {
        self.sa[i / self.w] as f64
    }
}

/// The estimate's light above the white point attributed to one region.
#[derive(Clone, Debug, Default)]
pub(super) struct EstimateLight {
    /// Power (luminance above the white point x solid angle).
    pub power: f64,
    /// Brightest luminance above the white point.
    pub peak: f64,
    /// Solid angle.
    pub area: f64,
    /// How far the estimate has the light from the region, in pixels (columns,
    /// rows): shape against shape, not power-weighted (a lamp brighter on one side
    /// would move though the estimate had it in place).
    pub shift: (f32, f32),
}

/// Lights placed in 3-D ([`super::lights`]) that fall in one region.
#[derive(Clone, Debug, Default)]
pub(super) struct Placed<'v> {
    /// True when some placed light falls in the region.
    pub any: bool,
    /// Their power at the frame.
    pub power: f64,
    /// Largest mean radiance above the white point a probe saw in them.
    pub radiance: f64,
    /// Brightest radiance above the white point a probe saw in them.
    pub peak: f64,
    /// The strongest of them that can be carried pixel by pixel through its
    /// surface, with its power.
    pub view: Option<(f64, &'v LightView<'v>)>,
    /// That light fell outside the region and was moved into it.
    pub view_moved: bool,
    /// Each of them as a disc in the frame: where its power lands when it has no
    /// surface to be carried through.
    pub discs: Vec<Disc>,
    /// True when one of them is not compact against the region (no disc shape).
    pub broad: bool,
}

/// A placed light seen as a disc: its direction (unit, camera axes), its angular
/// radius (radians) and its power, spread over the region's pixels by its weight.
#[derive(Clone, Copy, Debug)]
pub(super) struct Disc {
    pub dir: glam::Vec3,
    pub radius: f32,
    /// Its power at the frame.
    pub power: f32,
    /// The sum of its weight times solid angle over the region's fully clipped
    /// pixels that take a share of the power (set by the fill).
    pub norm: f32,
}

impl Disc {
    /// The disc's weight in direction `d` (unit): a point spread with the
    /// disc's radius as its scale and a tail falling as the fourth power of the
    /// angle, so the nearest pixels of a region take the power of a light placed
    /// a few pixels off it, and a light placed beside a region (moved into it)
    /// gives most to the pixels nearest to it.
    pub fn weight(&self, d: glam::Vec3) -> f32 {
        let chord = (d - self.dir).length();
        let t = 2.0 * (0.5 * chord).min(1.0).asin() / self.radius;
        let q = 1.0 + t * t;
        1.0 / (q * q)
    }
}

/// Far sources the other probes see in the region's directions (sky through a
/// window).
#[derive(Clone, Debug, Default)]
pub(super) struct Far {
    /// Solid angle of fully clipped pixels the lookup covers, and of all of them.
    pub cover: (f64, f64),
    /// True when the lookup is used in the region: it has a fully clipped
    /// pixel ([`Far::covers`]).
    pub ok: bool,
    /// Median (by luminance) of the covered pixels' radiance.
    pub median: Option<[f32; 3]>,
}

impl Far {
    /// Whether the far lookup (covering `cover.0` of the region's `cover.1`
    /// solid angle of fully clipped pixels) is used in the region: in every
    /// region with a fully clipped pixel. A far source the probes see in some
    /// of a region's directions is evidence there, however little of the
    /// region it covers (its partly clipped pixels included); the rest of the
    /// region is booked at the covered pixels' mean and filled at least to
    /// their median. Requiring a share of the region lost on development:
    /// 0.1479, 0.1466, 0.1440 with 0.3, 0.2, 0.1 against 0.1410 with none.
    pub fn covers(cover: (f64, f64)) -> bool {
        cover.1 > 0.0
    }
}

/// How the region's light is spread over its pixels.
#[derive(Clone, Debug, Default)]
pub(super) struct Fill {
    /// Power the region receives.
    pub target: f64,
    /// Per (clipped channel, measured channel): the estimate's colour ratio.
    pub ratio: [[Option<f32>; 3]; 3],
    /// Power above white in its partially clipped pixels.
    pub partial: f64,
    /// Some pixel clipped in every channel.
    pub has_full: bool,
    /// Some partially clipped pixel where the shifted estimate is above white.
    pub has_bright_partial: bool,
    /// Partial pixels are promoted to fully clipped (the region had none).
    pub promote: bool,
    /// Solid angle of its fully clipped pixels.
    pub full_area: f64,
    /// Shifted estimate's excess over its fully clipped pixels not carried.
    pub inside: f64,
    /// Power carried pixel by pixel into fully clipped pixels.
    pub carried: f64,
    /// Most radiance above white a pixel not carried may hold.
    pub missed_cap: Option<f64>,
    /// Power left for the pixels not carried.
    pub rest: f64,
    /// Power above white its missed pixels hold after the fill.
    pub missed_placed: f64,
    /// Solid angle of its fully clipped pixels not carried.
    pub missed_area: f64,
    /// Solid angle of its pixels under a compact placed light that measured
    /// nothing ([`super::FusionParams::censored_lights`]).
    pub under_light: f64,
    /// The compact lights' power those pixels take where the region's shape
    /// is not the lights' discs.
    pub lamp_rest: f64,
    /// Factor on the carried pixels' excess over white: above 1 when every fully
    /// clipped pixel was carried and power is left, so the power is kept.
    pub carried_gain: f64,
    /// Power above the white point it holds in the end.
    pub filled: f64,
}

/// One clipped region of the frame (a connected set of clipped pixels, grown by
/// the margin) and everything the fusion learns about it, phase by phase.
#[derive(Clone, Debug, Default)]
pub(super) struct Region<'v> {
    /// Pixels.
    pub pixels: usize,
    /// Solid angle.
    pub area: f64,
    /// Solid angle of its clipped pixels (before the margin).
    pub core_area: f64,
    /// Column of its first pixel: centroids are taken relative to it, so a region
    /// across the seam averages correctly.
    pub reference: usize,
    /// Centroid (columns relative to `reference`, rows).
    pub centroid: (f64, f64),
    /// Solid-angle-weighted sum of its directions.
    pub dir: Vec3,
    /// Phase 1: the estimate's light.
    pub estimate: EstimateLight,
    /// Phase 2: lights placed in 3-D.
    pub placed: Placed<'v>,
    /// Phase 3: far sources.
    pub far: Far,
    /// Phases 2-5: the fill.
    pub fill: Fill,
    /// Phase 3: what the probes' lookups give it, for the ledger.
    pub booked: super::ledger::Booked,
}

impl Region<'_> {
    /// Centre (column, row) in pixels of a `w`-wide frame.
    pub fn centre(&self, w: usize) -> (f32, f32) {
        (
            ((self.centroid.0 + self.reference as f64).rem_euclid(w as f64)) as f32,
            self.centroid.1 as f32,
        )
    }
}

/// Signed column offset of `x` from `r` in a `w`-wide panorama (shortest way).
fn rel_x(x: usize, r: usize, w: usize) -> f64 {
    let d = (x as i64 - r as i64).rem_euclid(w as i64);
    (if d > (w / 2) as i64 { d - w as i64 } else { d }) as f64
}

/// The frame's clipped regions and their pixels, and the estimate's light
/// attributed to each: each connected region of the estimate above the white
/// point goes to the clipped region nearest in direction, within
/// `max_angle_deg`.
pub(super) fn find<'v>(
    frame: &Measured,
    estimate: &HdrImage,
    p: &FusionParams,
) -> (Pixels, Vec<Region<'v>>) {
    let (sdr, white) = (frame.codes, frame.white);
    let (w, h) = (sdr.width(), sdr.height());
    let core = clip_mask(sdr, &frame.censor, 0);
    let mask = clip_mask(sdr, &frame.censor, p.margin_px);
    let (lab, n) = components(&mask, w, h);
    let kinds: Vec<Kind> = sdr
        .data()
        .chunks_exact(3)
        .map(|c| match frame.censor.clipped_channels(c) {
            3 => Kind::Full,
            0 => Kind::Margin,
            _ => Kind::Partial,
        })
        .collect();
    let px = Pixels {
        w,
        h,
        lab,
        core,
        mask,
        kinds,
        sa: row_solid_angles(w, h),
    };
    let mut regions: Vec<Region> = vec![Region::default(); n];
    let mut has_reference = vec![false; n];
    for (i, &l) in px.lab.iter().enumerate() {
        if l != u32::MAX && !has_reference[l as usize] {
            has_reference[l as usize] = true;
            regions[l as usize].reference = i % w;
        }
    }
    let bright: Vec<bool> = (0..w * h)
        .map(|i| luminance(estimate.get(i % w, i / w)) > white)
        .collect();
    let (elab, en) = components(&bright, w, h);
    let mut light_dir = vec![Vec3::ZERO; en];
    for i in 0..w * h {
        if let Some(o) = px.region(i) {
            regions[o].dir += px.dir(i) * px.sa[i / w];
        }
        if elab[i] != u32::MAX {
            let m = (luminance(estimate.get(i % w, i / w)) - white).max(0.0) * px.sa[i / w];
            light_dir[elab[i] as usize] += px.dir(i) * m;
        }
    }
    let cos_max = p.max_angle_deg.to_radians().cos();
    let light_owner: Vec<u32> = light_dir
        .iter()
        .map(|ld| {
            let ld = ld.normalize_or_zero();
            let mut best = (u32::MAX, cos_max);
            for (b, r) in regions.iter().enumerate() {
                let c = ld.dot(r.dir.normalize_or_zero());
                if c >= best.1 {
                    best = (b as u32, c);
                }
            }
            best.0
        })
        .collect();
    // Centroids of the estimate's attributed pixels (all above the white point).
    let mut est_c = vec![(0.0f64, 0.0f64, 0usize); n];
    for i in 0..w * h {
        let (x, y) = (i % w, i / w);
        let owner = if elab[i] != u32::MAX {
            light_owner[elab[i] as usize]
        } else {
            u32::MAX
        };
        if owner != u32::MAX {
            let o = owner as usize;
            let r = &mut regions[o];
            let l = luminance(estimate.get(x, y)) as f64;
            let sa = px.sa[y] as f64;
            r.estimate.power += (l - white as f64).max(0.0) * sa;
            r.estimate.peak = r.estimate.peak.max(l - white as f64);
            r.estimate.area += sa;
            if l > white as f64 {
                est_c[o].2 += 1;
                est_c[o].0 += rel_x(x, r.reference, w);
                est_c[o].1 += y as f64;
            }
        }
        if let Some(o) = px.region(i) {
            let r = &mut regions[o];
            r.area += px.sa[y] as f64;
            if px.core[i] {
                r.core_area += px.sa[y] as f64;
            }
            r.pixels += 1;
            r.centroid.0 += rel_x(x, r.reference, w);
            r.centroid.1 += y as f64;
        }
    }
    for (r, &(ex, ey, en)) in regions.iter_mut().zip(&est_c) {
        let c = r.pixels as f64;
        if en > 0 && r.pixels > 0 {
            let e = en as f64;
            r.estimate.shift = (
                (ex / e - r.centroid.0 / c) as f32,
                (ey / e - r.centroid.1 / c) as f32,
            );
        }
        r.centroid = (r.centroid.0 / c.max(1.0), r.centroid.1 / c.max(1.0));
    }
    (px, regions)
}
