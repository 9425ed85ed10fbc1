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
use crate::sphere::mask::{components, dilate};
use crate::sphere::{pixel_to_dir, row_solid_angles, sample_px_by};
use glam::DVec3;

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
    if n_src < 2 || !sizes_agree || !clip.is_finite() || clip <= 0.0 {
        return held;
    }
    if !clipped.iter().any(|&c| c) {
        return held;
    }
    let (lab, n) = components(&dilate(clipped, w, h, p.ring_px), w, h);
    let mut pixels: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (px, &l) in lab.iter().enumerate() {
        if l != u32::MAX {
            pixels[l as usize].push(px);
        }
    }
    let solid = row_solid_angles(w, h);
    // Light above the clip level of one pixel value, weighted by its solid angle.
    let above = |v: [f32; 3], row: usize| -> f64 {
        let s: f64 = v.iter().map(|&c| (c as f64 - clip as f64).max(0.0)).sum();
        if s.is_finite() {
            s * solid[row] as f64
        } else {
            0.0
        }
    };
    // Per source: pixels whose flow was set to zero, and those of them holding the
    // source's light above the clip level (allocated once something is held).
    let mut in_place: Vec<Vec<bool>> = Vec::new();
    let mut light: Vec<Vec<bool>> = Vec::new();
    // Directions from per-row and per-column sines and cosines, as `pixel_to_dir`.
    let rows: Vec<(f64, f64)> = (0..h)
        .map(|y| {
            let d = pixel_to_dir(0, y, w, h).as_dvec3();
            (d.y, d.x.hypot(d.z))
        })
        .collect();
    let cols: Vec<(f64, f64)> = (0..w)
        .map(|x| {
            let d = pixel_to_dir(x, h / 2, w, h).as_dvec3();
            let c = d.x.hypot(d.z).max(1e-300);
            (d.x / c, -d.z / c)
        })
        .collect();
    let dir = |x: usize, y: usize| {
        let ((st, ct), (sp, cp)) = (rows[y], cols[x]);
        DVec3::new(ct * sp, st, -ct * cp)
    };
    let mut zero_in = vec![0.0f64; n_src];
    let mut zero_out = vec![0.0f64; n_src];
    let mut flow_in = vec![0.0f64; n_src];
    let mut flow_out = vec![0.0f64; n_src];
    let mut dirs = vec![DVec3::ZERO; n_src];
    for region in &pixels {
        // Per source: the light inside and outside the clipped pixels and its
        // direction, unwarped; then, only for a distant light, the same warped.
        zero_in.fill(0.0);
        zero_out.fill(0.0);
        dirs.fill(DVec3::ZERO);
        for &px in region {
            let (x, y) = (px % w, px / w);
            for i in 0..n_src {
                let img = sources[i].data();
                let unwarped = above([img[3 * px], img[3 * px + 1], img[3 * px + 2]], y);
                if unwarped == 0.0 {
                    continue;
                }
                dirs[i] += unwarped * dir(x, y);
                if clipped[px] {
                    zero_in[i] += unwarped;
                } else {
                    zero_out[i] += unwarped;
                }
            }
        }
        if dirs.iter().any(|d| d.length_squared() == 0.0) {
            continue;
        }
        // Compact: the mean of the unit directions, weighted by light, has length
        // 1 - (mean squared angle) / 2 for a small light.
        let min_resultant = 1.0 - 0.5 * MAX_LIGHT_SPREAD_DEG.to_radians().powi(2);
        let compact = (0..n_src).all(|i| {
            let total = zero_in[i] + zero_out[i];
            total > 0.0 && dirs[i].length() >= min_resultant * total
        });
        if !compact {
            continue;
        }
        let first = dirs[0];
        let distant = dirs[1..]
            .iter()
            .all(|d| d.cross(first).length().atan2(d.dot(first)) <= p.tolerance_rad);
        if !distant {
            continue;
        }
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
            // Share of the light outside the clipped pixels (all of it when the
            // warp lost it entirely).
            let spill = |inside: f64, outside: f64| {
                if inside + outside > 0.0 {
                    outside / (inside + outside)
                } else {
                    1.0
                }
            };
            let flow_worse = flow_in[i] < zero_in[i]
                || spill(flow_in[i], flow_out[i]) > spill(zero_in[i], zero_out[i]);
            if zero_in[i] <= 0.0 || !flow_worse {
                continue;
            }
            let (fwd, bwd) = &mut flows[i];
            let img = sources[i].data();
            for &px in region {
                fwd.data[2 * px..2 * px + 2].fill(0.0);
                bwd.data[2 * px..2 * px + 2].fill(0.0);
                in_place[i][px] = true;
                let v = [img[3 * px], img[3 * px + 1], img[3 * px + 2]];
                light[i][px] = above(v, px / w) > 0.0;
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
}
