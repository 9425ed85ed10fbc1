//! Distant lights keep the alignment the rotation gave them.
//!
//! The probes are turned into the frame's orientation before the flow, so the flow
//! only has to explain parallax. A light at infinity (the sun, sky through a far
//! opening) has none: the rotation alone puts it where the frame sees it. Inside a
//! clipped light, though, the tone-mapped images are flat white and the flow there
//! is interpolated from around it; on outdoor frame 11 it moved a sun a few pixels
//! wide by about one pixel in each probe, half of its light onto sky the frame had
//! measured.
//!
//! Two probes that see a light in the same direction have no parallax for it, and a
//! frame between them has none either. Where that holds for a compact light, and
//! where the flow-warped probe puts less of it inside the frame's clipped pixels or
//! spills a larger share of it outside them than the unwarped probe does, the flow
//! is set to zero over the light and a ring around it.

use super::dense::{warp_pixel, FlowField};
use crate::image::HdrImage;
use crate::sphere::mask::{components, dilate, grow_from};
use crate::sphere::{pixel_to_dir, row_solid_angles, sample_dir, sample_px_by};
use glam::{DVec3, Mat3};

/// Widest spread (root-mean-square angle from its mean direction, in degrees) of a
/// light that is held. A wide clipped region (a sky band) has a mean direction that
/// says nothing about the parallax along its edges; its flow is left alone.
pub const MAX_LIGHT_SPREAD_DEG: f64 = 5.0;

/// How [`hold_distant_lights`] decides.
#[derive(Clone, Copy, Debug)]
pub struct DistantLights {
    /// Radiance at which the frame clips: only light above it counts.
    pub clip_radiance: f32,
    /// Pixels around a clipped region searched for its light (the most a flow
    /// error is expected to move it), in 4-neighbour steps.
    pub ring_px: usize,
    /// Largest angle, in radians, between the direction in which a probe sees a
    /// region's light and the direction the first probe sees it in, for the light
    /// to count as distant.
    pub tolerance_rad: f64,
}

