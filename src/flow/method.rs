//! The flow method (thesis Part I, after Gupta et al. 2009): the two neighbouring HDR
//! probes, already turned into the frame's orientation, are warped onto the SDR
//! frame with dense optical flow and fused per pixel by a graph cut whose labels are
//! "left probe", "right probe" and "SDR frame".

use super::dense::{
    confidence_with, pano_flow, texture_confidence, warp_backward, FlowField, FlowParams,
};
use super::distant::{hold_distant_lights, restore_distant_lights, DistantLights, RotatedView};
use super::graphcut::{argmin_labels, cheapest_label, optimize, GridEnergy, Optimizer, INFEASIBLE};
use crate::error::{Error, Result};
use crate::image::censor::Censor;
use crate::image::{HdrImage, SdrImage};
use crate::sphere::{sample_dir, sample_px, sample_px_by, uv_to_dir};
use crate::tonemap::{to_gray8, EncodeLut, Response};
use glam::Mat3;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Settings of the flow method.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FlowMethodParams {
    /// Optical flow and confidence.
    pub flow: FlowParams,
    /// Data cost of the SDR label (the thesis's c = 500: SDR only where nothing
    /// else is valid).
    pub sdr_cost: f32,
    /// Calibrated SDR label (radiometric fusion): where the frame did not clip it
    /// costs `sdr_cost` (set it low: the frame is a measurement there); where any
    /// channel clipped (`censor`) it is infeasible, so the probes fill it.
    pub sdr_calibrated: bool,
    /// Which codes are clipped or bled ([`crate::image::censor`]): the one
    /// setting of it for a run (the fusion on top reads it too).
    #[serde(default)]
    pub censor: Censor,
    /// Weight of the seam (smoothness) cost against the data cost.
    pub lambda: f32,
    /// Move-making algorithm.
    pub optimizer: Optimizer,
    /// Most expansion/swap cycles.
    pub max_cycles: usize,
    /// Ablation: choose the cheapest label per pixel, no smoothness.
    pub no_smoothness: bool,
    /// Radius of the box window over which the colour term is averaged (0 = per pixel).
    pub dc_radius: usize,
    /// Seam-cost weight, relative to clipped pixels, where the SDR frame measured
    /// the scene (did not clip). There the colour term already tells the labels
    /// apart, so smoothness should barely override it; in clipped regions the
    /// colour term is blind and the seam cost alone keeps light sources whole. It
    /// changes labels only with `measured_decides` off: otherwise measured pixels
    /// keep their cheapest label.
    pub seam_measured: f32,
    /// Weight of the colour term where the frame clipped. There the frame only
    /// bounds the radiance from below, and a label darker than the clip level
    /// contradicts that measurement however much seam cost it would save; the
    /// display difference alone (at most 1) is too weak against log-exposure seams.
    pub clipped_dc_weight: f32,
    /// Constant cost of a label change between clipped pixels (a Potts term on top
    /// of the seam cost). Inside a clipped lamp the colour term cannot tell the
    /// labels apart, but at its rim it can (the label whose lamp edge lines up with
    /// the frame's); a constant change cost carries that evidence inward, where the
    /// seam cost alone lets labels change freely wherever their radiances agree.
    pub clipped_potts: f32,
    /// Weight of the log-exposure seam cost where the frame clipped (and next to
    /// such pixels).
    pub seam_clipped: f32,
    /// Where the frame measured (did not clip), the label is the one its data cost
    /// prefers, whatever a clipped neighbour's label: the Potts cost then carries
    /// the rim's evidence into a clipped region but cannot pull a measured rim
    /// pixel onto the region's label against its measurement.
    #[serde(default = "yes")]
    pub measured_decides: bool,
    /// Weight of the colour term Dc against Df and Dd (the thesis: 1). Dc is a
    /// measurement (typically 0.01 to 0.1 in display units) while Dd spans [0, 1]
    /// and Df is near 1 wherever the frame has little texture; at weight 1 the
    /// distance prior decides almost every pixel. Default 100: the measurement
    /// decides, the priors break ties (measured on the three evaluation scenes:
    /// +2.3 to +3.1 dB for the flow method, +1.2 to +2.7 dB for hybrid).
    pub dc_weight: f32,
    /// Widest frame processed at full resolution. A wider frame is processed at
    /// `1/k` of its size (the smallest integer `k` that brings it to this width,
    /// averaging `k x k` samples per pixel): flow, confidence, costs and graph cut
    /// run there, and the labels and flow are then applied to the full-size probes
    /// and frame (see [`flow_frame_scaled`]). At 7776 x 3888 the full-size buffers
    /// of those stages took over 10 GB. 0 = always full resolution.
    #[serde(default = "default_work_width")]
    pub work_width: usize,
    /// Largest angle, in degrees, between the direction in which each probe sees a
    /// clipped region's light and the one the first probe sees it in, for the light
    /// to count as distant: the probes then have no parallax for it, so the flow
    /// keeps their rotated alignment there (see [`super::distant`]). 0 turns this
    /// off.
    #[serde(default = "default_distant_light_deg")]
    pub distant_light_deg: f32,
    /// How far around a clipped region its light is looked for, in degrees of
    /// longitude: the most a flow error is expected to move it.
    #[serde(default = "default_light_ring_deg")]
    pub light_ring_deg: f32,
    /// Hybrid only: how far (degrees of longitude) from a clipped region the warp
    /// stage may have moved its distant light; such a light is put back where the
    /// rotation puts it before the flow (see [`restore_warped_lights`]). Needs
    /// `distant_light_deg` > 0.
    #[serde(default = "default_light_reach_deg")]
    pub light_reach_deg: f32,
}

