//! Dense optical flow between panoramas: DIS on 8-bit images padded across the
//! u = 0/1 seam, forward–backward motion confidence, and backward warping of HDR
//! radiance along the flow.

use crate::cv::{self, DisParams};
use crate::error::{Error, Result};
use crate::image::HdrImage;
use crate::sphere::sample_px;
use serde::{Deserialize, Serialize};

/// Speed/quality presets of OpenCV's DIS flow.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum FlowPreset {
    /// Coarsest and fastest.
    Ultrafast,
    /// The default balance.
    Fast,
    /// Finer patches, more iterations.
    Medium,
}

/// Settings of the panorama flow and its confidence.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FlowParams {
    /// DIS preset.
    pub preset: FlowPreset,
    /// Finest DIS pyramid level (0 = full resolution; `None` = the preset's).
    pub finest_scale: Option<i32>,
    /// Variational refinement iterations (`None` = the preset's).
    pub refinement_iterations: Option<i32>,
    /// Fraction of the width copied across the seam on each side before the flow,
    /// so motion is continuous at u = 0/1.
    pub seam_pad: f32,
    /// Forward–backward disagreement (pixels) at which confidence falls to 1/e.
    pub fb_sigma: f32,
    /// Gradient magnitude (8-bit units per pixel) at which texture confidence is 1/2.
    pub texture_half: f32,
}

impl Default for FlowParams {
    fn default() -> Self {
        FlowParams {
            preset: FlowPreset::Fast,
            finest_scale: None,
            refinement_iterations: None,
            seam_pad: 0.125,
            fb_sigma: 1.5,
            texture_half: 4.0,
        }
    }
}

/// Pyramid levels a reduction by `k` moves the flow's finest level down
/// (`log2 k`, rounded).
pub fn level_shift(k: usize) -> i32 {
    (k.max(1) as f64).log2().round() as i32
}

impl FlowPreset {
    /// OpenCV's finest pyramid level for the preset.
    pub fn finest_scale(self) -> i32 {
        match self {
            FlowPreset::Ultrafast | FlowPreset::Fast => 2,
            FlowPreset::Medium => 1,
        }
    }
}

impl FlowParams {
    /// These settings for images reduced `k` times: the finest pyramid level moves
    /// `log2 k` levels down (not below full resolution), so the flow is as fine in
    /// the full-size image as it would be there (DIS's patch size and finest level
    /// are in pixels).
    pub fn reduced(&self, k: usize) -> FlowParams {
        let shift = level_shift(k);
        let finest = self.finest();
        let mut r = self.clone();
        r.finest_scale = Some((finest - shift).max(0));
        r
    }

    /// The finest pyramid level these settings give (the preset's unless set).
    pub fn finest(&self) -> i32 {
        self.finest_scale.unwrap_or(self.preset.finest_scale())
    }

    fn dis(&self) -> DisParams {
        DisParams {
            preset: match self.preset {
                FlowPreset::Ultrafast => 0,
                FlowPreset::Fast => 1,
                FlowPreset::Medium => 2,
            },
            finest_scale: self.finest_scale.unwrap_or(-1),
            variational_refinement_iterations: self.refinement_iterations.unwrap_or(-1),
            ..DisParams::default()
        }
    }
}

/// A dense flow field: for pixel `(x, y)`, `(dx, dy)` such that the first image at
/// `(x, y)` shows what the second shows at `(x + dx, y + dy)`.
#[derive(Clone, Debug, PartialEq)]
pub struct FlowField {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Interleaved `(dx, dy)`.
    pub data: Vec<f32>,
}

impl FlowField {
    /// The vector at `(x, y)`.
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> (f32, f32) {
        let i = 2 * (y * self.width + x);
        (self.data[i], self.data[i + 1])
    }
    /// Bilinear sample at continuous pixel coordinates (centre of pixel `i` at `i`),
    /// wrapping horizontally, clamped vertically.
    pub fn sample(&self, x: f32, y: f32) -> (f32, f32) {
        let (w, h) = (self.width as i64, self.height as i64);
        let y = y.clamp(0.0, (h - 1) as f32);
        let x0 = crate::sphere::floor(x);
        let y0 = crate::sphere::floor(y);
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        if x0 >= 0 && x0 + 1 < w && y0 + 1 < h {
            // Interior (y was clamped to at least 0): no wrapping, no division.
            let (x0, y0) = (x0 as usize, y0 as usize);
            let (a, b, c, d) = (
                self.at(x0, y0),
                self.at(x0 + 1, y0),
                self.at(x0, y0 + 1),
                self.at(x0 + 1, y0 + 1),
            );
            let lerp = |p: f32, q: f32, t: f32| p + (q - p) * t;
            return (
                lerp(lerp(a.0, b.0, fx), lerp(c.0, d.0, fx), fy),
                lerp(lerp(a.1, b.1, fx), lerp(c.1, d.1, fx), fy),
            );
        }
        let get =
            |xi: i64, yi: i64| self.at(xi.rem_euclid(w) as usize, yi.clamp(0, h - 1) as usize);
        let (a, b, c, d) = (
            get(x0, y0),
            get(x0 + 1, y0),
            get(x0, y0 + 1),
            get(x0 + 1, y0 + 1),
        );
        let lerp = |p: f32, q: f32, t: f32| p + (q - p) * t;
        (
            lerp(lerp(a.0, b.0, fx), lerp(c.0, d.0, fx), fy),
            lerp(lerp(a.1, b.1, fx), lerp(c.1, d.1, fx), fy),
        )
    }
    /// Mean length of the vectors.
    pub fn mean_magnitude(&self) -> f32 {
        let n = (self.width * self.height).max(1) as f64;
        (self
            .data
            .chunks_exact(2)
            .map(|v| ((v[0] as f64).powi(2) + (v[1] as f64).powi(2)).sqrt())
            .sum::<f64>()
            / n) as f32
    }
}

