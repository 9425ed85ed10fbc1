//! Scene synthesizer: a small deterministic ray caster of a textured room that
//! produces a complete capture in the evaluation data's layout (HDR probes with
//! exposure brackets, an SDR walk, ground-truth HDR at every frame, `poses.json`).
//!
//! It exists so `lumiprobe demo` and the tests have data with exact ground truth
//! that costs well under a second to make, without shipping renders. Everything is
//! a pure function of [`SynthParams`] (the seed included): the same parameters give
//! bit-identical images and poses on every machine and thread count.
//!
//! Conventions are exactly those of the data README: world right-handed, z up,
//! metres; camera x right, y up, -z forward; `world_dir = world_from_camera · d_cam`
//! with `d_cam` from [`crate::sphere::pixel_to_dir`]; yaw/pitch/roll as in
//! [`pose::world_from_camera`]. SDR images follow the README's camera model:
//! `x = gain · E`, Gaussian noise `sigma = 0.002 + 0.01 sqrt(x)`, the rational-gamma
//! response, 8-bit quantisation (and JPEG once written).

pub mod pose;
pub mod rng;
pub mod room;

pub use pose::{world_from_camera, Pose};
pub use room::Room;

use crate::error::{Error, Result};
use crate::image::{luminance, HdrImage, SdrImage};
use crate::tonemap::Response;
use rayon::prelude::*;
use rng::{derive, SplitMix64};
use std::path::{Path, PathBuf};

/// The response formula exactly as the evaluation data's `camera.response` states it
/// (parsed by [`Response::parse`]).
pub const RESPONSE_TEXT: &str = "f(x) = min(1, 1.08 * x^(1/2.2) / (1 + 0.08 * x^(1/2.2))), x = exposure-scaled linear radiance; Gaussian noise sigma = 0.002 + 0.01*sqrt(x) added before the response; 8-bit";

/// Exposure time of the 0 EV bracket (1/60 s), as in the data.
pub const BASE_EXPOSURE_TIME_S: f64 = 1.0 / 60.0;

/// EVs of the thesis's seven probe brackets.
pub const BRACKET_EVS: [i32; 7] = [-3, -2, -1, 0, 1, 2, 3];

/// EVs of the wide 2-EV-step probe brackets.
pub const WIDE_BRACKET_EVS: [i32; 8] = [-12, -10, -8, -6, -4, -2, 0, 2];

/// What to synthesize. All fields have sensible defaults ([`SynthParams::default`]);
/// the defaults give a 5 x 4 x 2.6 m room, 3 probes and 6 frames at 256 x 128.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SynthParams {
    /// Scene name written to `poses.json`.
    pub name: String,
    /// Panorama width in pixels; height is `width / 2`.
    pub width: usize,
    /// Number of HDR probes (tripod, yaw only).
    pub n_probes: usize,
    /// Number of SDR frames along the walk.
    pub n_frames: usize,
    /// Seed of everything random: layout, textures, poses, sensor noise.
    pub seed: u64,
    /// Room size `[W (x), D (y), H (z)]` in metres.
    pub room_size: [f32; 3],
    /// Furniture boxes, 0 to 4 (table, counter, tall cabinet, crate).
    pub n_boxes: usize,
    /// Emissive ceiling panels (2–3 typical).
    pub n_lights: usize,
    /// Posters spread over the walls.
    pub n_posters: usize,
    /// Whether the brick wall has a window onto a bright sky.
    pub window: bool,
    /// Luminance of a ceiling panel before `light_scale` (scene-linear units).
    pub light_radiance: f32,
    /// Luminance of the horizon sky seen through the window.
    pub sky_radiance: f32,
    /// Ambient (indirect) irradiance over pi: a surface of albedo a gets `a * ambient`.
    pub ambient: f32,
    /// Multiplier on the ceiling panels (their visible radiance and their light).
    pub light_scale: f32,
    /// Anti-aliasing: `aa x aa` stratified jittered rays per pixel.
    pub aa: usize,
    /// Whether to make the probes' exposure brackets (7 + 8 JPEGs each).
    pub brackets: bool,
}