fn default_light_reach_deg() -> f32 {
    12.0
}

fn default_distant_light_deg() -> f32 {
    0.2
}

fn default_light_ring_deg() -> f32 {
    2.0
}

fn yes() -> bool {
    true
}

fn default_work_width() -> usize {
    2048
}

impl FlowMethodParams {
    /// The factor `k` by which a frame `width` pixels wide is reduced for the flow,
    /// costs and graph cut (1 = full resolution).
    pub fn work_factor(&self, width: usize) -> usize {
        if self.work_width == 0 || width <= self.work_width {
            1
        } else {
            width.div_ceil(self.work_width)
        }
    }

    /// The working size of a `w x h` frame (`w / k`, `h / k` rounded).
    pub fn work_size(&self, w: usize, h: usize) -> (usize, usize) {
        let k = self.work_factor(w) as f64;
        (
            ((w as f64 / k).round() as usize).max(8),
            ((h as f64 / k).round() as usize).max(4),
        )
    }

    /// The working width at most `360 / pixel_deg` pixels (`pixel_deg` > 0),
    /// within these settings' own (`work_width`, 0 = the frame's size).
    pub fn work_width_at_most(&self, pixel_deg: f32) -> usize {
        if !(pixel_deg.is_finite() && pixel_deg > 0.0) {
            return self.work_width;
        }
        let most = ((360.0 / pixel_deg).round() as usize).max(8);
        if self.work_width == 0 {
            most
        } else {
            self.work_width.min(most)
        }
    }

    /// The finest flow level (in the frame's pixels, as `flow.finest_scale`)
    /// for a frame `w` pixels wide so that at the working size a pixel of it
    /// is no finer than `flow_deg` degrees, and never finer than these
    /// settings give (unchanged when they already are that coarse).
    pub fn finest_scale_at_least(&self, w: usize, flow_deg: f32) -> Option<i32> {
        if !(flow_deg.is_finite() && flow_deg > 0.0) || w == 0 {
            return self.flow.finest_scale;
        }
        let (ws, _) = self.work_size(w, 1);
        let level = ((flow_deg as f64) / (360.0 / ws as f64))
            .log2()
            .round()
            .max(0.0) as i32;
        let want = level + crate::flow::dense::level_shift(self.work_factor(w));
        if want > self.flow.finest() {
            Some(want)
        } else {
            self.flow.finest_scale
        }
    }
}

impl Default for FlowMethodParams {
    fn default() -> Self {
        FlowMethodParams {
            flow: FlowParams::default(),
            sdr_cost: 500.0,
            sdr_calibrated: false,
            censor: Censor::default(),
            lambda: 1.0,
            optimizer: Optimizer::Expansion,
            max_cycles: 4,
            no_smoothness: false,
            dc_radius: 0,
            seam_measured: 0.0,
            clipped_dc_weight: 100.0,
            clipped_potts: 5.0,
            seam_clipped: 0.0,
            measured_decides: true,
            dc_weight: 100.0,
            work_width: default_work_width(),
            distant_light_deg: default_distant_light_deg(),
            light_ring_deg: default_light_ring_deg(),
            light_reach_deg: default_light_reach_deg(),
        }
    }
}

/// One HDR source for the fusion, already in the frame's orientation.
pub struct Source<'a> {
    /// Name for the report (probe id).
    pub name: String,
    /// Radiance panorama, same size as the frame.
    pub image: &'a HdrImage,
    /// Distance from the source's capture position to the frame, in metres.
    pub distance_m: f32,
}

/// One HDR source for [`flow_frame_scaled`]: a panorama seen through a rotation
/// (the source's direction for frame direction `d` is `rotation * d`), so it is
/// never resampled to a full-size copy in the frame's orientation.
pub struct RotatedSource<'a> {
    /// Name for the report (probe id).
    pub name: String,
    /// Radiance panorama, any size.
    pub image: &'a HdrImage,
    /// Frame camera -> source camera.
    pub rotation: Mat3,
    /// Distance from the source's capture position to the frame, in metres.
    pub distance_m: f32,
}

/// Stage timings of the flow method, in milliseconds.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct FlowTimings {
    /// Tone mapping of sources and frame to 8 bit (for frames processed at a
    /// reduced size, with their resampling to it).
    pub tonemap_ms: f64,
    /// Forward and backward optical flow.
    pub flow_ms: f64,
    /// Confidence, backward warping of HDR and display images, data costs (for
    /// frames processed at a reduced size, with the full-size warp of the result).
    pub warp_ms: f64,
    /// The graph cut.
    pub graphcut_ms: f64,
}