/// Where the frame clipped (`clipped`, a `w x h` mask), sets each source's flow pair
/// (frame -> source, source -> frame) to zero over a clipped region and `ring_px`
/// around it when every source sees the region's light, compact (see
/// [`MAX_LIGHT_SPREAD_DEG`]), in the same direction (within `tolerance_rad` of the
/// first's), and that source, unwarped, has some of it in the clipped pixels and
/// either more of it there or a smaller share of it outside them than warped along
/// its flow. The forward flow of any other pixel that reads a held light is set to
/// zero too, so the light is not shown twice (its backward flow belongs to other
/// pixels and is kept, so the confidence sees the inconsistency). Needs two
/// sources or more, all `w x h` like the flows; returns the pixels whose forward
/// flow was set to zero, per source.
pub fn hold_distant_lights(
    clipped: &[bool],
    w: usize,
    h: usize,
    sources: &[&HdrImage],
    flows: &mut [(FlowField, FlowField)],
    p: &DistantLights,
) -> Vec<usize> {
    let n_src = sources.len().min(flows.len());
    let mut held = vec![0usize; sources.len()];
    let clip = p.clip_radiance;
    let sizes_agree = clipped.len() == w * h
        && sources.iter().all(|s| s.width() == w && s.height() == h)
        && flows.iter().all(|(f, b)| {
            (f.width, f.height, b.width, b.height) == (w, h, w, h)
                && f.data.len() == 2 * w * h
                && b.data.len() == 2 * w * h
        });
    if n_src < 2 || !sizes_agree {
        return held;
    }
    let Some((_, pixels)) = clipped_regions(clipped, w, h, p) else {
        return held;
    };
    let meter = LightMeter::new(w, h, clip);
    let above = |v: [f32; 3], row: usize| meter.above(v, row);
    // Per source: pixels whose flow was set to zero, and those of them holding the
    // source's light above the clip level (allocated once something is held).
    let mut in_place: Vec<Vec<bool>> = Vec::new();
    let mut light: Vec<Vec<bool>> = Vec::new();
    let mut flow_in = vec![0.0f64; n_src];
    let mut flow_out = vec![0.0f64; n_src];
    for region in &pixels {
        // Per source: the light inside and outside the clipped pixels, unwarped;
        // then, only for a distant light, the same warped.
        let Some(RegionLight {
            inside: zero_in,
            outside: zero_out,
        }) = meter.distant_light(region, clipped, &sources[..n_src], p.tolerance_rad)
        else {
            continue;
        };
        flow_in.fill(0.0);
        flow_out.fill(0.0);
        for &px in region {
            let (x, y) = (px % w, px / w);
            for i in 0..n_src {
                let warped = above(warp_pixel(sources[i], &flows[i].0, x, y), y);
                if clipped[px] {
                    flow_in[i] += warped;
                } else {
                    flow_out[i] += warped;
                }
            }
        }
        if in_place.is_empty() {
            in_place = vec![vec![false; w * h]; n_src];
            light = vec![vec![false; w * h]; n_src];
        }
        for i in 0..n_src {
            let flow_worse = flow_in[i] < zero_in[i]
                || spill(flow_in[i], flow_out[i]) > spill(zero_in[i], zero_out[i]);
            if zero_in[i] <= 0.0 || !flow_worse {
                continue;
            }
            let (fwd, bwd) = &mut flows[i];
            for &px in region {
                fwd.data[2 * px..2 * px + 2].fill(0.0);
                bwd.data[2 * px..2 * px + 2].fill(0.0);
                in_place[i][px] = true;
                light[i][px] = above(sources[i].value(px), px / w) > 0.0;
            }
            held[i] += region.len();
        }
    }
    // A held light now sits where the rotation put it; a frame pixel elsewhere whose
    // flow still reads it would show it twice (on sparse outdoor probes, a sun copy
    // six pixels above the real one). Such pixels read the probe in place too.
    for i in 0..n_src {
        if held[i] == 0 {
            continue;
        }
        // Rows holding the held light: a pixel whose flow lands more than a row away
        // from them is skipped before any lookup (unless the light touches a pole,
        // across which the sampling reflects).
        let lit_rows = (0..h).filter(|&y| light[i][y * w..(y + 1) * w].contains(&true));
        let (lo, hi) = lit_rows.fold((usize::MAX, 0), |(lo, hi), y| (lo.min(y), hi.max(y)));
        if lo > hi {
            continue;
        }
        let (lo, hi) = if lo == 0 || hi + 1 == h {
            (f32::NEG_INFINITY, f32::INFINITY)
        } else {
            (lo as f32 - 1.0, hi as f32 + 1.0)
        };
        let lit = &light[i];
        let fwd = &mut flows[i].0;
        for px in 0..w * h {
            let (x, y) = (px % w, px / w);
            let (dx, dy) = fwd.at(x, y);
            let sy = y as f32 + dy;
            // Also false for NaN.
            if !(sy >= lo && sy < hi) || in_place[i][px] {
                continue;
            }
            // The warp's own bilinear taps and weights, on the light mask.
            let (sx, sy) = (x as f32 + 0.5 + dx, sy + 0.5);
            let reads = sample_px_by(w, h, sx, sy, |q| [if lit[q] { 1.0 } else { 0.0 }, 0.0, 0.0]);
            if reads[0] > 0.0 {
                fwd.data[2 * px..2 * px + 2].fill(0.0);
                held[i] += 1;
            }
        }
    }
    held
}