impl Default for SynthParams {
    fn default() -> Self {
        SynthParams {
            name: "synth".into(),
            width: 256,
            n_probes: 3,
            n_frames: 6,
            seed: 1,
            room_size: [5.0, 4.0, 2.6],
            n_boxes: 3,
            n_lights: 3,
            n_posters: 8,
            window: true,
            light_radiance: 300.0,
            sky_radiance: 30.0,
            ambient: 0.45,
            light_scale: 1.0,
            aa: 2,
            brackets: true,
        }
    }
}

impl SynthParams {
    /// Panorama height (`width / 2`, at least 1).
    pub fn height(&self) -> usize {
        (self.width / 2).max(1)
    }
}

/// One exposure bracket of a probe, as a camera would store it.
#[derive(Clone, Debug, PartialEq)]
pub struct Bracket {
    /// Exposure relative to the 0 EV bracket (gain `path_gain · 2^ev`).
    pub ev: i32,
    /// Shutter time: 1/60 s at 0 EV, doubling per EV.
    pub exposure_time_s: f64,
    /// The 8-bit image (noise, response, quantisation; JPEG only once written).
    pub image: SdrImage,
}

/// A synthetic light probe: its pose, true HDR panorama and brackets.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthProbe {
    /// Tripod pose (yaw only), id `probe_XX`.
    pub pose: Pose,
    /// True scene-linear radiance at the probe.
    pub hdr: HdrImage,
    /// Brackets at [`BRACKET_EVS`] (empty unless `params.brackets`).
    pub brackets: Vec<Bracket>,
    /// Brackets at [`WIDE_BRACKET_EVS`] (empty unless `params.brackets`).
    pub brackets_wide: Vec<Bracket>,
}

/// A synthetic frame of the walk: pose, SDR image and its ground truth.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthFrame {
    /// Hand-held pose, id `frame_XXX`.
    pub pose: Pose,
    /// What the 360° camera stored (locked exposure `path_gain`).
    pub sdr: SdrImage,
    /// True scene-linear radiance at the frame's pose.
    pub ground_truth: HdrImage,
}

/// A complete synthetic capture, in memory; [`SynthScene::write`] stores it in the
/// evaluation data's layout.
#[derive(Clone, Debug)]
pub struct SynthScene {
    /// The parameters it was made from.
    pub params: SynthParams,
    /// The room, to render more ground truth (e.g. at any other pose).
    pub room: Room,
    /// Probes `probe_00 …`.
    pub probes: Vec<SynthProbe>,
    /// Frames `frame_000 …`.
    pub frames: Vec<SynthFrame>,
    /// The camera response used for every SDR image.
    pub response: Response,
    /// Exposure gain of the walk and of the 0 EV bracket: `0.18 / median_luminance`.
    pub path_gain: f32,
    /// Largest pixel luminance over all probes and ground-truth frames.
    pub max_luminance: f32,
    /// Median pixel luminance over all probes and ground-truth frames.
    pub median_luminance: f32,
}

/// The documented camera response, `RationalGamma { 1.08, 0.08, 2.2 }`.
pub fn data_response() -> Response {
    Response::RationalGamma {
        scale: 1.08,
        knee: 0.08,
        gamma: 2.2,
    }
}