/// What the flow method did for one frame.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FlowReport {
    /// Label names: the sources, then `sdr`.
    pub labels: Vec<String>,
    /// Fraction of pixels taking each label.
    pub label_fractions: Vec<f32>,
    /// Mean motion confidence per source.
    pub mean_confidence: Vec<f32>,
    /// Mean flow magnitude per source, in pixels.
    pub mean_flow_px: Vec<f32>,
    /// Pixels per source whose flow was set to zero because the probes agree that a
    /// clipped light is distant: over the light and its ring, and wherever else the
    /// flow read it (see [`super::distant`]).
    #[serde(default)]
    pub distant_light_px: Vec<usize>,
    /// Hybrid: pixels per probe whose warped values were replaced by the rotated
    /// probe's to put a distant light back (see [`restore_warped_lights`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub restored_light_px: Vec<usize>,
    /// Final energy, and its data and smoothness parts.
    pub energy: f64,
    /// Data part of the energy.
    pub data_energy: f64,
    /// Smoothness part of the energy.
    pub smooth_energy: f64,
    /// Energy after each cycle.
    pub energy_history: Vec<f64>,
    /// Stage timings.
    pub timings: FlowTimings,
    /// The size flow, costs and graph cut ran at, when smaller than the frame
    /// (see [`FlowMethodParams::work_width`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub work_size: Option<(usize, usize)>,
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Display values in [0, 1] of radiance as the frame camera would record it.
fn camera_display(img: &HdrImage, lut: &EncodeLut) -> Vec<f32> {
    img.data().iter().map(|&v| lut.encode(v)).collect()
}

/// The colour term Dc of one label at one pixel: the mean absolute display
/// difference between the label (`label`, display units) and the frame (`frame`)
/// over the three channels. A channel the frame clipped (`clipped[k]`) only bounds
/// the radiance from below, so there a label brighter than the frame costs nothing
/// and only a darker one is charged.
fn colour_cost(label: &[f32], frame: &[f32], clipped: &[bool]) -> f32 {
    (0..3)
        .map(|k| {
            if clipped[k] {
                (frame[k] - label[k]).max(0.0)
            } else {
                (label[k] - frame[k]).abs()
            }
        })
        .sum::<f32>()
        / 3.0
}

/// Mean over a `(2r+1)^2` box, wrapping horizontally and clamping vertically.
fn box_filter(v: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    if r == 0 {
        return v.to_vec();
    }
    let ri = r as i64;
    let mut tmp = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for dx in -ri..=ri {
                s += v[y * w + (x as i64 + dx).rem_euclid(w as i64) as usize];
            }
            tmp[y * w + x] = s / (2 * r + 1) as f32;
        }
    }
    let mut out = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for dy in -ri..=ri {
                s += tmp[(y as i64 + dy).clamp(0, h as i64 - 1) as usize * w + x];
            }
            out[y * w + x] = s / (2 * r + 1) as f32;
        }
    }
    out
}

/// Fuses `sources` (one or two, in the frame's orientation) onto the SDR frame.
/// `sdr_linear` is the frame's radiance (used by the SDR label); `response` and
/// `gain` describe the frame camera. Sources with NaN, infinite or negative
/// samples are an [`Error::Invalid`] naming the source. Everything runs at the
/// frame's size (see [`flow_frame_scaled`] for wide frames).
pub fn flow_frame(
    sdr: &SdrImage,
    sdr_linear: &HdrImage,
    sources: &[Source],
    response: &Response,
    gain: f32,
    p: &FlowMethodParams,
) -> Result<(HdrImage, FlowReport)> {
    let fused = fuse(sdr, sdr_linear, sources, response, gain, p, None)?;
    let (w, h) = (sdr.width(), sdr.height());
    let n_src = sources.len();
    let mut out = HdrImage::new(w, h);
    for px in 0..w * h {
        let l = fused.labels[px] as usize;
        let v = if l < n_src {
            &fused.warped[l].data()[3 * px..3 * px + 3]
        } else {
            &sdr_linear.data()[3 * px..3 * px + 3]
        };
        out.data_mut()[3 * px..3 * px + 3].copy_from_slice(v);
    }
    Ok((out, fused.report))
}

/// The outcome of the flow method before the output is assembled.
struct Fused {
    /// Label per pixel: a source, or `sources.len()` for the SDR frame.
    labels: Vec<u8>,
    /// Forward flow (frame -> source) per source.
    flows: Vec<FlowField>,
    /// The sources warped onto the frame along `flows`.
    warped: Vec<HdrImage>,
    report: FlowReport,
}