/// Where the frame clipped (`clipped`, `w x h`), puts a distant light back where
/// the rotation alone puts it in each `warped` source, from the same source seen
/// through its rotation into the frame (`rotated`, same order and size). For the
/// hybrid, whose sources come through the warp method: a face's homography is
/// fitted to the features it matched, mostly near ones, and moves a light at
/// infinity by their parallax (outdoor frame 19 at a reduced working size: a sun
/// 11 pixels off, then lost by the flow stage). The light counts as distant when
/// every rotated source sees it compact and in the same direction (as
/// [`hold_distant_lights`]). Within `reach_px` steps of the region (other clipped
/// regions left out), a warped source is mended when it has less of the light
/// above the clip inside the clipped pixels than its rotation, or a larger share
/// of it outside them. The region and the warped source's light within reach,
/// with `ring_px` around them, then take the rotated source's values. Returns the
/// pixels replaced, per source.
pub fn restore_distant_lights(
    clipped: &[bool],
    w: usize,
    h: usize,
    rotated: &[RotatedView],
    warped: &mut [HdrImage],
    p: &DistantLights,
    reach_px: usize,
) -> Vec<usize> {
    let n_src = rotated.len().min(warped.len());
    let mut restored = vec![0usize; warped.len()];
    let clip = p.clip_radiance;
    let sizes_agree = clipped.len() == w * h
        && rotated.iter().all(|s| (s.width, s.height) == (w, h))
        && warped.iter().all(|s| s.width() == w && s.height() == h);
    if n_src < 2 || !sizes_agree {
        return restored;
    }
    let Some((lab, pixels)) = clipped_regions(clipped, w, h, p) else {
        return restored;
    };
    let meter = LightMeter::new(w, h, clip);
    let mut scratch = vec![false; w * h];
    // Pixels replaced per source (allocated once something is).
    let mut touched: Vec<Vec<bool>> = Vec::new();
    for (k, region) in pixels.iter().enumerate() {
        let Some(light) = meter.distant_light(region, clipped, &rotated[..n_src], p.tolerance_rad)
        else {
            continue;
        };
        // Pixels within reach of the region, other clipped regions (other lights,
        // with their own parallax) left out.
        let mine = |q: usize| lab[q] == k as u32 || lab[q] == u32::MAX;
        let near: Vec<usize> = grow_from(region, w, h, reach_px, &mut scratch)
            .into_iter()
            .filter(|&q| mine(q))
            .collect();
        for i in 0..n_src {
            if light.inside[i] <= 0.0 {
                continue;
            }
            // Both placements' light within reach, inside the clipped pixels and
            // outside them.
            let (mut w_in, mut w_out, mut r_in, mut r_out) = (0.0, 0.0, 0.0, 0.0);
            let mut span = Vec::new();
            for &q in &near {
                let (wv, rv) = (
                    meter.above(warped[i].value(q), q / w),
                    meter.above(rotated[i].value(q), q / w),
                );
                if clipped[q] {
                    w_in += wv;
                    r_in += rv;
                } else {
                    w_out += wv;
                    r_out += rv;
                }
                if lab[q] == k as u32 || wv > 0.0 {
                    span.push(q);
                }
            }
            // No margin: for a light at infinity the rotation is right up to the
            // pose error, so replacing a warp that placed it as well costs little
            // (outdoor frame 18: 4% less light inside after the warp, and the
            // replacement took the irradiance error from 0.022 to 0.001).
            let warp_worse = w_in < r_in || spill(w_in, w_out) > spill(r_in, r_out);
            if !warp_worse {
                continue;
            }
            // The region and the warped light near it, with the ring around them.
            let patch = grow_from(&span, w, h, p.ring_px, &mut scratch);
            if touched.is_empty() {
                touched = vec![vec![false; w * h]; n_src];
            }
            let dst = warped[i].data_mut();
            for q in patch.into_iter().filter(|&q| mine(q)) {
                dst[3 * q..3 * q + 3].copy_from_slice(&rotated[i].value(q));
                if !touched[i][q] {
                    touched[i][q] = true;
                    restored[i] += 1;
                }
            }
        }
    }
    restored
}