/// Simulates the README's camera on a scene-linear panorama: `x = gain · E`, plus
/// Gaussian noise with `sigma = 0.002 + 0.01 sqrt(x)` (seeded per row from
/// `noise_seed`, so the result is reproducible and parallel), then `response`, then
/// rounding to 8 bits.
pub fn simulate_sdr(hdr: &HdrImage, gain: f32, response: &Response, noise_seed: u64) -> SdrImage {
    let (w, h) = (hdr.width(), hdr.height());
    let mut out = SdrImage::new(w, h);
    if w == 0 || h == 0 {
        return out;
    }
    out.data_mut()
        .par_chunks_mut(3 * w)
        .zip(hdr.data().par_chunks(3 * w))
        .enumerate()
        .for_each(|(row, (dst, src))| {
            let mut rng = SplitMix64::new(derive(noise_seed, row as u64));
            for (o, &e) in dst.iter_mut().zip(src) {
                let x = gain * if e.is_finite() { e.max(0.0) } else { 0.0 };
                let sigma = 0.002 + 0.01 * x.sqrt();
                let xn = x + sigma * rng.gaussian() as f32;
                let code = response.encode(xn) * 255.0 + 0.5;
                *o = code.clamp(0.0, 255.0) as u8;
            }
        });
    out
}

/// Median of a slice of finite values (upper median for even lengths; 0 if empty).
fn median(mut v: Vec<f32>) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    *m
}

impl SynthScene {
    /// Renders the true panorama at `pose` with the scene's resolution and
    /// anti-aliasing: exactly the function that made every probe and ground truth.
    pub fn render(&self, pose: &Pose) -> HdrImage {
        self.room.render(
            pose.position_vec3(),
            pose.rotation(),
            self.params.width,
            self.params.height(),
            self.params.aa,
        )
    }

    /// Relative path of a probe's HDR file, as written in `poses.json`.
    pub fn probe_file(id: &str) -> String {
        format!("probes/{id}.exr")
    }

    /// Relative path of a probe bracket (`wide` for the 2-EV set).
    pub fn bracket_file(id: &str, ev: i32, wide: bool) -> String {
        if wide {
            format!("probes/{id}/wide/ev{ev:+}.jpg")
        } else {
            format!("probes/{id}/ev{ev:+}.jpg")
        }
    }

    /// Relative paths of a frame's SDR image and ground truth.
    pub fn frame_files(id: &str) -> (String, String) {
        (format!("path/{id}.jpg"), format!("path/{id}_gt.exr"))
    }

    /// The `poses.json` document, keyed exactly like the evaluation data's.
    pub fn poses_json(&self) -> serde_json::Value {
        use serde_json::json;
        let pose_json = |p: &Pose| {
            json!({
                "id": p.id,
                "position": p.position,
                "yaw_pitch_roll_deg": p.yaw_pitch_roll_deg,
                "world_from_camera": p.world_from_camera,
            })
        };
        let brackets_json = |id: &str, b: &[Bracket], wide: bool| -> Vec<serde_json::Value> {
            b.iter()
                .map(|b| {
                    json!({
                        "file": Self::bracket_file(id, b.ev, wide),
                        "ev": b.ev,
                        "exposure_time_s": b.exposure_time_s,
                    })
                })
                .collect()
        };
        let probes: Vec<serde_json::Value> = self
            .probes
            .iter()
            .map(|p| {
                let mut v = pose_json(&p.pose);
                let o = v.as_object_mut().expect("object");
                o.insert(
                    "brackets".into(),
                    brackets_json(&p.pose.id, &p.brackets, false).into(),
                );
                o.insert(
                    "brackets_wide".into(),
                    brackets_json(&p.pose.id, &p.brackets_wide, true).into(),
                );
                o.insert("hdr".into(), Self::probe_file(&p.pose.id).into());
                v
            })
            .collect();
        let frames: Vec<serde_json::Value> = self
            .frames
            .iter()
            .map(|f| {
                let mut v = pose_json(&f.pose);
                let (sdr, gt) = Self::frame_files(&f.pose.id);
                let o = v.as_object_mut().expect("object");
                o.insert("sdr".into(), sdr.into());
                o.insert("ground_truth".into(), gt.into());
                v
            })
            .collect();
        json!({
            "scene": self.params.name,
            "resolution": [self.params.width, self.params.height()],
            "probes": probes,
            "frames": frames,
            "camera": {
                "projection": "equirectangular",
                "pixel_to_camera_direction": "phi = (u - 0.5) * 2*pi, theta = (0.5 - v) * pi with u = (col + 0.5) / W, v = (row + 0.5) / H; d_cam = (cos(theta) sin(phi), sin(theta), -cos(theta) cos(phi)) in camera axes x right, y up, -z forward",
                "world_axes": "right-handed, z up (metres)",
                "world_from_camera": "3x3 rotation, world_direction = world_from_camera @ d_cam",
                "response": RESPONSE_TEXT,
                "path_gain": self.path_gain as f64,
                "bracket_gain_at_0ev": self.path_gain as f64,
                "bracket_base_exposure_time_s": BASE_EXPOSURE_TIME_S,
                "sdr_linear_from_8bit": "x = f^-1(code / 255) / path_gain gives scene radiance in the units of the ground-truth EXRs",
            },
            "stats": {
                "max_luminance": self.max_luminance as f64,
                "median_luminance": self.median_luminance as f64,
            },
        })
    }