/// Checks, flow, confidence, costs and graph cut of [`flow_frame`], at the
/// frame's size. `clipped` flags, per pixel and channel, where the frame only
/// bounds the radiance from below (default: codes at or above `p.clip_code`).
fn fuse(
    sdr: &SdrImage,
    sdr_linear: &HdrImage,
    sources: &[Source],
    response: &Response,
    gain: f32,
    p: &FlowMethodParams,
    clipped: Option<&[bool]>,
) -> Result<Fused> {
    let (w, h) = (sdr.width(), sdr.height());
    let from_codes: Vec<bool>;
    let clipped_ch: &[bool] = match clipped {
        Some(c) if c.len() == 3 * w * h => c,
        Some(c) => {
            return Err(Error::Invalid(format!(
                "{} clipped-channel flags for a {w}x{h} frame",
                c.len()
            )))
        }
        None => {
            from_codes = sdr.data().iter().map(|&c| p.censor.clipped(c)).collect();
            &from_codes
        }
    };
    if sources.is_empty() {
        return Err(Error::Invalid(
            "the flow method needs at least one probe".into(),
        ));
    }
    for s in sources {
        if s.image.width() != w || s.image.height() != h {
            return Err(Error::Invalid(format!(
                "source {} is {}x{} but the frame is {w}x{h}",
                s.name,
                s.image.width(),
                s.image.height()
            )));
        }
        let bad = s.image.count_invalid();
        if bad > 0 {
            let m = format!(
                "source {} has {bad} NaN, infinite or negative samples",
                s.name
            );
            return Err(Error::Invalid(
                m + "; re-export it, or run it through `lumiprobe convert`, which repairs them",
            ));
        }
    }
    if sdr_linear.width() != w || sdr_linear.height() != h {
        return Err(Error::Invalid(
            "linearised frame and frame differ in size".into(),
        ));
    }
    for (name, v) in [
        ("SDR label cost", p.sdr_cost),
        ("lambda", p.lambda),
        ("colour-term weight", p.dc_weight),
        ("clipped colour-term weight", p.clipped_dc_weight),
        ("clipped Potts cost", p.clipped_potts),
    ] {
        if v.is_nan() || v < 0.0 {
            return Err(Error::Invalid(format!(
                "flow method: {name} is {v}; it must be a number >= 0"
            )));
        }
    }
    check_light_settings(p)?;
    let mut timings = FlowTimings::default();
    let t = Instant::now();
    let frame_disp: Vec<f32> = sdr.data().iter().map(|&c| c as f32 / 255.0).collect();
    let frame_gray = to_gray8(&frame_disp);
    let lut = EncodeLut::new(response, gain, 4096);
    let src_disp: Vec<Vec<f32>> = sources
        .iter()
        .map(|s| camera_display(s.image, &lut))
        .collect();
    let src_gray: Vec<Vec<u8>> = src_disp.iter().map(|d| to_gray8(d)).collect();
    timings.tonemap_ms = ms(t);

    // Flow frame -> source (to warp the source onto the frame) and back.
    let t = Instant::now();
    let flows: Vec<Result<_>> = {
        use rayon::prelude::*;
        src_gray
            .par_iter()
            .map(|g| {
                let fwd = pano_flow(&frame_gray, g, w, h, &p.flow)?;
                let bwd = pano_flow(g, &frame_gray, w, h, &p.flow)?;
                Ok((fwd, bwd))
            })
            .collect()
    };
    let mut flows: Vec<_> = flows.into_iter().collect::<Result<Vec<_>>>()?;
    let clipped_px = p.censor.clipped_pixels(sdr.data());
    // Where the frame clipped, a light the probes see in the same direction keeps
    // the rotation's alignment. At a reduced working size a light smaller than a
    // working pixel clips none of them whole: any clipped sample counts.
    let light_clipped: Vec<bool> = clipped_ch
        .chunks_exact(3)
        .map(|c| c.contains(&true))
        .collect();
    let distant_light_px = if let Some(settings) = distant_settings(p, w, response, gain) {
        let images: Vec<&HdrImage> = sources.iter().map(|s| s.image).collect();
        hold_distant_lights(&light_clipped, w, h, &images, &mut flows, &settings)
    } else {
        vec![0; sources.len()]
    };
    timings.flow_ms = ms(t);

    let t = Instant::now();
    let n_src = sources.len();
    let n_lab = n_src + 1;
    let mut warped = Vec::with_capacity(n_src);
    let mut warped_disp = Vec::with_capacity(n_src);
    let mut confs = Vec::with_capacity(n_src);
    let texture = texture_confidence(&frame_gray, w, h, &p.flow);
    for (i, (fwd, bwd)) in flows.iter().enumerate() {
        let wi = warp_backward(sources[i].image, fwd)?;
        warped_disp.push(camera_display(&wi, &lut));
        warped.push(wi);
        confs.push(confidence_with(fwd, bwd, &texture, &p.flow));
    }
    // In f64 and capped: infinite or huge distances must not make the prior NaN.
    let dist = |s: &Source| (s.distance_m.max(0.0) as f64).min(f32::MAX as f64);
    let dist_sum: f64 = sources.iter().map(dist).sum();
    // Colour term per source: mean absolute display difference to the frame,
    // optionally averaged over a box window (wrapping across the seam). A channel
    // the frame clipped bounds the radiance from below only: a label brighter than
    // it agrees with the frame, one darker contradicts it.
    let dcs: Vec<Vec<f32>> = warped_disp
        .iter()
        .map(|wd| {
            let raw: Vec<f32> = (0..w * h)
                .map(|px| {
                    let (d, f) = (&wd[3 * px..3 * px + 3], &frame_disp[3 * px..3 * px + 3]);
                    colour_cost(d, f, &clipped_ch[3 * px..3 * px + 3])
                })
                .collect();
            box_filter(&raw, w, h, p.dc_radius)
        })
        .collect();
    // Seam weight per pixel: 1 where the frame clipped (or next to a clipped
    // pixel), `seam_measured` where it measured.
    let seam_ch = if p.seam_clipped != 0.0 || p.seam_measured != 0.0 {
        3
    } else {
        0
    };
    // Only the seam channels read it (none by default).
    let seam_w: Vec<f32> = (0..if seam_ch > 0 { w * h } else { 0 })
        .map(|px| {
            let (x, y) = (px % w, px / w);
            let near = [(0i64, 0i64), (-1, 0), (1, 0), (0, -1), (0, 1)]
                .iter()
                .any(|&(dx, dy)| {
                    let yy = y as i64 + dy;
                    if yy < 0 || yy >= h as i64 {
                        return false;
                    }
                    let xx = (x as i64 + dx).rem_euclid(w as i64) as usize;
                    clipped_px[yy as usize * w + xx]
                });
            if near {
                p.seam_clipped
            } else {
                p.seam_measured
            }
        })
        .collect();
    // Seam features: log exposure `ln(1 + gain E)`, which does not saturate, so
    // labels that disagree inside a clipped lamp still cost a seam.
    let seam_feature = |v: f32| (1.0 + (gain * v).max(0.0)).ln();
    let mut data = vec![0.0f32; w * h * n_lab];
    // Per label: three seam channels, then a one-hot label code scaled by the
    // Potts weight (non-zero only where the frame clipped). Channels that would be
    // zero everywhere are left out.
    let potts_ch = if p.clipped_potts != 0.0 { n_lab } else { 0 };
    let ch = seam_ch + potts_ch;
    let potts_feature = p.clipped_potts / std::f32::consts::SQRT_2;
    let mut features = vec![0.0f32; w * h * n_lab * ch];
    for px in 0..w * h {
        for i in 0..n_src {
            let dc = if clipped_px[px] {
                p.dc_weight * p.clipped_dc_weight * dcs[i][px]
            } else {
                p.dc_weight * dcs[i][px]
            };
            let df = 1.0 - confs[i][px];
            let dd = if dist_sum > 0.0 {
                (dist(&sources[i]) / dist_sum) as f32
            } else {
                0.0
            };
            let cost = dc + df + dd;
            let hdr = &warped[i].data()[3 * px..3 * px + 3];
            let feasible = cost.is_finite() && hdr.iter().all(|v| v.is_finite());
            data[px * n_lab + i] = if feasible { cost } else { INFEASIBLE };
            for k in 0..seam_ch {
                features[(px * n_lab + i) * ch + k] = seam_w[px] * seam_feature(hdr[k]);
            }
            if potts_ch > 0 && clipped_px[px] {
                features[(px * n_lab + i) * ch + seam_ch + i] = potts_feature;
            }
        }
        let clipped = p.sdr_calibrated && clipped_px[px];
        data[px * n_lab + n_src] = if clipped { INFEASIBLE } else { p.sdr_cost };
        let lin = &sdr_linear.data()[3 * px..3 * px + 3];
        for k in 0..seam_ch {
            features[(px * n_lab + n_src) * ch + k] = seam_w[px] * seam_feature(lin[k]);
        }
        if potts_ch > 0 && clipped_px[px] {
            features[(px * n_lab + n_src) * ch + seam_ch + n_src] = potts_feature;
        }
    }
    if p.measured_decides && !p.no_smoothness {
        fix_measured_labels(&mut data, &clipped_px, n_lab);
    }
    timings.warp_ms = ms(t);

    let t = Instant::now();
    // The SDR label can be left out when it can never win: its data cost exceeds the
    // cheapest probe label's by more than the most smoothness the pixel can save,
    // `lambda` times the largest label-pair feature distance at the pixel (four
    // times, once per edge) plus that at each of its four neighbours.
    let dmax: Vec<f32> = features
        .chunks_exact(n_lab * ch)
        .map(|f| {
            let mut m = 0.0f32;
            for a in 0..n_lab {
                for b in a + 1..n_lab {
                    let (fa, fb) = (&f[a * ch..(a + 1) * ch], &f[b * ch..(b + 1) * ch]);
                    let d2: f32 = (0..ch).map(|k| (fa[k] - fb[k]) * (fa[k] - fb[k])).sum();
                    m = m.max(d2.sqrt());
                }
            }
            if m.is_finite() {
                m
            } else {
                f32::INFINITY
            }
        })
        .collect();
    let sdr_needed = (0..w * h).any(|px| {
        let d = &data[px * n_lab..(px + 1) * n_lab];
        let best_probe = d[..n_src].iter().cloned().fold(f32::INFINITY, f32::min);
        let (x, y) = (px % w, px / w);
        let mut reach = 4.0 * dmax[px];
        reach += dmax[y * w + (x + 1) % w] + dmax[y * w + (x + w - 1) % w];
        if y > 0 {
            reach += dmax[px - w];
        }
        if y + 1 < h {
            reach += dmax[px + w];
        }
        d[n_src] <= best_probe + p.lambda * reach
    });
    let (cut_labels, cut_data, cut_features);
    let (data_ref, feat_ref) = if sdr_needed {
        cut_labels = n_lab;
        (&data[..], &features[..])
    } else {
        cut_labels = n_src;
        cut_data = data
            .chunks_exact(n_lab)
            .flat_map(|d| d[..n_src].to_vec())
            .collect::<Vec<f32>>();
        cut_features = features
            .chunks_exact(n_lab * ch)
            .flat_map(|f| f[..n_src * ch].to_vec())
            .collect::<Vec<f32>>();
        (&cut_data[..], &cut_features[..])
    };
    let energy = GridEnergy {
        width: w,
        height: h,
        labels: cut_labels,
        data: data_ref,
        features: feat_ref,
        channels: ch,
        lambda: p.lambda,
        wrap_x: true,
    };
    let (labels, e, ed, es, hist) = if p.no_smoothness {
        let l = argmin_labels(&energy);
        let (ed, es) = super::graphcut::energy(&energy, &l)?;
        (l, ed + es, ed, es, vec![ed + es])
    } else {
        let r = optimize(&energy, p.optimizer, p.max_cycles, None)?;
        (
            r.labels,
            r.energy,
            r.data_energy,
            r.smooth_energy,
            r.history,
        )
    };
    timings.graphcut_ms = ms(t);

    let mut counts = vec![0usize; n_lab];
    for &l in &labels {
        counts[(l as usize).min(n_lab - 1)] += 1;
    }
    let npx = (w * h).max(1) as f32;
    let report = FlowReport {
        labels: sources
            .iter()
            .map(|s| s.name.clone())
            .chain(std::iter::once("sdr".to_string()))
            .collect(),
        label_fractions: counts.iter().map(|&c| c as f32 / npx).collect(),
        mean_confidence: confs.iter().map(|c| c.iter().sum::<f32>() / npx).collect(),
        mean_flow_px: flows.iter().map(|(f, _)| f.mean_magnitude()).collect(),
        distant_light_px,
        restored_light_px: Vec::new(),
        energy: e,
        data_energy: ed,
        smooth_energy: es,
        energy_history: hist,
        timings,
        work_size: None,
    };
    Ok(Fused {
        labels,
        flows: flows.into_iter().map(|(fwd, _)| fwd).collect(),
        warped,
        report,
    })
}