/// The frame's clipped regions, each grown by `p.ring_px`: a label per pixel
/// (`u32::MAX` outside) and each region's pixels. `None` when nothing clipped or
/// the clip level is unusable.
fn clipped_regions(
    clipped: &[bool],
    w: usize,
    h: usize,
    p: &DistantLights,
) -> Option<(Vec<u32>, Vec<Vec<usize>>)> {
    let clip = p.clip_radiance;
    if !clip.is_finite() || clip <= 0.0 || !clipped.contains(&true) {
        return None;
    }
    let (lab, n) = components(&dilate(clipped, w, h, p.ring_px), w, h);
    let mut pixels: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (px, &l) in lab.iter().enumerate() {
        if l != u32::MAX {
            pixels[l as usize].push(px);
        }
    }
    Some((lab, pixels))
}

/// Per-pixel radiance of a `w x h` panorama, read one pixel at a time.
trait Pixels {
    fn value(&self, px: usize) -> [f32; 3];
}

impl Pixels for HdrImage {
    fn value(&self, px: usize) -> [f32; 3] {
        self.get(px % self.width(), px / self.width())
    }
}

impl<T: Pixels> Pixels for &T {
    fn value(&self, px: usize) -> [f32; 3] {
        (**self).value(px)
    }
}

/// A panorama seen through a rotation at the frame's size (`rotation * d` is the
/// panorama's direction for frame direction `d`, as
/// [`crate::flow::method::RotatedSource`]), sampled on demand: the few pixels
/// around a light cost far less than rotating the whole panorama at full size.
pub struct RotatedView<'a> {
    /// The panorama.
    pub image: &'a HdrImage,
    /// Frame direction to panorama direction.
    pub rotation: Mat3,
    /// The frame's width.
    pub width: usize,
    /// The frame's height.
    pub height: usize,
}

impl Pixels for RotatedView<'_> {
    fn value(&self, px: usize) -> [f32; 3] {
        let d = pixel_to_dir(px % self.width, px / self.width, self.width, self.height);
        sample_dir(self.image, self.rotation * d)
    }
}

/// A distant, compact light of one clipped region, per source: its light above
/// the clip level (weighted by solid angle) inside the frame's clipped pixels and
/// outside them.
struct RegionLight {
    inside: Vec<f64>,
    outside: Vec<f64>,
}

/// Light above the clip level and pixel directions of a `w x h` panorama.
struct LightMeter {
    clip: f32,
    solid: Vec<f32>,
    /// Per row: sine and cosine of the latitude.
    rows: Vec<(f64, f64)>,
    /// Per column: sine and cosine of the longitude, as `pixel_to_dir`.
    cols: Vec<(f64, f64)>,
}

impl LightMeter {
    fn new(w: usize, h: usize, clip: f32) -> Self {
        let rows = (0..h)
            .map(|y| {
                let d = pixel_to_dir(0, y, w, h).as_dvec3();
                (d.y, d.x.hypot(d.z))
            })
            .collect();
        let cols = (0..w)
            .map(|x| {
                let d = pixel_to_dir(x, h / 2, w, h).as_dvec3();
                let c = d.x.hypot(d.z).max(1e-300);
                (d.x / c, -d.z / c)
            })
            .collect();
        LightMeter {
            clip,
            solid: row_solid_angles(w, h),
            rows,
            cols,
        }
    }

    /// Light above the clip level of one pixel value in row `row`, weighted by its
    /// solid angle (0 for non-finite values).
    fn above(&self, v: [f32; 3], row: usize) -> f64 {
        let s: f64 = v
            .iter()
            .map(|&c| (c as f64 - self.clip as f64).max(0.0))
            .sum();
        if s.is_finite() {
            s * self.solid[row] as f64
        } else {
            0.0
        }
    }

    fn dir(&self, x: usize, y: usize) -> DVec3 {
        let ((st, ct), (sp, cp)) = (self.rows[y], self.cols[x]);
        DVec3::new(ct * sp, st, -ct * cp)
    }

