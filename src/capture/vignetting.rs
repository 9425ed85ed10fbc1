//! A two-lens 360° camera's vignetting, from the walk itself (issue 20).
//!
//! A consumer camera's stitched panorama still darkens towards each lens's rim
//! (the seam between the two fisheyes). The falloff is fixed in the camera's
//! own axes, so every frame shows the same one: against the probes (which
//! have none), a frame's blocks read `log gain + ln(1 - k rim)`, `rim` the
//! squared angle of the block from the nearer lens axis over 90 degrees (0 on
//! an axis, 1 on the seam; lenses along the camera's ±z, as the Theta and Gear
//! 360 and `lumiprobe fisheye` have them). Left in, it pulls every frame's gain
//! down by the falloff's mean over the blocks that voted (about -0.2 EV for
//! `k = 0.25`). `k` is the value that makes each frame's votes agree best
//! with one gain (the least absolute deviation from each frame's median, over
//! every frame), searched on a grid: parallax and passers-by scatter votes
//! whatever their rim, the falloff only along it.

use super::median;
use crate::image::HdrImage;
use glam::Vec3;

/// Largest falloff searched (`1 - k` at the seam): 0.6 is 1.3 EV.
const MAX_K: f64 = 0.6;
/// Grid step of the search.
const STEP: f64 = 0.01;
/// Frames with fewer votes than this do not take part in the fit.
const MIN_VOTES: usize = 8;

/// Squared angle of camera-axes direction `d` from the nearer lens axis (±z),
/// over 90 degrees: 0 on an axis, 1 on the seam between the lenses.
pub fn rim(d: Vec3) -> f32 {
    let len = d.length();
    if !(len > 0.0 && len.is_finite()) {
        return 0.0;
    }
    let theta = (d.z.abs() / len).clamp(0.0, 1.0).acos();
    (theta / std::f32::consts::FRAC_PI_2).powi(2)
}

/// The falloff `k` (`1 - k rim`) that best explains `frames`' votes (each a
/// block's log ratio of frame to probe, with its [`rim`]); 0 when too few
/// frames voted.
pub fn fit(frames: &[Vec<(f64, f32)>]) -> f64 {
    let used: Vec<&Vec<(f64, f32)>> = frames.iter().filter(|v| v.len() >= MIN_VOTES).collect();
    if used.is_empty() {
        return 0.0;
    }
    let steps = (MAX_K / STEP).round() as usize;
    let mut best = (f64::INFINITY, 0.0);
    for i in 0..=steps {
        let k = i as f64 * STEP;
        let cost: f64 = used
            .iter()
            .map(|votes| {
                let mut v = corrected(votes, k);
                let m = median(&mut v);
                v.iter().map(|x| (x - m).abs()).sum::<f64>()
            })
            .sum();
        if cost < best.0 {
            best = (cost, k);
        }
    }
    best.1
}

/// The median of `votes` with a falloff `k` taken out (NaN without votes).
pub fn frame_median(votes: &[(f64, f32)], k: f64) -> f64 {
    median(&mut corrected(votes, k))
}

/// Divides a panorama (camera axes) by the falloff `1 - k rim`: what a lens
/// without vignetting would have recorded. Nothing changes for `k` not in
/// (0, 1).
pub fn divide_out(img: &mut HdrImage, k: f32) {
    if !(k > 0.0 && k < 1.0) {
        return;
    }
    let (w, h) = (img.width(), img.height());
    for y in 0..h {
        for x in 0..w {
            let f = 1.0 - k * rim(crate::sphere::pixel_to_dir(x, y, w, h));
            let v = img.get(x, y);
            img.set(x, y, v.map(|c| c / f));
        }
    }
}

fn corrected(votes: &[(f64, f32)], k: f64) -> Vec<f64> {
    votes
        .iter()
        .map(|&(v, r)| v - (1.0 - k * r as f64).ln())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Votes of `n` frames with gains 0.1 apart, blocks spread over the rim,
    /// a falloff `k` and a scatter that does not depend on the rim.
    fn walk(k: f64, n: usize) -> Vec<Vec<(f64, f32)>> {
        (0..n)
            .map(|f| {
                (0..60)
                    .map(|b| {
                        let r = (b % 20) as f32 / 19.0;
                        // A deterministic scatter of +-0.15 in log.
                        let noise = 0.15 * (((b * 37 + f * 11) % 17) as f64 / 8.0 - 1.0);
                        (0.1 * f as f64 + (1.0 - k * r as f64).ln() + noise, r)
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn the_falloff_of_the_walk_is_found_and_taken_out_of_each_frames_gain() {
        for k in [0.0, 0.25, 0.4] {
            let votes = walk(k, 12);
            let found = fit(&votes);
            assert!((found - k).abs() <= 0.03, "k {k}: found {found}");
            // Each frame's gain with the falloff out is its own (0.1 f),
            // within the scatter's median error; left in, it is biased low.
            for (f, v) in votes.iter().enumerate() {
                let got = frame_median(v, found);
                assert!(
                    (got - 0.1 * f as f64).abs() < 0.05,
                    "k {k} frame {f}: {got}"
                );
                if k >= 0.25 {
                    assert!(frame_median(v, 0.0) < 0.1 * f as f64 - 0.05);
                }
            }
        }
    }

    #[test]
    fn a_vignetted_panorama_divided_by_its_falloff_is_what_the_lens_saw() {
        let (w, h) = (32, 16);
        let truth = HdrImage::from_fn(w, h, |x, y| [1.0 + x as f32, 2.0, 0.5 + y as f32]);
        let k = 0.3;
        let mut img = HdrImage::from_fn(w, h, |x, y| {
            let f = 1.0 - k * rim(crate::sphere::pixel_to_dir(x, y, w, h));
            truth.get(x, y).map(|v| v * f)
        });
        assert!(img.get(w / 4, h / 2)[1] < 1.5, "the seam is darker");
        divide_out(&mut img, k);
        for (a, b) in img.pixels().zip(truth.pixels()) {
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() < 1e-4 * b[c], "{a:?} vs {b:?}");
            }
        }
        // Outside (0, 1) nothing changes.
        let before = img.clone();
        divide_out(&mut img, 0.0);
        divide_out(&mut img, 1.0);
        assert!(img == before);
    }

    #[test]
    fn rim_is_zero_on_the_lens_axes_and_one_on_the_seam() {
        assert_eq!(rim(Vec3::Z), 0.0);
        assert_eq!(rim(-Vec3::Z), 0.0);
        assert!((rim(Vec3::X) - 1.0).abs() < 1e-6);
        assert!((rim(Vec3::new(1.0, 0.0, 1.0)) - 0.25).abs() < 1e-5);
        assert_eq!(rim(Vec3::ZERO), 0.0);
        assert!(fit(&[]) == 0.0);
    }
}