/// Flow from panorama `a` to panorama `b` (8-bit gray, `w x h`), computed on copies
/// padded across the seam so that it is continuous at u = 0/1.
pub fn pano_flow(a: &[u8], b: &[u8], w: usize, h: usize, p: &FlowParams) -> Result<FlowField> {
    if a.len() != w * h || b.len() != w * h || w == 0 || h == 0 {
        return Err(Error::Invalid(format!(
            "flow needs two {w}x{h} panoramas; got {} and {} pixels",
            a.len(),
            b.len()
        )));
    }
    let pad = ((w as f32 * p.seam_pad.clamp(0.0, 0.5)) as usize).min(w);
    let pw = w + 2 * pad;
    let padded = |img: &[u8]| -> Vec<u8> {
        let mut out = Vec::with_capacity(pw * h);
        for y in 0..h {
            let row = &img[y * w..(y + 1) * w];
            out.extend_from_slice(&row[w - pad..]);
            out.extend_from_slice(row);
            out.extend_from_slice(&row[..pad]);
        }
        out
    };
    let (pa, pb) = (padded(a), padded(b));
    let f = cv::dis_flow(&pa, &pb, pw, h, &p.dis()).map_err(|e| match e {
        Error::External { tool, msg } => Error::External {
            tool,
            msg: format!("flow on a {w}x{h} panorama: {msg}"),
        },
        e => e,
    })?;
    let mut data = Vec::with_capacity(w * h * 2);
    for y in 0..h {
        let row = &f[2 * (y * pw + pad)..2 * (y * pw + pad + w)];
        data.extend(row.iter().map(|v| if v.is_finite() { *v } else { 0.0 }));
    }
    Ok(FlowField {
        width: w,
        height: h,
        data,
    })
}

/// Per-pixel motion confidence in [0, 1]: forward–backward consistency
/// `exp(-(|F(x) + B(x + F(x))| / fb_sigma)^2)` times a texture term
/// `g / (g + texture_half)` from the gradient magnitude `g` of `gray` (the first
/// image), since flow in uniform or saturated regions is a guess.
pub fn confidence(fwd: &FlowField, bwd: &FlowField, gray: &[u8], p: &FlowParams) -> Vec<f32> {
    confidence_with(
        fwd,
        bwd,
        &texture_confidence(gray, fwd.width, fwd.height, p),
        p,
    )
}

/// The texture term of [`confidence`] per pixel of the `w x h` image `gray`:
/// `g / (g + texture_half)`. It depends on the frame only, so a frame matched
/// against several probes computes it once.
pub fn texture_confidence(gray: &[u8], w: usize, h: usize, p: &FlowParams) -> Vec<f32> {
    let half = p.texture_half.max(1e-3);
    let mut out = vec![0.0f32; w * h];
    use rayon::prelude::*;
    out.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, line)| {
            // Neighbours one pixel away: wrapped across the seam by a compare,
            // not a division.
            let wi = w as i64;
            let g = |xx: i64, yy: i64| {
                let xx = if xx < 0 {
                    xx + wi
                } else if xx >= wi {
                    xx - wi
                } else {
                    xx
                };
                gray[(yy.clamp(0, h as i64 - 1) as usize) * w + xx as usize] as f32
            };
            for (x, c) in line.iter_mut().enumerate() {
                let (xi, yi) = (x as i64, y as i64);
                let gx = 0.5 * (g(xi + 1, yi) - g(xi - 1, yi));
                let gy = 0.5 * (g(xi, yi + 1) - g(xi, yi - 1));
                // `hypot` of finite values, as glibc computes it, inline.
                let mag = ((gx as f64).powi(2) + (gy as f64).powi(2)).sqrt() as f32;
                *c = mag / (mag + half);
            }
        });
    out
}