/// Makes every label but the cheapest infeasible at measured (unclipped) pixels, so
/// the cut decides only the clipped ones (see `FlowMethodParams::measured_decides`).
fn fix_measured_labels(data: &mut [f32], clipped_px: &[bool], n_lab: usize) {
    for (d, &clipped) in data.chunks_exact_mut(n_lab).zip(clipped_px) {
        if clipped {
            continue;
        }
        let best = cheapest_label(d);
        for (i, v) in d.iter_mut().enumerate() {
            if i != best {
                *v = INFEASIBLE;
            }
        }
    }
}

/// Area-averaged resampling to `ws x hs` of a `w x h` panorama given by `f(x, y)`
/// at continuous pixel coordinates (pixel `i` spans `[i, i + 1)`): each output
/// pixel averages `k x k` samples spread evenly over its footprint, which are the
/// input's pixel centres when `w = k ws` and `h = k hs`.
fn area_resample(
    ws: usize,
    hs: usize,
    w: usize,
    h: usize,
    k: usize,
    f: impl Fn(f32, f32) -> [f32; 3] + Sync,
    px: impl Fn(usize) -> [f32; 3] + Sync,
) -> HdrImage {
    use rayon::prelude::*;
    // When `w = k ws` and `h = k hs` every sample is a pixel centre, where `f`
    // (a bilinear sample) is the pixel itself: `px(i)` reads it directly.
    let centres = w == ws * k && h == hs * k;
    let (sx, sy) = (w as f32 / (ws * k) as f32, h as f32 / (hs * k) as f32);
    let norm = 1.0 / (k * k) as f32;
    let mut out = HdrImage::new(ws, hs);
    out.rows_mut()
        .enumerate()
        .par_bridge()
        .for_each(|(j, line)| {
            for i in 0..ws {
                let mut acc = [0.0f32; 3];
                for b in 0..k {
                    let y = ((j * k + b) as f32 + 0.5) * sy;
                    for a in 0..k {
                        let v = if centres {
                            px((j * k + b) * w + i * k + a)
                        } else {
                            f(((i * k + a) as f32 + 0.5) * sx, y)
                        };
                        for c in 0..3 {
                            acc[c] += v[c];
                        }
                    }
                }
                for c in 0..3 {
                    line[3 * i + c] = acc[c] * norm;
                }
            }
        });
    out
}

