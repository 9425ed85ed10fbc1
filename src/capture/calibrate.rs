//! Radiometric calibration of the SDR frames against the probes: the exposure
//! gain `g` in `radiance = f⁻¹(code / 255) / g` that puts the linearised frames on
//! the probes' radiance scale. It is what makes an unclipped SDR pixel a
//! measurement the fusion can keep; without it (no documented gain, probes merged
//! from brackets at an arbitrary scale) the gain is recovered here.
//!
//! **Estimator.** For each frame the nearest probe is turned into the frame's
//! orientation (no parallax correction). Both images are averaged over square
//! blocks (8 x 8 pixels at 512 x 256), which makes small misalignments average
//! out; blocks in which every pixel of the frame is well exposed (all channels
//! within [`CalibrateOptions::low_code`, `high_code`]) vote with the log ratio of
//! their mean exposure to the probe's mean radiance. The frame's estimate is the
//! median vote (robust to the blocks that parallax still misaligns), the scene's
//! the median over frames; the spread of the frame estimates is reported so an
//! unreliable calibration shows.

use super::median;
use crate::error::{Error, Result};
use crate::image::{io, HdrImage, SdrImage};
use crate::scene::Scene;
use crate::sphere::rotate;
use crate::tonemap::Response;

/// Settings of [`calibrate_gain`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibrateOptions {
    /// Block side in pixels over which frame and probe are averaged.
    pub block: usize,
    /// Lowest code of a well-exposed pixel (below: noise and quantisation).
    pub low_code: u8,
    /// Highest code of a well-exposed pixel (above: the response's shoulder, JPEG
    /// ringing next to clipped regions).
    pub high_code: u8,
    /// Frames used at most, spread evenly over the walk (0 = all).
    pub max_frames: usize,
}

impl Default for CalibrateOptions {
    fn default() -> Self {
        CalibrateOptions {
            block: 8,
            low_code: 20,
            high_code: 230,
            max_frames: 0,
        }
    }
}

/// A recovered exposure gain.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct GainEstimate {
    /// The gain `g`: radiance = `f⁻¹(code / 255) / g`.
    pub gain: f32,
    /// Frames that gave an estimate.
    pub frames_used: usize,
    /// Interquartile range of the frames' natural-log estimates: the calibration's
    /// own spread (0.05 is about ±2.5% around the median).
    pub log_iqr: f32,
    /// Each frame's estimate, in frame order (NaN where a frame had no usable block).
    pub per_frame: Vec<f32>,
}

fn block_means(values: impl Fn(usize, usize) -> f64, w: usize, h: usize, b: usize) -> Vec<f64> {
    let (bw, bh) = (w / b, h / b);
    let mut out = vec![0.0; bw * bh];
    for by in 0..bh {
        for bx in 0..bw {
            let mut s = 0.0;
            for y in by * b..(by + 1) * b {
                for x in bx * b..(bx + 1) * b {
                    s += values(x, y);
                }
            }
            out[by * bw + bx] = s / (b * b) as f64;
        }
    }
    out
}