/// [`confidence`] with its texture term given ([`texture_confidence`]).
pub fn confidence_with(
    fwd: &FlowField,
    bwd: &FlowField,
    texture: &[f32],
    p: &FlowParams,
) -> Vec<f32> {
    let (w, h) = (fwd.width, fwd.height);
    let sigma = p.fb_sigma.max(1e-3);
    let mut out = vec![0.0f32; w * h];
    use rayon::prelude::*;
    out.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, line)| {
            for x in 0..w {
                let (dx, dy) = fwd.at(x, y);
                let (bx, by) = bwd.sample(x as f32 + dx, y as f32 + dy);
                // `hypot` for finite values (glibc's `hypotf` is this sum in
                // f64), without the library call; NaN or infinite gives 0 below
                // either way.
                let (ex, ey) = ((dx + bx) as f64, (dy + by) as f64);
                let e = (ex * ex + ey * ey).sqrt() as f32;
                let c_fb = (-(e / sigma).powi(2)).exp();
                let c = c_fb * texture[y * w + x];
                line[x] = if c.is_finite() {
                    c.clamp(0.0, 1.0)
                } else {
                    0.0
                };
            }
        });
    out
}

/// Warps `img` (same size as the flow) backwards along the flow: the output at `x`
/// is `img` at `x + flow(x)`, sampled bilinearly in float (seam- and pole-aware, never
/// clamped in value).
pub fn warp_backward(img: &HdrImage, flow: &FlowField) -> Result<HdrImage> {
    if img.width() != flow.width || img.height() != flow.height {
        return Err(Error::Invalid(format!(
            "image {}x{} and flow {}x{} differ in size",
            img.width(),
            img.height(),
            flow.width,
            flow.height
        )));
    }
    let (w, h) = (img.width(), img.height());
    let mut out = HdrImage::new(w, h);
    for y in 0..h {
        for x in 0..w {
            out.set(x, y, warp_pixel(img, flow, x, y));
        }
    }
    Ok(out)
}

/// One pixel of [`warp_backward`]: `img` at `(x, y) + flow(x, y)` (both the
/// flow's size).
#[inline]
pub fn warp_pixel(img: &HdrImage, flow: &FlowField, x: usize, y: usize) -> [f32; 3] {
    let (dx, dy) = flow.at(x, y);
    sample_px(img, x as f32 + 0.5 + dx, y as f32 + 0.5 + dy)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn texture(w: usize, h: usize) -> Vec<u8> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as u32, (i / w) as u32);
                let mut v = (x / 6).wrapping_mul(2654435761) ^ (y / 6).wrapping_mul(40503);
                v ^= v >> 13;
                v = v.wrapping_mul(0x5bd1e995);
                ((v >> 8) & 0xff) as u8
            })
            .collect()
    }

    #[test]
    fn flow_is_continuous_across_the_seam() {
        // b is a shifted across u = 0 by 5 pixels: a(x) = b(x + 5) with wrap.
        let (w, h) = (256, 64);
        let a = texture(w, h);
        let b: Vec<u8> = (0..w * h)
            .map(|i| a[(i / w) * w + (i % w + w - 5) % w])
            .collect();
        let f = pano_flow(&a, &b, w, h, &FlowParams::default()).unwrap();
        for &x in &[0usize, 1, 2, w - 3, w - 2, w - 1, w / 2] {
            let (dx, dy) = f.at(x, h / 2);
            assert!(
                (dx - 5.0).abs() < 1.0 && dy.abs() < 1.0,
                "x={x}: ({dx}, {dy})"
            );
        }
    }

    #[test]
    fn uniform_and_saturated_images_give_finite_low_confidence() {
        let (w, h) = (64, 32);
        for v in [0u8, 128, 255] {
            let img = vec![v; w * h];
            let p = FlowParams::default();
            let f = pano_flow(&img, &img, w, h, &p).unwrap();
            let b = pano_flow(&img, &img, w, h, &p).unwrap();
            assert!(f.data.iter().all(|v| v.is_finite()));
            let c = confidence(&f, &b, &img, &p);
            assert!(c.iter().all(|&c| (0.0..0.05).contains(&c)), "value {v}");
        }
    }

    #[test]
    fn mismatched_sizes_are_errors() {
        let a = vec![0u8; 64 * 32];
        assert!(pano_flow(&a, &a[..100], 64, 32, &FlowParams::default()).is_err());
        let f = FlowField {
            width: 4,
            height: 2,
            data: vec![0.0; 16],
        };
        assert!(warp_backward(&HdrImage::new(8, 4), &f).is_err());
    }

    #[test]
    fn backward_warp_keeps_hdr_values() {
        let img = HdrImage::from_fn(16, 8, |x, _| {
            if x == 5 {
                [1e5, 1e5, 1e5]
            } else {
                [1.0, 1.0, 1.0]
            }
        });
        let f = FlowField {
            width: 16,
            height: 8,
            data: (0..16 * 8).flat_map(|_| [2.0f32, 0.0]).collect(),
        };
        let out = warp_backward(&img, &f).unwrap();
        assert_eq!(out.get(3, 4)[0], 1e5);
    }
}