/// `sources` with their images replaced by `images` (already in the frame's
/// orientation), as [`Source`]s.
fn with_images<'a>(sources: &[RotatedSource], images: &[&'a HdrImage]) -> Vec<Source<'a>> {
    sources
        .iter()
        .zip(images)
        .map(|(s, &image)| Source {
            name: s.name.clone(),
            image,
            distance_m: s.distance_m,
        })
        .collect()
}

/// An angle in degrees of longitude as whole pixels of a `w`-wide panorama
/// (rounded up).
fn degrees_to_px(deg: f32, w: usize) -> usize {
    (deg.max(0.0) / 360.0 * w as f32).ceil() as usize
}

/// The distant-light angles must be finite and >= 0: an infinite reach or ring
/// would grow each light over the whole panorama.
fn check_light_settings(p: &FlowMethodParams) -> Result<()> {
    for (name, v) in [
        ("distant-light angle", p.distant_light_deg),
        ("light ring", p.light_ring_deg),
        ("light reach", p.light_reach_deg),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(Error::Invalid(format!(
                "flow method: {name} is {v}; it must be a finite number >= 0"
            )));
        }
    }
    Ok(())
}

/// The distant-light rules' settings for a `w`-wide frame; `None` when they are
/// off (`distant_light_deg` 0) or the frame's gain is unusable.
fn distant_settings(
    p: &FlowMethodParams,
    w: usize,
    response: &Response,
    gain: f32,
) -> Option<DistantLights> {
    (p.distant_light_deg > 0.0 && gain.is_finite() && gain > 0.0).then(|| DistantLights {
        clip_radiance: response.decode(p.censor.clip_code as f32 / 255.0) / gain,
        ring_px: degrees_to_px(p.light_ring_deg, w),
        tolerance_rad: (p.distant_light_deg as f64).to_radians(),
    })
}