    /// Writes the capture to `dir` in the evaluation data's layout: `poses.json`,
    /// `probes/probe_XX.exr` (+ `probes/probe_XX/ev±N.jpg` and `…/wide/ev±N.jpg`
    /// brackets), `path/frame_XXX.jpg` and `path/frame_XXX_gt.exr`. Every file is
    /// written atomically; `poses.json` last, so a complete file means a complete set.
    pub fn write(&self, dir: &Path) -> Result<()> {
        let mkdir = |p: PathBuf| std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e));
        mkdir(dir.join("path"))?;
        mkdir(dir.join("probes"))?;
        for p in &self.probes {
            if !p.brackets.is_empty() {
                mkdir(dir.join("probes").join(&p.pose.id))?;
            }
            if !p.brackets_wide.is_empty() {
                mkdir(dir.join("probes").join(&p.pose.id).join("wide"))?;
            }
        }

        enum Job<'a> {
            Hdr(PathBuf, &'a HdrImage),
            Sdr(PathBuf, &'a SdrImage),
        }
        let mut jobs = Vec::new();
        for p in &self.probes {
            let id = &p.pose.id;
            jobs.push(Job::Hdr(dir.join(Self::probe_file(id)), &p.hdr));
            for b in &p.brackets {
                jobs.push(Job::Sdr(
                    dir.join(Self::bracket_file(id, b.ev, false)),
                    &b.image,
                ));
            }
            for b in &p.brackets_wide {
                jobs.push(Job::Sdr(
                    dir.join(Self::bracket_file(id, b.ev, true)),
                    &b.image,
                ));
            }
        }
        for f in &self.frames {
            let (sdr, gt) = Self::frame_files(&f.pose.id);
            jobs.push(Job::Sdr(dir.join(sdr), &f.sdr));
            jobs.push(Job::Hdr(dir.join(gt), &f.ground_truth));
        }
        jobs.par_iter().try_for_each(|job| match job {
            Job::Hdr(path, img) => crate::image::io::write_hdr(path, img),
            Job::Sdr(path, img) => crate::image::io::write_sdr(path, img),
        })?;

        let text = serde_json::to_string_pretty(&self.poses_json())
            .map_err(|e| Error::Invalid(format!("poses.json: {e}")))?;
        crate::fsutil::write_atomic(&dir.join("poses.json"), text.as_bytes())
    }
}