    /// The light of a region (pixel indices; `clipped` marks the frame's clipped
    /// ones) when every source sees some of it, compact (see
    /// [`MAX_LIGHT_SPREAD_DEG`]), in the same direction (within `tolerance_rad` of
    /// the first source's); `None` otherwise.
    fn distant_light(
        &self,
        region: &[usize],
        clipped: &[bool],
        sources: &[impl Pixels],
        tolerance_rad: f64,
    ) -> Option<RegionLight> {
        let n = sources.len();
        let w = self.cols.len();
        let mut inside = vec![0.0f64; n];
        let mut outside = vec![0.0f64; n];
        let mut dirs = vec![DVec3::ZERO; n];
        for &px in region {
            let (x, y) = (px % w, px / w);
            for i in 0..n {
                let v = self.above(sources[i].value(px), y);
                if v == 0.0 {
                    continue;
                }
                dirs[i] += v * self.dir(x, y);
                if clipped[px] {
                    inside[i] += v;
                } else {
                    outside[i] += v;
                }
            }
        }
        if n == 0 || dirs.iter().any(|d| d.length_squared() == 0.0) {
            return None;
        }
        // Compact: the mean of the unit directions, weighted by light, has length
        // 1 - (mean squared angle) / 2 for a small light.
        let min_resultant = 1.0 - 0.5 * MAX_LIGHT_SPREAD_DEG.to_radians().powi(2);
        let compact = (0..n).all(|i| {
            let total = inside[i] + outside[i];
            total > 0.0 && dirs[i].length() >= min_resultant * total
        });
        let first = dirs[0];
        let distant = dirs[1..]
            .iter()
            .all(|d| d.cross(first).length().atan2(d.dot(first)) <= tolerance_rad);
        (compact && distant).then_some(RegionLight { inside, outside })
    }
}