/// The hybrid's step between its two stages: where the frame clipped, a distant
/// light that a warped probe (`warped`, at the frame's size) holds elsewhere than
/// the same probe merely rotated into the frame (`unwarped`, same order) is put
/// back where the rotation puts it, with the rotated probe's values over the light
/// and a ring around it (see [`super::distant::restore_distant_lights`]). Off with
/// `distant_light_deg` 0, and a no-op on frames without clipped pixels. Returns
/// the pixels replaced per probe.
pub fn restore_warped_lights(
    sdr: &SdrImage,
    warped: &mut [HdrImage],
    unwarped: &[RotatedSource],
    response: &Response,
    gain: f32,
    p: &FlowMethodParams,
) -> Result<Vec<usize>> {
    let (w, h) = (sdr.width(), sdr.height());
    if warped.len() != unwarped.len() {
        return Err(Error::Invalid(format!(
            "{} warped probes for {} probes",
            warped.len(),
            unwarped.len()
        )));
    }
    if let Some(img) = warped.iter().find(|i| i.width() != w || i.height() != h) {
        return Err(Error::Invalid(format!(
            "a warped probe is {}x{}, the frame {w}x{h}",
            img.width(),
            img.height()
        )));
    }
    check_light_settings(p)?;
    let clipped = p.censor.clipped_pixels(sdr.data());
    let Some(settings) = distant_settings(p, w, response, gain) else {
        return Ok(vec![0; warped.len()]);
    };
    if warped.len() < 2 || !clipped.contains(&true) {
        return Ok(vec![0; warped.len()]);
    }
    let rotated: Vec<RotatedView> = unwarped
        .iter()
        .map(|s| RotatedView {
            image: s.image,
            rotation: s.rotation,
            width: w,
            height: h,
        })
        .collect();
    let reach = degrees_to_px(p.light_reach_deg, w);
    Ok(restore_distant_lights(
        &clipped, w, h, &rotated, warped, &settings, reach,
    ))
}