/// Makes a whole synthetic capture from `params`: lays out probe and frame poses,
/// generates the room around them, renders every probe and ground-truth frame, picks
/// the exposure `path_gain = 0.18 / median` (as the data does), and simulates the
/// SDR frames and probe brackets. Deterministic in `params`.
pub fn synthesize(params: &SynthParams) -> SynthScene {
    let (w, h) = (params.width.max(2), params.height());
    let mut params = params.clone();
    params.width = w;
    let size = params.room_size.map(|v| v.max(1.0) as f64);

    let mut layout_rng = SplitMix64::new(derive(params.seed, 1));
    let layout = pose::make_layout(&mut layout_rng, size, params.n_probes, params.n_frames);
    let cams: Vec<glam::Vec3> = layout
        .probes
        .iter()
        .chain(&layout.frames)
        .map(|p| p.position_vec3())
        .collect();
    let mut room_rng = SplitMix64::new(derive(params.seed, 2));
    let room = Room::generate(&params, &mut room_rng, &cams);

    let render = |p: &Pose| room.render(p.position_vec3(), p.rotation(), w, h, params.aa);
    let probe_hdr: Vec<HdrImage> = layout.probes.iter().map(render).collect();
    let frame_gt: Vec<HdrImage> = layout.frames.iter().map(render).collect();

    let lums: Vec<f32> = probe_hdr
        .iter()
        .chain(&frame_gt)
        .flat_map(|img| img.pixels().map(luminance))
        .collect();
    let max_luminance = lums.iter().copied().fold(0.0f32, f32::max);
    let median_luminance = median(lums);
    let path_gain = 0.18 / median_luminance.max(1e-6);
    let response = data_response();

    let bracket_set = |i: usize, hdr: &HdrImage, evs: &[i32], wide: bool| -> Vec<Bracket> {
        if !params.brackets {
            return Vec::new();
        }
        evs.iter()
            .map(|&ev| {
                let label = 0x1_0000
                    + ((i as u64) << 8)
                    + ((ev + 64) as u64)
                    + if wide { 0x8000 } else { 0 };
                Bracket {
                    ev,
                    exposure_time_s: BASE_EXPOSURE_TIME_S * 2f64.powi(ev),
                    image: simulate_sdr(
                        hdr,
                        path_gain * 2f32.powi(ev),
                        &response,
                        derive(params.seed, label),
                    ),
                }
            })
            .collect()
    };
    let probes: Vec<SynthProbe> = layout
        .probes
        .into_iter()
        .zip(probe_hdr)
        .enumerate()
        .map(|(i, (pose, hdr))| SynthProbe {
            brackets: bracket_set(i, &hdr, &BRACKET_EVS, false),
            brackets_wide: bracket_set(i, &hdr, &WIDE_BRACKET_EVS, true),
            pose,
            hdr,
        })
        .collect();
    let frames: Vec<SynthFrame> = layout
        .frames
        .into_iter()
        .zip(frame_gt)
        .enumerate()
        .map(|(j, (pose, gt))| SynthFrame {
            sdr: simulate_sdr(
                &gt,
                path_gain,
                &response,
                derive(params.seed, 0x2_0000 + j as u64),
            ),
            pose,
            ground_truth: gt,
        })
        .collect();

    SynthScene {
        params,
        room,
        probes,
        frames,
        response,
        path_gain,
        max_luminance,
        median_luminance,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sphere;
    use std::sync::OnceLock;

    fn small() -> SynthParams {
        SynthParams {
            width: 128,
            ..SynthParams::default()
        }
    }

    /// The default scene, made once for all tests that only read it.
    fn default_scene() -> &'static SynthScene {
        static S: OnceLock<SynthScene> = OnceLock::new();
        S.get_or_init(|| synthesize(&SynthParams::default()))
    }

    fn lum_median_max(img: &HdrImage) -> (f32, f32) {
        let l: Vec<f32> = img.pixels().map(luminance).collect();
        let max = l.iter().copied().fold(0.0, f32::max);
        (median(l), max)
    }

    #[test]
    fn same_seed_same_scene_other_seed_other_scene() {
        let a = synthesize(&small());
        let b = synthesize(&small());
        assert_eq!(a.probes, b.probes);
        assert_eq!(a.frames, b.frames);
        assert_eq!(a.path_gain, b.path_gain);
        let c = synthesize(&SynthParams { seed: 2, ..small() });
        assert_ne!(a.frames[0].ground_truth, c.frames[0].ground_truth);
        assert_ne!(a.probes[0].pose, c.probes[0].pose);
    }

    #[test]
    fn ground_truth_is_high_dynamic_range() {
        let s = default_scene();
        assert_eq!(s.probes.len(), 3);
        assert_eq!(s.frames.len(), 6);
        for f in &s.frames {
            let gt = &f.ground_truth;
            assert_eq!((gt.width(), gt.height()), (256, 128));
            assert_eq!(gt.count_invalid(), 0);
            let (med, max) = lum_median_max(gt);
            assert!(max / med > 100.0, "{}: max {max} median {med}", f.pose.id);
        }
        assert!(
            (0.2..1.5).contains(&s.median_luminance),
            "median {}",
            s.median_luminance
        );
        let ratio = s.max_luminance / s.median_luminance;
        assert!((150.0..2000.0).contains(&ratio), "max/median {ratio}");
        assert!((s.path_gain * s.median_luminance - 0.18).abs() < 1e-4);
    }

    #[test]
    fn sdr_frames_clip_at_lamps_but_are_well_exposed() {
        let s = default_scene();
        for f in &s.frames {
            let px: Vec<[u8; 3]> = f
                .sdr
                .data()
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect();
            let n = px.len() as f32;
            let white = px.iter().filter(|c| c.iter().all(|&v| v == 255)).count() as f32;
            let black = px.iter().filter(|c| c.iter().all(|&v| v <= 5)).count() as f32;
            let mean: f32 = px
                .iter()
                .map(|c| (c[0] as f32 + c[1] as f32 + c[2] as f32) / 3.0)
                .sum::<f32>()
                / n;
            assert!(white > 0.0, "{}: no clipped lamp", f.pose.id);
            assert!(white / n < 0.08, "{}: {} clipped", f.pose.id, white / n);
            assert!(black / n < 0.05, "{}: {} black", f.pose.id, black / n);
            assert!(
                (50.0..200.0).contains(&mean),
                "{}: mean code {mean}",
                f.pose.id
            );
        }
        // The linearised SDR agrees with the ground truth where it does not clip.
        let f = &s.frames[0];
        let lut = s.response.decode_lut();
        let mut errs = Vec::new();
        for (c, e) in f.sdr.data().iter().zip(f.ground_truth.data()) {
            if (20..235).contains(c) {
                let est = lut[*c as usize] / s.path_gain;
                errs.push(((est + 1e-3) / (e + 1e-3)).ln().abs());
            }
        }
        let med = median(errs);
        assert!(med < 0.05, "median |log ratio| {med}");
    }

    #[test]
    fn brackets_follow_exposure() {
        let s = default_scene();
        let p = &s.probes[0];
        assert_eq!(p.brackets.len(), 7);
        assert_eq!(p.brackets_wide.len(), 8);
        let mean = |img: &SdrImage| {
            img.data().iter().map(|&v| v as f64).sum::<f64>() / img.data().len() as f64
        };
        for w in p.brackets.windows(2) {
            assert!(mean(&w[1].image) > mean(&w[0].image));
            assert!((w[1].exposure_time_s / w[0].exposure_time_s - 2.0).abs() < 1e-12);
        }
        // At -12 EV the lamps are measured, not clipped.
        let darkest = &p.brackets_wide[0].image;
        assert!(darkest.data().iter().all(|&v| v < 255));
    }

    #[test]
    fn rendering_a_frame_pose_reproduces_its_ground_truth() {
        let s = synthesize(&small());
        for f in &s.frames {
            assert_eq!(s.render(&f.pose), f.ground_truth);
        }
        for p in &s.probes {
            assert_eq!(s.render(&p.pose), p.hdr);
        }
        // A tripod pose at a frame's position, rotated into the frame's orientation
        // with the crate's own convention (r = R_p^T R_f), matches the frame.
        let f = &s.frames[2];
        let tripod = Pose::new("t", f.pose.position, [37.0, 0.0, 0.0]);
        let img = s.render(&tripod);
        let r = tripod.rotation().transpose() * f.pose.rotation();
        let rotated = sphere::rotate(&img, r, img.width(), img.height());
        let (w, h) = (img.width(), img.height());
        let mut errs = Vec::new();
        for y in h / 8..h - h / 8 {
            for x in 0..w {
                let a = luminance(rotated.get(x, y));
                let b = luminance(f.ground_truth.get(x, y));
                errs.push(((a + 0.01) / (b + 0.01)).ln().abs());
            }
        }
        let med = median(errs);
        assert!(med < 0.1, "median |log ratio| after rotation {med}");
    }

    #[test]
    fn poses_json_round_trips_with_the_data_layout() {
        let s = synthesize(&SynthParams {
            width: 64,
            ..SynthParams::default()
        });
        let dir = tempfile::tempdir().unwrap();
        s.write(dir.path()).unwrap();
        let text = std::fs::read_to_string(dir.path().join("poses.json")).unwrap();
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        for key in ["scene", "resolution", "probes", "frames", "camera", "stats"] {
            assert!(v.get(key).is_some(), "missing {key}");
        }
        assert_eq!(v["resolution"], serde_json::json!([64, 32]));
        let cam = &v["camera"];
        let resp = Response::parse(cam["response"].as_str().unwrap()).unwrap();
        assert_eq!(resp, data_response());
        assert_eq!(cam["path_gain"].as_f64().unwrap() as f32, s.path_gain);
        assert_eq!(cam["projection"], "equirectangular");

        let check_rot = |e: &serde_json::Value| {
            let m: Vec<Vec<f64>> = serde_json::from_value(e["world_from_camera"].clone()).unwrap();
            for i in 0..3 {
                for j in 0..3 {
                    let dot: f64 = (0..3).map(|k| m[i][k] * m[j][k]).sum();
                    let want = if i == j { 1.0 } else { 0.0 };
                    assert!((dot - want).abs() < 1e-9, "{}: not orthonormal", e["id"]);
                }
            }
            let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
                - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
                + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
            assert!((det - 1.0).abs() < 1e-9);
        };
        let probes = v["probes"].as_array().unwrap();
        assert_eq!(probes.len(), 3);
        for (e, p) in probes.iter().zip(&s.probes) {
            check_rot(e);
            assert_eq!(e["id"], p.pose.id.as_str());
            let pos: [f64; 3] = serde_json::from_value(e["position"].clone()).unwrap();
            assert_eq!(pos, p.pose.position);
            let m: [[f64; 3]; 3] = serde_json::from_value(e["world_from_camera"].clone()).unwrap();
            assert_eq!(m, p.pose.world_from_camera);
            // Probes: yaw about world z only, camera y is world z.
            assert!((m[2][1] - 1.0).abs() < 1e-12);
            let hdr_path = dir.path().join(e["hdr"].as_str().unwrap());
            let back = crate::image::io::read_hdr(&hdr_path).unwrap();
            assert_eq!(back, p.hdr);
            for b in e["brackets"]
                .as_array()
                .unwrap()
                .iter()
                .chain(e["brackets_wide"].as_array().unwrap())
            {
                assert!(dir.path().join(b["file"].as_str().unwrap()).is_file());
            }
        }
        let frames = v["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 6);
        for (e, f) in frames.iter().zip(&s.frames) {
            check_rot(e);
            let sdr =
                crate::image::io::read_sdr(&dir.path().join(e["sdr"].as_str().unwrap())).unwrap();
            assert_eq!((sdr.width(), sdr.height()), (64, 32));
            let gt =
                crate::image::io::read_hdr(&dir.path().join(e["ground_truth"].as_str().unwrap()))
                    .unwrap();
            assert_eq!(gt, f.ground_truth);
        }
        let st = &v["stats"];
        assert_eq!(
            st["median_luminance"].as_f64().unwrap() as f32,
            s.median_luminance
        );
        assert_eq!(
            st["max_luminance"].as_f64().unwrap() as f32,
            s.max_luminance
        );

        // The crate's own loader reads it without complaint and gets the same poses.
        let scene = crate::scene::Scene::load(dir.path()).unwrap();
        assert!(scene.warnings.is_empty(), "{:?}", scene.warnings);
        assert_eq!(scene.response, data_response());
        assert_eq!(scene.path_gain, s.path_gain);
        assert_eq!(scene.probes.len(), s.probes.len());
        assert_eq!(scene.frames.len(), s.frames.len());
        for (a, b) in scene.frames.iter().zip(&s.frames) {
            assert_eq!(a.id, b.pose.id);
            assert_eq!(a.pose.position, b.pose.position_vec3());
            assert!(a
                .pose
                .world_from_camera
                .abs_diff_eq(b.pose.rotation(), 1e-6));
            assert!(a.ground_truth.as_ref().unwrap().is_file());
        }
        for (a, b) in scene.probes.iter().zip(&s.probes) {
            assert_eq!(a.pose.position, b.pose.position_vec3());
            assert!(a
                .pose
                .world_from_camera
                .abs_diff_eq(b.pose.rotation(), 1e-6));
            assert_eq!(a.brackets.len(), 7);
        }
    }

    #[test]
    fn image_centre_looks_along_world_from_camera_forward() {
        let s = synthesize(&small());
        let f = &s.frames[1];
        let rot = f.pose.rotation();
        // The straight-ahead world direction maps back to the panorama centre.
        let (u, v) = sphere::dir_to_uv(rot.transpose() * f.pose.forward());
        assert!((u - 0.5).abs() < 1e-5 && (v - 0.5).abs() < 1e-5);

        // Aim a camera at the frame's position at a lamp: the centre pixels
        // see the lamp; aim it at the floor: they see something dim.
        let pos = f.pose.position_vec3();
        let (w, h) = (s.params.width, s.params.height());
        let centre = |img: &HdrImage| -> f32 {
            let mut sum = 0.0;
            for (x, y) in [
                (w / 2 - 1, h / 2 - 1),
                (w / 2, h / 2 - 1),
                (w / 2 - 1, h / 2),
                (w / 2, h / 2),
            ] {
                sum += luminance(img.get(x, y));
            }
            sum / 4.0
        };
        // Roll 0: with this convention roll would tilt a pitched view direction.
        let roll = 0.0;
        for lamp in s.room.lamp_centres() {
            let d = lamp - pos;
            let yaw = pose::yaw_towards(d.x as f64, d.y as f64);
            let pitch = (d.z as f64)
                .atan2((d.x as f64).hypot(d.y as f64))
                .to_degrees();
            let aimed = Pose::new("aim", f.pose.position, [yaw, pitch, roll]);
            assert!((aimed.forward() - d.normalize()).length() < 1e-4);
            let img = s.render(&aimed);
            let c = centre(&img);
            assert!(c > 50.0, "lamp at {lamp} seen as {c}");
            // The exact straight-ahead radiance is the lamp too.
            assert!(luminance(s.room.radiance(pos, aimed.forward())) > 50.0);
        }
        let down = Pose::new("down", f.pose.position, [10.0, -89.0, roll]);
        assert!(centre(&s.render(&down)) < 5.0);
    }

    #[test]
    fn default_synthesis_is_fast() {
        let t = std::time::Instant::now();
        let s = synthesize(&SynthParams::default());
        let dt = t.elapsed();
        eprintln!(
            "synthesize(default): {:.3} s, median {:.3}, max {:.1}, gain {:.3}",
            dt.as_secs_f64(),
            s.median_luminance,
            s.max_luminance,
            s.path_gain
        );
        // Generous bound: tests may share the machine with other builds.
        assert!(dt.as_secs_f64() < 20.0);
    }
}