/// Share of a light outside the clipped pixels (all of it when there is none).
fn spill(inside: f64, outside: f64) -> f64 {
    if inside + outside > 0.0 {
        outside / (inside + outside)
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: usize = 96;
    const H: usize = 48;

    /// A dim sky with a sun of radiance 1e5 covering the pixels `(x, y)` for which
    /// `sun(x, y)` holds.
    fn sky(sun: impl Fn(usize, usize) -> bool) -> HdrImage {
        HdrImage::from_fn(W, H, |x, y| if sun(x, y) { [1e5; 3] } else { [0.2; 3] })
    }

    fn flow(dx: f32, dy: f32) -> FlowField {
        FlowField {
            width: W,
            height: H,
            data: (0..W * H).flat_map(|_| [dx, dy]).collect(),
        }
    }

    /// A 2 x 2 sun straddling the seam at rows 20-21.
    fn at_seam(x: usize, y: usize) -> bool {
        (x == 0 || x == W - 1) && (y == 20 || y == 21)
    }

    fn clipped() -> Vec<bool> {
        (0..W * H).map(|p| at_seam(p % W, p / W)).collect()
    }

    fn params() -> DistantLights {
        DistantLights {
            clip_radiance: 1.0,
            ring_px: 3,
            tolerance_rad: 0.2f64.to_radians(),
        }
    }

    fn zero_at(f: &FlowField, x: usize, y: usize) -> bool {
        f.at(x, y) == (0.0, 0.0)
    }

    #[test]
    fn a_sun_both_probes_see_in_place_keeps_zero_flow() {
        // Both probes hold the sun where the frame clipped; the flow moved each by
        // about a pixel (as DIS does inside flat white regions).
        let a = sky(at_seam);
        let b = sky(at_seam);
        let mut flows = vec![
            (flow(1.0, -1.0), flow(-1.0, 1.0)),
            (flow(0.5, 0.6), flow(-0.5, -0.6)),
        ];
        // Pixel (10, 10) of the first probe's flow reads the sun, far outside its
        // ring: it would show a second sun.
        let o = 2 * (10 * W + 10);
        flows[0].0.data[o..o + 2].copy_from_slice(&[-10.0, 10.5]);
        let held = hold_distant_lights(&clipped(), W, H, &[&a, &b], &mut flows, &params());
        assert!(held.iter().all(|&n| n > 4), "held {held:?}");
        for (fwd, bwd) in &flows {
            assert!(zero_at(fwd, 0, 20) && zero_at(fwd, W - 1, 21) && zero_at(fwd, 2, 22));
            assert!(zero_at(bwd, W - 1, 20));
            // Far from the sun the flow is untouched.
            assert!(!zero_at(fwd, 40, 20));
        }
        assert!(zero_at(&flows[0].0, 10, 10), "a second sun is left");
        assert!(!zero_at(&flows[1].0, 10, 10));
        // Its backward flow is another pixel's and stays.
        assert!(!zero_at(&flows[0].1, 10, 10));
    }

    #[test]
    fn a_light_seen_with_parallax_keeps_its_flow() {
        // The second probe sees the light two pixels lower: it is near, and the flow
        // has parallax to explain.
        let a = sky(at_seam);
        let b = sky(|x, y| (x == 0 || x == W - 1) && (y == 22 || y == 23));
        let mut flows = vec![
            (flow(1.0, -1.0), flow(-1.0, 1.0)),
            (flow(0.0, 2.0), flow(0.0, -2.0)),
        ];
        let held = hold_distant_lights(&clipped(), W, H, &[&a, &b], &mut flows, &params());
        assert_eq!(held, vec![0, 0]);
        assert!(!zero_at(&flows[0].0, 0, 20));
    }

    #[test]
    fn a_flow_that_aligns_the_light_better_is_kept() {
        // Both probes agree (the light is distant) but sit a pixel right of the
        // frame's clipped pixels, as after a small rotation error; the flow of the
        // first moves it back into place, the second's flow moves it further away.
        let off = |x: usize, y: usize| (x == 0 || x == 1) && (y == 20 || y == 21);
        let (a, b) = (sky(off), sky(off));
        let mut flows = vec![
            (flow(1.0, 0.0), flow(-1.0, 0.0)),
            (flow(-1.0, 0.0), flow(1.0, 0.0)),
        ];
        let held = hold_distant_lights(&clipped(), W, H, &[&a, &b], &mut flows, &params());
        assert_eq!(held[0], 0, "the aligning flow was dropped");
        assert!(held[1] > 0, "the misaligning flow was kept");
        assert!(!zero_at(&flows[0].0, 0, 20));
        assert!(zero_at(&flows[1].0, 0, 20));
    }

    #[test]
    fn one_source_or_no_clipped_pixel_changes_nothing() {
        let a = sky(at_seam);
        let mut flows = vec![(flow(1.0, -1.0), flow(-1.0, 1.0))];
        assert_eq!(
            hold_distant_lights(&clipped(), W, H, &[&a], &mut flows, &params()),
            vec![0]
        );
        let mut two = vec![flows[0].clone(), flows[0].clone()];
        let none = vec![false; W * H];
        assert_eq!(
            hold_distant_lights(&none, W, H, &[&a, &a], &mut two, &params()),
            vec![0, 0]
        );
        assert!(!zero_at(&two[0].0, 0, 20));
    }

    #[test]
    fn a_light_only_in_the_ring_is_not_held() {
        // Both probes agree on a light two pixels beside the clipped pixels, and
        // both flows lose it entirely: holding it would put it on pixels the frame
        // measured.
        let beside = |x: usize, y: usize| (x == 2 || x == 3) && (y == 20 || y == 21);
        let (a, b) = (sky(beside), sky(beside));
        let mut flows = vec![
            (flow(0.0, 9.0), flow(0.0, -9.0)),
            (flow(0.0, 9.0), flow(0.0, -9.0)),
        ];
        let held = hold_distant_lights(&clipped(), W, H, &[&a, &b], &mut flows, &params());
        assert_eq!(held, vec![0, 0]);
    }

    #[test]
    fn a_clipped_sky_band_is_left_to_the_flow() {
        // Rows 5-8 clipped all around: the probes' light has the same mean
        // direction (straight up) but is no compact light.
        let band = |_: usize, y: usize| (5..9).contains(&y);
        let clipped: Vec<bool> = (0..W * H).map(|p| band(p % W, p / W)).collect();
        let (a, b) = (sky(band), sky(band));
        let mut flows = vec![
            (flow(0.0, 3.0), flow(0.0, -3.0)),
            (flow(0.0, 3.0), flow(0.0, -3.0)),
        ];
        let held = hold_distant_lights(&clipped, W, H, &[&a, &b], &mut flows, &params());
        assert_eq!(held, vec![0, 0]);
    }

    /// Light above the clip level (1.0) of an image inside `(x0..x1, y0..y1)`.
    fn light_in(img: &HdrImage, xs: std::ops::Range<usize>, ys: std::ops::Range<usize>) -> f32 {
        ys.flat_map(|y| xs.clone().map(move |x| (x, y)))
            .map(|(x, y)| (img.get(x, y)[0] - 1.0).max(0.0))
            .sum()
    }

    /// A 2 x 2 sun at columns 30-31, rows 20-21 (where the frame clipped).
    fn in_place(x: usize, y: usize) -> bool {
        (30..32).contains(&x) && (20..22).contains(&y)
    }

    /// A probe already in the frame's orientation.
    fn view(image: &HdrImage) -> RotatedView<'_> {
        RotatedView {
            image,
            rotation: Mat3::IDENTITY,
            width: W,
            height: H,
        }
    }

    fn clipped_at_30() -> Vec<bool> {
        (0..W * H).map(|p| in_place(p % W, p / W)).collect()
    }

    #[test]
    fn a_warp_that_moved_a_distant_sun_gets_it_back_from_the_rotation() {
        // Both rotated probes hold the sun where the frame clipped; the first
        // probe's warp moved it 5 pixels right and 4 down (a homography fitted to
        // near features), the second's left it in place.
        // The probes themselves hold the sun 10 columns further east, where the
        // rotation into the frame takes it from.
        let east = |x: usize, y: usize| (40..42).contains(&x) && (20..22).contains(&y);
        let probes = [sky(east), sky(east)];
        let yaw = Mat3::from_rotation_y(-10.0 / W as f32 * std::f32::consts::TAU);
        let refs: Vec<RotatedView> = probes
            .iter()
            .map(|image| RotatedView {
                rotation: yaw,
                ..view(image)
            })
            .collect();
        let moved = |x: usize, y: usize| (35..37).contains(&x) && (24..26).contains(&y);
        let mut warped = vec![sky(moved), sky(in_place)];
        let before = warped[1].clone();
        let n = restore_distant_lights(&clipped_at_30(), W, H, &refs, &mut warped, &params(), 12);
        assert!(n[0] > 4, "nothing restored: {n:?}");
        assert_eq!(n[1], 0, "a warp with the sun in place was changed");
        assert_eq!(warped[1].data(), before.data());
        assert!(
            light_in(&warped[0], 30..32, 20..22) > 3.0e5,
            "the sun is not back"
        );
        assert_eq!(
            light_in(&warped[0], 33..40, 22..28),
            0.0,
            "the moved copy is left"
        );
    }

    #[test]
    fn a_sun_moved_beyond_the_reach_or_seen_with_parallax_is_left() {
        let moved = |x: usize, y: usize| (35..37).contains(&x) && (24..26).contains(&y);
        let refs_agree = [sky(in_place), sky(in_place)];
        let refs: Vec<RotatedView> = refs_agree.iter().map(view).collect();
        // Beyond the reach, the moved copy is not seen: the warp has no light near
        // the region, which still counts as worse, so the region is mended but the
        // far copy stays.
        let mut warped = vec![sky(moved), sky(in_place)];
        restore_distant_lights(&clipped_at_30(), W, H, &refs, &mut warped, &params(), 0);
        assert!(light_in(&warped[0], 30..32, 20..22) > 3.0e5);
        assert!(
            light_in(&warped[0], 35..37, 24..26) > 3.0e5,
            "a light beyond the reach was removed"
        );
        // The rotated probes disagree by two rows: the light is near, and the
        // warp's placement stands.
        let lower = |x: usize, y: usize| (30..32).contains(&x) && (22..24).contains(&y);
        let parallax = [sky(in_place), sky(lower)];
        let refs: Vec<RotatedView> = parallax.iter().map(view).collect();
        let mut warped = vec![sky(moved), sky(moved)];
        let n = restore_distant_lights(&clipped_at_30(), W, H, &refs, &mut warped, &params(), 12);
        assert_eq!(n, vec![0, 0]);
        assert!(light_in(&warped[0], 35..37, 24..26) > 3.0e5);
    }

    #[test]
    fn restoring_with_mismatched_sizes_or_one_probe_changes_nothing() {
        let rotated = [sky(in_place), sky(in_place)];
        let refs: Vec<RotatedView> = rotated.iter().map(view).collect();
        let moved = |x: usize, y: usize| (35..37).contains(&x) && (24..26).contains(&y);
        let mut one = vec![sky(moved)];
        let n = restore_distant_lights(&clipped_at_30(), W, H, &refs[..1], &mut one, &params(), 12);
        assert_eq!(n, vec![0]);
        let mut small = vec![HdrImage::new(W / 2, H / 2), HdrImage::new(W / 2, H / 2)];
        let n = restore_distant_lights(&clipped_at_30(), W, H, &refs, &mut small, &params(), 12);
        assert_eq!(n, vec![0, 0]);
    }

    #[test]
    fn a_near_lamp_beside_a_distant_sun_keeps_the_warps_placement() {
        // A sun the warp moved, and 11 columns east of it a lamp the probes see with
        // parallax (two rows apart), which the warp placed where the frame clipped
        // it. Mending the sun must not touch the lamp.
        let lamp_frame = |x: usize, y: usize| (42..44).contains(&x) && (20..22).contains(&y);
        let lamp_a = |x: usize, y: usize| (42..44).contains(&x) && (18..20).contains(&y);
        let lamp_b = |x: usize, y: usize| (42..44).contains(&x) && (22..24).contains(&y);
        let moved = |x: usize, y: usize| (33..35).contains(&x) && (22..24).contains(&y);
        let a = sky(|x, y| in_place(x, y) || lamp_a(x, y));
        let b = sky(|x, y| in_place(x, y) || lamp_b(x, y));
        let refs = [view(&a), view(&b)];
        let mut warped = vec![
            sky(|x, y| moved(x, y) || lamp_frame(x, y)),
            sky(|x, y| in_place(x, y) || lamp_frame(x, y)),
        ];
        let clipped: Vec<bool> = (0..W * H)
            .map(|p| in_place(p % W, p / W) || lamp_frame(p % W, p / W))
            .collect();
        let n = restore_distant_lights(&clipped, W, H, &refs, &mut warped, &params(), 12);
        assert!(n[0] > 4, "the sun was not mended: {n:?}");
        assert!(
            light_in(&warped[0], 30..32, 20..22) > 3.0e5,
            "the sun is not back"
        );
        for (i, img) in warped.iter().enumerate() {
            let lamp = light_in(img, 42..44, 20..22);
            assert!(lamp > 3.0e5, "probe {i}: the lamp holds {lamp}");
        }
    }

    #[test]
    fn a_sun_across_the_seam_is_restored_across_it() {
        // The frame clipped a sun straddling u = 0/1; the warp moved the first
        // probe's copy four columns east of the seam and three rows down.
        let moved = |x: usize, y: usize| (3..5).contains(&x) && (23..25).contains(&y);
        let probes = [sky(at_seam), sky(at_seam)];
        let refs = [view(&probes[0]), view(&probes[1])];
        let mut warped = vec![sky(moved), sky(at_seam)];
        let n = restore_distant_lights(&clipped(), W, H, &refs, &mut warped, &params(), 12);
        assert!(n[0] > 4 && n[1] == 0, "{n:?}");
        let back = light_in(&warped[0], 0..1, 20..22) + light_in(&warped[0], W - 1..W, 20..22);
        assert!(back > 3.0e5, "the sun is not back across the seam: {back}");
        assert_eq!(
            light_in(&warped[0], 2..8, 22..27),
            0.0,
            "the moved copy is left"
        );
    }
}