/// The flow method on sources seen through rotations, for frames of any size.
/// Up to [`FlowMethodParams::work_width`] this is [`flow_frame`] on the sources
/// rotated into the frame's orientation. A wider frame, its radiance and the
/// sources are area-averaged to the working size, where flow, confidence, costs
/// and graph cut run as in [`flow_frame`]; the labels and the flow (bilinear,
/// scaled) are then applied at full size, each output pixel sampling its source
/// panorama once, in float, where the flow points. A pixel takes its working
/// pixel's label, except between working pixels of different probes, where the
/// probe closer to the frame's colour there decides. At full size only the output
/// is allocated; the report's label fractions are those of the working size.
pub fn flow_frame_scaled(
    sdr: &SdrImage,
    sdr_linear: &HdrImage,
    sources: &[RotatedSource],
    response: &Response,
    gain: f32,
    p: &FlowMethodParams,
) -> Result<(HdrImage, FlowReport)> {
    use rayon::prelude::*;
    let (w, h) = (sdr.width(), sdr.height());
    if sdr_linear.width() != w || sdr_linear.height() != h {
        return Err(Error::Invalid(
            "linearised frame and frame differ in size".into(),
        ));
    }
    let k = p.work_factor(w);
    if k <= 1 {
        // A source already in the frame's orientation and size (the hybrid's warped
        // probes) is used as it is.
        let rotated: Vec<std::borrow::Cow<HdrImage>> = sources
            .iter()
            .map(|s| {
                let same_size = s.image.width() == w && s.image.height() == h;
                if same_size && s.rotation == glam::Mat3::IDENTITY {
                    std::borrow::Cow::Borrowed(s.image)
                } else {
                    std::borrow::Cow::Owned(crate::sphere::rotate(s.image, s.rotation, w, h))
                }
            })
            .collect();
        let images: Vec<&HdrImage> = rotated.iter().map(|c| c.as_ref()).collect();
        let plain = with_images(sources, &images);
        return flow_frame(sdr, sdr_linear, &plain, response, gain, p);
    }
    let t = Instant::now();
    let (ws, hs) = p.work_size(w, h);
    let codes = sdr.data();
    let display = |i: usize| {
        let c = &codes[3 * i..3 * i + 3];
        [
            c[0] as f32 / 255.0,
            c[1] as f32 / 255.0,
            c[2] as f32 / 255.0,
        ]
    };
    let small_disp = area_resample(
        ws,
        hs,
        w,
        h,
        k,
        |x, y| sample_px_by(w, h, x, y, display),
        display,
    );
    let small_sdr = SdrImage::from_vec(ws, hs, crate::tonemap::quantize(small_disp.data()))?;
    drop(small_disp);
    // A working pixel with a clipped sample in a channel only bounds that channel
    // from below (its average counts the clipped sample at the clip level), even
    // when the average itself falls under the clip code: a sun a few pixels wide
    // leaves such pixels all around it.
    let clip_flag = |i: usize| {
        let c = &codes[3 * i..3 * i + 3];
        [0, 1, 2].map(|k| if p.censor.clipped(c[k]) { 1.0f32 } else { 0.0 })
    };
    let small_clipped: Vec<bool> = area_resample(
        ws,
        hs,
        w,
        h,
        k,
        |x, y| {
            // Nearest pixel: a bilinear tap would lend a neighbour's flag.
            let (xi, yi) = (
                (x.max(0.0) as usize).min(w - 1),
                (y.max(0.0) as usize).min(h - 1),
            );
            clip_flag(yi * w + xi)
        },
        clip_flag,
    )
    .data()
    .iter()
    .map(|&share| share > 0.0)
    .collect();
    let pixel = |img: &HdrImage, i: usize| {
        let d = img.data();
        [d[3 * i], d[3 * i + 1], d[3 * i + 2]]
    };
    let small_lin = area_resample(
        ws,
        hs,
        w,
        h,
        k,
        |x, y| sample_px(sdr_linear, x, y),
        |i| pixel(sdr_linear, i),
    );
    // Each source is area-averaged in its own axes to about the working size, then
    // rotated into the frame's: sampling the full-size source k x k times per
    // working pixel through the rotation costs as much as rotating it at full size.
    let small_src: Vec<HdrImage> = sources
        .iter()
        .map(|s| {
            let (pw, ph) = (s.image.width(), s.image.height());
            let kp = ((pw as f64 / ws as f64).round() as usize).max(1);
            if kp == 1 {
                return crate::sphere::rotate(s.image, s.rotation, ws, hs);
            }
            let (pws, phs) = (
                ((pw as f64 / kp as f64).round() as usize).max(8),
                ((ph as f64 / kp as f64).round() as usize).max(4),
            );
            let reduced = area_resample(
                pws,
                phs,
                pw,
                ph,
                kp,
                |x, y| sample_px(s.image, x, y),
                |i| pixel(s.image, i),
            );
            crate::sphere::rotate(&reduced, s.rotation, ws, hs)
        })
        .collect();
    let plain = with_images(sources, &small_src.iter().collect::<Vec<_>>());
    let resample_ms = ms(t);
    // DIS works in pixels: at the working size its finest level moves down by
    // log2 k, so the flow stays as fine as at full size (at 2048 x 1024 from
    // 512 x 256 working images: 29.3 dB instead of 26.9, full size 29.9).
    let pw = FlowMethodParams {
        flow: p.flow.reduced(k),
        ..p.clone()
    };
    let fused = fuse(
        &small_sdr,
        &small_lin,
        &plain,
        response,
        gain,
        &pw,
        Some(&small_clipped),
    )?;
    drop(plain);
    drop(small_src);
    drop(small_lin);
    let Fused {
        labels,
        flows,
        warped,
        mut report,
    } = fused;
    drop(warped);

    let t = Instant::now();
    let n_src = sources.len();
    let (sx, sy) = (ws as f32 / w as f32, hs as f32 / h as f32);
    let lut = EncodeLut::new(response, gain, 4096);
    let mut out = HdrImage::new(w, h);
    out.rows_mut()
        .enumerate()
        .par_bridge()
        .for_each(|(row, line)| {
            // Working-size coordinates of this row's pixel centres.
            let yw = (row as f32 + 0.5) * sy;
            let lrow = (yw as usize).min(hs - 1);
            let value = |l: usize, col: usize, xw: f32| {
                // `FlowField::sample` puts pixel i's centre at i.
                let (dx, dy) = flows[l].sample(xw - 0.5, yw - 0.5);
                let x = col as f32 + 0.5 + dx / sx;
                let y = row as f32 + 0.5 + dy / sy;
                let s = &sources[l];
                sample_dir(s.image, s.rotation * uv_to_dir(x / w as f32, y / h as f32))
            };
            let y0 = ((yw - 0.5).floor().max(0.0) as usize).min(hs - 1);
            let y1 = (y0 + 1).min(hs - 1);
            for col in 0..w {
                let xw = (col as f32 + 0.5) * sx;
                let mut l = labels[lrow * ws + (xw as usize).min(ws - 1)] as usize;
                // Where working pixels around this one took different probes, the
                // probe whose warped value is closest to the frame's (the colour
                // term of the cut, at full size) decides: label edges follow the
                // frame instead of the working grid (+0.4 dB at 2048 x 1024 from
                // 512 x 256). Clipped pixels, where colour cannot tell, keep theirs.
                if l < n_src {
                    let x0 = ((xw - 0.5).floor() as i64).rem_euclid(ws as i64) as usize;
                    let x1 = (x0 + 1) % ws;
                    let near = [y0 * ws + x0, y0 * ws + x1, y1 * ws + x0, y1 * ws + x1];
                    let c = &codes[3 * (row * w + col)..3 * (row * w + col) + 3];
                    if near
                        .iter()
                        .any(|&q| labels[q] as usize != l && (labels[q] as usize) < n_src)
                        && !p.censor.any_clipped(c)
                    {
                        let mut best = (f32::INFINITY, l);
                        for (j, &q) in near.iter().enumerate() {
                            let m = labels[q] as usize;
                            if m >= n_src || near[..j].iter().any(|&r| labels[r] == labels[q]) {
                                continue;
                            }
                            let v = value(m, col, xw);
                            let dc: f32 = (0..3)
                                .map(|k| (lut.encode(v[k]) - c[k] as f32 / 255.0).abs())
                                .sum();
                            if dc < best.0 {
                                best = (dc, m);
                            }
                        }
                        l = best.1;
                    }
                }
                let v = if l < n_src {
                    value(l, col, xw)
                } else {
                    sdr_linear.get(col, row)
                };
                line[3 * col..3 * col + 3].copy_from_slice(&v);
            }
        });
    report.timings.tonemap_ms += resample_ms;
    report.timings.warp_ms += ms(t);
    for m in &mut report.mean_flow_px {
        *m /= sx;
    }
    report.work_size = Some((ws, hs));
    Ok((out, report))
}

#[cfg(test)]
mod tests;