/// The log gain one frame votes for, or `None` without a usable block.
pub fn frame_log_gain(
    sdr: &SdrImage,
    probe_in_frame: &HdrImage,
    response: &Response,
    opts: &CalibrateOptions,
) -> Option<f64> {
    let (w, h) = (sdr.width(), sdr.height());
    let b = opts.block.max(1);
    if probe_in_frame.width() != w || probe_in_frame.height() != h || w < b || h < b {
        return None;
    }
    let decode: Vec<f64> = (0..256)
        .map(|c| response.decode(c as f32 / 255.0) as f64)
        .collect();
    let ok = |x: usize, y: usize| {
        let c = sdr.get(x, y);
        c.iter().all(|&v| v >= opts.low_code && v <= opts.high_code)
    };
    let good = block_means(|x, y| if ok(x, y) { 1.0 } else { 0.0 }, w, h, b);
    let frame = block_means(
        |x, y| {
            let c = sdr.get(x, y);
            (decode[c[0] as usize] + decode[c[1] as usize] + decode[c[2] as usize]) / 3.0
        },
        w,
        h,
        b,
    );
    let probe = block_means(
        |x, y| {
            let p = probe_in_frame.get(x, y);
            (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0
        },
        w,
        h,
        b,
    );
    let mut votes: Vec<f64> = (0..good.len())
        .filter(|&i| good[i] >= 1.0 && probe[i] > 0.0 && probe[i].is_finite())
        .map(|i| (frame[i] / probe[i]).ln())
        .filter(|v| v.is_finite())
        .collect();
    if votes.is_empty() {
        None
    } else {
        Some(median(&mut votes))
    }
}

/// The probe nearest frame `f`, read once into `probes` (one slot per probe of
/// the scene), turned into the frame's orientation at `w` x `h`; with its index.
/// Fails, naming the probe, when it has no HDR file yet.
pub(crate) fn nearest_probe_in_frame(
    scene: &Scene,
    f: &crate::scene::Frame,
    probes: &mut [Option<HdrImage>],
    w: usize,
    h: usize,
) -> Result<(HdrImage, usize)> {
    let k = scene.nearest_probe(f.pose.position);
    if probes[k].is_none() {
        let p = &scene.probes[k];
        let path = p.hdr.as_ref().ok_or_else(|| {
            Error::Invalid(format!(
                "calibration needs probe {}'s HDR (merge its brackets first)",
                p.id
            ))
        })?;
        let mut img = io::read_hdr(path)?;
        img.repair_invalid();
        probes[k] = Some(img);
    }
    let probe = probes[k].as_ref().expect("loaded above");
    let r = f.pose.from_other(&scene.probes[k].pose);
    Ok((rotate(probe, r, w, h), k))
}

/// Recovers the frames' exposure gain relative to the scene's HDR probes (see the
/// module docs). Needs the probes' HDR files and the frames' poses; fails with an
/// error naming the scene when no frame has a well-exposed block.
pub fn calibrate_gain(scene: &Scene, opts: &CalibrateOptions) -> Result<GainEstimate> {
    let n = scene.frames.len();
    let step = if opts.max_frames == 0 || n <= opts.max_frames {
        1
    } else {
        n.div_ceil(opts.max_frames)
    };
    let mut per_frame = vec![f32::NAN; n];
    let mut probes: Vec<Option<HdrImage>> = vec![None; scene.probes.len()];
    for (i, f) in scene.frames.iter().enumerate().step_by(step) {
        let sdr = io::read_sdr(&f.sdr)?;
        let (turned, _) = nearest_probe_in_frame(scene, f, &mut probes, sdr.width(), sdr.height())?;
        if let Some(v) = frame_log_gain(&sdr, &turned, &scene.response, opts) {
            per_frame[i] = v as f32;
        }
    }
    let mut logs: Vec<f64> = per_frame
        .iter()
        .filter(|v| v.is_finite())
        .map(|&v| v as f64)
        .collect();
    if logs.is_empty() {
        return Err(Error::Invalid(format!(
            "{} (scene {}): none of its {} frames has a well-exposed region a probe also sees \
             (every one clipped or dark there), so nothing calibrates the frames against the \
             probes; run without --calibrate and give the gain in the manifest",
            scene.root.display(),
            scene.name,
            scene.frames.len()
        )));
    }
    let used = logs.len();
    let med = median(&mut logs);
    let q = |p: f64| logs[((logs.len() - 1) as f64 * p).round() as usize];
    let iqr = (q(0.75) - q(0.25)) as f32;
    Ok(GainEstimate {
        gain: med.exp() as f32,
        frames_used: used,
        log_iqr: iqr,
        per_frame: per_frame.iter().map(|v| v.exp()).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{synthesize, SynthParams};

    #[test]
    fn recovers_the_gain_of_a_synthetic_walk() {
        let tmp = tempfile::tempdir().unwrap();
        let p = SynthParams {
            width: 256,
            n_frames: 4,
            n_probes: 3,
            seed: 3,
            name: "c".into(),
            ..Default::default()
        };
        let dir = tmp.path().join("scene");
        synthesize(&p).write(&dir).unwrap();
        let scene = Scene::load(&dir).unwrap();
        let est = calibrate_gain(&scene, &CalibrateOptions::default()).unwrap();
        let rel = est.gain / scene.path_gain - 1.0;
        assert!(rel.abs() < 0.08, "gain {} vs {}", est.gain, scene.path_gain);
        assert_eq!(est.frames_used, 4);
        assert!(est.log_iqr.is_finite());
    }

    #[test]
    fn a_frame_without_well_exposed_blocks_gives_no_vote() {
        let sdr = SdrImage::from_vec(32, 16, vec![255; 32 * 16 * 3]).unwrap();
        let probe = HdrImage::from_fn(32, 16, |_, _| [1.0; 3]);
        let v = frame_log_gain(&sdr, &probe, &Response::Srgb, &CalibrateOptions::default());
        assert_eq!(v, None);
        // A constant frame against a constant probe: exactly their ratio.
        let c = 128u8;
        let sdr = SdrImage::from_vec(32, 16, vec![c; 32 * 16 * 3]).unwrap();
        let probe = HdrImage::from_fn(32, 16, |_, _| [0.5; 3]);
        let v =
            frame_log_gain(&sdr, &probe, &Response::Srgb, &CalibrateOptions::default()).unwrap();
        let want = (Response::Srgb.decode(c as f32 / 255.0) as f64 / 0.5).ln();
        assert!((v - want).abs() < 1e-6);
    }
}
