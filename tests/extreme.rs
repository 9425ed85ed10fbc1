//! Stiff and extreme inputs (issue 7, item 2): a sun a million times the median
//! through every stage, black and saturated frames, NaN / infinite / negative
//! samples, featureless faces, frames at, far from and between coincident probes,
//! tiny and odd panorama sizes, non-orthonormal poses; plus property tests
//! (proptest) of the numeric kernels.
//!
//! Already covered elsewhere, and only extended here where something was missing:
//! * merge of a sun that clips in every bracket (lower bound, report):
//!   `tests/merge.rs` `clipped_sun_is_reported_as_a_lower_bound` and
//!   `tiny_sun_with_jpeg_softened_codes_is_at_least_the_clamp`; here the merged sun
//!   is followed through the methods, prefilter and render.
//! * all-black and all-saturated brackets: `tests/merge.rs` `saturated_and_black_sets`.
//! * brackets out of order or duplicated: `tests/merge.rs`
//!   `order_duplicates_and_single_exposures`; here only a bracket made of nothing
//!   but copies of one exposure.
//! * half-float overflow on EXR write: `tests/io_formats.rs`
//!   `exr_half_overflow_is_an_error_or_an_explicit_clamp` and
//!   `non_finite_samples_are_never_written`; here only negative overflow.
//! * prefilter fireflies from a 1e6 sun: `tests/ibl.rs`
//!   `sun_of_a_million_times_the_median_makes_no_fireflies`; fusion of a 1e6 sun
//!   in isolation: `src/fusion/mod.rs`
//!   `a_sun_a_million_times_the_median_stays_finite_and_keeps_its_power`.
//! * negative probe samples in `prefilter_to_dir`: `tests/ibl.rs`
//!   `invalid_probes_and_directories_are_clear_errors`; NaN in the metrics:
//!   `src/eval/mod.rs` `invalid_samples_are_counted_and_repaired`.
//! * a flat (featureless) frame and a white frame in the warp method:
//!   `src/warp/mod.rs` `textureless_frame_falls_back_cleanly` and
//!   `saturated_frame_takes_the_light_from_the_probe`; here featureless *probe*
//!   faces.
//! * slightly non-orthonormal and singular poses in `poses.json`:
//!   `src/scene/mod.rs` `parses_and_repairs_rotation`, `bad_scenes_name_file_and_problem`.
//! * SH rotation at fixed rotations: `src/ibl/sh.rs`
//!   `rotation_matches_pointwise_evaluation`, `rotation_is_equivariant_with_panorama_rotation`;
//!   equirect/cube round trip at one size: `src/sphere/cube.rs`
//!   `equirect_cube_equirect_round_trip`.
//!
//! What each entry point does with NaN, infinite or negative samples (asserted in
//! `invalid_samples_are_rejected_or_repaired_and_said_so`, except `write_hdr` and
//! `eval::compare`, whose tests are listed above):
//! * `image::io::read_hdr`: returns the samples as stored (a reader is lossless);
//!   every consumer below decides.
//! * `image::io::write_hdr`: NaN / infinite refused, naming the file and the count
//!   (`tests/io_formats.rs` `non_finite_samples_are_never_written`).
//! * `pipeline::run` (`load_probe`): repaired (NaN and negatives to 0, +inf to the
//!   largest finite sample), counted in `FrameRecord::repaired_pixels` of every
//!   probe the frame used.
//! * `warp::warp_frame`, `flow::method::flow_frame`, `fusion::fuse`: rejected with
//!   `Error::Invalid` naming the input and the count (in memory there is no file
//!   to name; repair first with `HdrImage::repair_invalid` if that is acceptable).
//! * `ibl::prefilter_to_dir`: rejected with `Error::Format` naming the file;
//!   `ibl::Prefiltered::from_env`: rejected with `Error::Invalid`.
//! * `eval::compare`: repaired, counted in `Metrics::invalid_pixels`.
//! * `render::render`: an environment answering NaN / infinite / negative
//!   radiance still gives finite, non-negative pixels.
//!
//! Sizes: the geometry (cube faces, rotation, SH projection), the metrics, the
//! warp method and fusion work at any size down to 1x1; the flow method needs
//! what DIS needs (8 pixels in each dimension, 12 in one, after the seam
//! padding) and otherwise fails with an error naming the size; prefiltering
//! refuses probes under 8x4 (`ibl::export::MIN_PROBE_SIZE`), naming the size.
//!
//! Poses: `Scene::parse` re-orthonormalises a rotation that is off (with a
//! warning giving the deviation) and rejects singular, non-finite and mirrored
//! (determinant < 0) matrices with an error naming the file and the entry. The
//! in-memory methods take `Pose` as given; a non-rotation there still gives a
//! finite output.

use glam::{Mat3, Vec3};
use lumiprobe::capture::merge::{merge, Exposure, MergeOptions, SATURATED};
use lumiprobe::capture::ResponseCurve;
use lumiprobe::eval;
use lumiprobe::flow::method::{flow_frame, FlowMethodParams, Source};
use lumiprobe::fusion::{clip_mask, components, fuse, FusionParams, Measured};
use lumiprobe::ibl::{
    prefilter_specular, prefilter_to_dir, FaceLayout, PrefilterOptions, Prefiltered, Sh9, ShWindow,
    SpecularOptions,
};
use lumiprobe::image::io::{self, exr, ExrWriteOptions, Overflow};
use lumiprobe::image::{luminance, HdrImage, SdrImage};
use lumiprobe::pipeline::{self, Method, RunParams};
use lumiprobe::render::{render, Background, Camera, Material, Model, RenderOptions};
use lumiprobe::scene::{Frame, Pose, Probe, Scene};
use lumiprobe::sphere::cube::{cube_to_equirect, equirect_to_cube};
use lumiprobe::sphere::{pixel_solid_angle, pixel_to_dir, rotate, ypr_to_mat};
use lumiprobe::synth::{simulate_sdr, synthesize, SynthParams, SynthScene};
use lumiprobe::warp::{warp_frame, PreparedProbe, ProbeTonemap, WarpParams};
use lumiprobe::Error;
use proptest::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Arc;

// ---------------------------------------------------------------------------
// Helpers.

/// A small synthetic room: `n_probes` probes and one frame, no brackets.
fn small_world(width: usize, n_probes: usize, seed: u64) -> SynthScene {
    synthesize(&SynthParams {
        width,
        n_probes,
        n_frames: 1,
        seed,
        aa: 1,
        brackets: false,
        name: "extreme".into(),
        ..Default::default()
    })
}

fn pose_of(p: &lumiprobe::synth::Pose) -> Pose {
    Pose {
        position: p.position_vec3(),
        world_from_camera: p.rotation(),
    }
}

/// The synthetic capture as an in-memory [`Scene`] (no files).
fn scene_of(s: &SynthScene) -> Scene {
    Scene {
        root: PathBuf::from("/nonexistent"),
        name: "extreme".into(),
        probes: s
            .probes
            .iter()
            .map(|p| Probe {
                id: p.pose.id.clone(),
                pose: pose_of(&p.pose),
                hdr: None,
                brackets: Vec::new(),
                brackets_wide: Vec::new(),
            })
            .collect(),
        frames: s
            .frames
            .iter()
            .map(|f| Frame {
                id: f.pose.id.clone(),
                pose: pose_of(&f.pose),
                sdr: PathBuf::from(format!("/nonexistent/{}.png", f.pose.id)),
                ground_truth: None,
                gain: None,
            })
            .collect(),
        response: s.response.clone(),
        path_gain: s.path_gain,
        probe_unit: "as given (in memory)".into(),
        warnings: Vec::new(),
        vignetting: None,
    }
}

type Prediction = (
    HdrImage,
    Option<lumiprobe::warp::WarpReport>,
    Option<lumiprobe::flow::method::FlowReport>,
    Option<lumiprobe::fusion::FusionReport>,
);

/// Runs `method` on frame `fi` of `scene` with the SDR image `sdr` and the probe
/// panoramas `probes` (in the scene's probe order), all in memory.
fn predict(
    scene: &Scene,
    fi: usize,
    sdr: &SdrImage,
    probes: &[HdrImage],
    method: Method,
) -> lumiprobe::Result<Prediction> {
    let params = RunParams {
        method,
        ..Default::default()
    };
    let prepared: Vec<Arc<PreparedProbe>> = probes
        .iter()
        .zip(&scene.probes)
        .map(|(img, p)| {
            Arc::new(PreparedProbe::new(
                Arc::new(img.clone()),
                p.pose,
                params.warp.probe_tonemap,
                &scene.response,
                scene.path_gain,
            ))
        })
        .collect();
    let get = |i: usize| -> lumiprobe::Result<(Arc<PreparedProbe>, usize)> {
        Ok((prepared[i].clone(), 0))
    };
    let frame = &scene.frames[fi];
    let mut used = scene.probes_by_distance(frame.pose.position);
    used.truncate(method.probes_needed());
    let lin = pipeline::linearize(sdr, scene, frame);
    let pairs = pipeline::LightPairs::default();
    let access = pipeline::ProbeAccess {
        get: &get,
        pairs: &pairs,
    };
    pipeline::predict_frame(scene, frame, sdr, &lin, &used, access, &params)
}

const METHODS: [Method; 4] = [Method::Warp, Method::Flow, Method::Hybrid, Method::Fusion];

fn channel_max(img: &HdrImage) -> f32 {
    img.data().iter().copied().fold(0.0f32, f32::max)
}

/// `sum L dOmega` (luminance) over the pixels whose direction is within `deg`
/// degrees of `d`.
fn power_near(img: &HdrImage, d: Vec3, deg: f32) -> f64 {
    let (w, h) = (img.width(), img.height());
    let c = deg.to_radians().cos();
    let mut s = 0.0f64;
    for y in 0..h {
        let da = pixel_solid_angle(y, w, h) as f64;
        for x in 0..w {
            if pixel_to_dir(x, y, w, h).dot(d) >= c {
                s += luminance(img.get(x, y)) as f64 * da;
            }
        }
    }
    s
}

/// Brute-force irradiance `sum L max(0, n.d) dOmega` (luminance).
fn irradiance_brute(img: &HdrImage, n: Vec3) -> f64 {
    let (w, h) = (img.width(), img.height());
    let mut s = 0.0f64;
    for y in 0..h {
        let da = pixel_solid_angle(y, w, h) as f64;
        for x in 0..w {
            let c = pixel_to_dir(x, y, w, h).dot(n).max(0.0) as f64;
            s += luminance(img.get(x, y)) as f64 * c * da;
        }
    }
    s
}

/// Paints a disc of `radius_deg` around the world direction `sun` into a
/// panorama taken with rotation `world_from_camera`.
fn paint_sun(
    img: &mut HdrImage,
    world_from_camera: Mat3,
    sun: Vec3,
    radiance: f32,
    radius_deg: f32,
) {
    let (w, h) = (img.width(), img.height());
    let c = radius_deg.to_radians().cos();
    for y in 0..h {
        for x in 0..w {
            if (world_from_camera * pixel_to_dir(x, y, w, h)).dot(sun) >= c {
                img.set(x, y, [radiance; 3]);
            }
        }
    }
}

fn small_prefilter_opts() -> PrefilterOptions {
    PrefilterOptions {
        specular: SpecularOptions {
            face_size: 16,
            mip_count: 4,
            samples: 64,
        },
        irradiance_face_size: 8,
        lut_size: 16,
        lut_samples: 32,
        sh_window: ShWindow::None,
        layout: FaceLayout::Faces,
    }
}

fn assert_finite(img: &HdrImage, what: &str) {
    assert_eq!(
        img.count_invalid(),
        0,
        "{what}: NaN, infinite or negative samples"
    );
}

// ---------------------------------------------------------------------------
// A sun of a million times the median luminance through every stage.

/// A directional sun of 1e6 times the median luminance (a disc of 3° radius, a
/// few pixels at 128x64) added to a small synthetic room: to both probes, to the
/// frame's ground truth and so to its SDR image, where it clips.
///
/// * merge: a -3..+3 EV bracket of the probe clips the sun in every frame; the
///   merged sun is finite, flagged saturated, at least the clamp value
///   (`exp g(255) / t_min`) and at most the true radiance (a lower bound).
/// * warp, flow, hybrid, fusion (fed the true probes): no NaN / infinite /
///   negative sample. No fireflies: warp, flow and hybrid only resample and
///   select, so no sample exceeds the brightest source sample; fusion transfers
///   the sun's power into the frame's fully clipped pixels, which may
///   concentrate it (here 3x the source radiance) but no texel may carry more
///   than the whole sun's power, and fusion never goes below the clip level
///   where the frame clipped. Energy: the power within 8° of the sun within 25%
///   of the ground truth's for warp (which resamples the probe) and fusion
///   (which restores the clipped light). Flow and hybrid are only held to the
///   bounds above: their flow drags the small sun disc with the parallax of the
///   walls around it in both warped probes, and the graph cut then keeps the
///   frame's white (a lower bound) there, losing the sun; fusion is the method
///   that restores it.
/// * prefilter (of the fusion output): every mip finite and never above the
///   environment's maximum; the SH irradiance towards the sun within 10% of the
///   brute-force integral (an order-2 SH overestimates a point light by 1/16 there).
/// * render of a white Lambertian sphere: finite, no pixel above the
///   environment's maximum, the point facing the sun within 25% of
///   `albedo E(n) / pi`, and the side facing away at least 100 times darker.
#[test]
fn sun_of_a_million_times_the_median_through_every_stage() {
    let mut s = small_world(128, 2, 11);
    let sun = Vec3::new(0.3, -0.4, 0.8).normalize(); // world, z up
    let sun_l = 1e6 * s.median_luminance;
    for p in &mut s.probes {
        let r = p.pose.rotation();
        paint_sun(&mut p.hdr, r, sun, sun_l, 3.0);
    }
    let f = &mut s.frames[0];
    paint_sun(&mut f.ground_truth, f.pose.rotation(), sun, sun_l, 3.0);
    f.sdr = simulate_sdr(&f.ground_truth, s.path_gain, &s.response, 5);
    let scene = scene_of(&s);
    let probes: Vec<HdrImage> = s.probes.iter().map(|p| p.hdr.clone()).collect();
    let gt = &s.frames[0].ground_truth;
    let sun_cam = s.frames[0].pose.rotation().transpose() * sun;
    let true_power = power_near(gt, sun_cam, 8.0);
    let source_max = probes.iter().map(channel_max).fold(0.0f32, f32::max);

    // Merge.
    let t0 = lumiprobe::synth::BASE_EXPOSURE_TIME_S;
    let exps: Vec<Exposure> = (-3..=3)
        .map(|ev: i32| Exposure {
            name: PathBuf::from(format!("ev{ev:+}.jpg")),
            image: simulate_sdr(
                &probes[0],
                s.path_gain * 2f32.powi(ev),
                &s.response,
                (100 + ev) as u64,
            ),
            time_s: t0 * 2f64.powi(ev),
        })
        .collect();
    let curve = ResponseCurve::from_response(&s.response);
    let m = merge(&exps, &curve, &MergeOptions::default()).unwrap();
    assert!(m.image.data().iter().all(|v| v.is_finite() && *v >= 0.0));
    let t_min = exps[0].time_s;
    let to_radiance = (t0 / s.path_gain as f64) as f32; // merged units -> scene radiance
    let (w, h) = (128usize, 64usize);
    let r0 = s.probes[0].pose.rotation();
    let mut sun_px = 0;
    for y in 0..h {
        for x in 0..w {
            if (r0 * pixel_to_dir(x, y, w, h)).dot(sun) < 3f32.to_radians().cos() {
                continue;
            }
            sun_px += 1;
            assert!(
                m.flags[y * w + x] & SATURATED != 0,
                "sun pixel {x},{y} not flagged"
            );
            for c in 0..3 {
                let v = m.image.get(x, y)[c];
                let clamp = (curve.g[c][255].exp() / t_min) as f32;
                assert!(
                    v >= clamp * (1.0 - 1e-5),
                    "merged sun {v} below the clamp {clamp}"
                );
                assert!(v * to_radiance <= sun_l, "merged sun above the truth");
            }
        }
    }
    assert!(sun_px >= 3, "the sun covers {sun_px} pixels");
    assert!(m.report.clipped_light_share > 0.0 && m.report.clipped_light_share <= 1.0);

    // The methods.
    let white = s.response.decode(1.0) / s.path_gain;
    let (w, h) = (128, 64);
    let sdr = &s.frames[0].sdr;
    let mut fusion_out = None;
    for method in METHODS {
        let (out, ..) = predict(&scene, 0, sdr, &probes, method).unwrap();
        assert_finite(&out, &format!("{method:?}"));
        let p = power_near(&out, sun_cam, 8.0);
        let mx = channel_max(&out);
        println!("{method:?}: sun power {p:.4e} vs truth {true_power:.4e}, max {mx:.4e}");
        if method == Method::Fusion {
            for y in 0..h {
                let da = pixel_solid_angle(y, w, h) as f64;
                for x in 0..w {
                    let (c, o) = (sdr.get(x, y), out.get(x, y));
                    // Never below what the frame measured where it clipped.
                    for k in 0..3 {
                        if c[k] == 255 {
                            assert!(
                                o[k] >= white * 0.999,
                                "fusion: {o:?} below the clip at {x},{y}"
                            );
                        }
                    }
                    // Power transfer may concentrate an unresolved light in fewer
                    // pixels than the probe spread it over, but never gives one
                    // texel more than all of the sun's power.
                    let pw = luminance(o) as f64 * da;
                    assert!(
                        pw <= 1.1 * true_power,
                        "fusion: texel {x},{y} carries {pw}, the sun {true_power}"
                    );
                }
            }
        } else {
            assert!(
                mx <= source_max * 1.0001,
                "{method:?}: firefly {mx} above the source maximum {source_max}"
            );
        }
        if matches!(method, Method::Warp | Method::Fusion) {
            assert!(
                (p / true_power - 1.0).abs() < 0.25,
                "{method:?}: sun power {p} vs truth {true_power}"
            );
        }
        if method == Method::Fusion {
            fusion_out = Some(out);
        }
    }

    // Prefilter the fusion output.
    let env = fusion_out.unwrap();
    let env_max = channel_max(&env);
    let pre = Prefiltered::from_env(&env, &small_prefilter_opts()).unwrap();
    for mip in &pre.specular.mips {
        for face in &mip.faces {
            assert_finite(face, "specular mip");
            assert!(channel_max(face) <= env_max * 1.0001, "specular firefly");
        }
    }
    for face in &pre.irradiance {
        assert!(face.data().iter().all(|v| v.is_finite()));
    }
    let e_sh = luminance(pre.irradiance(sun_cam)) as f64;
    let e_true = irradiance_brute(&env, sun_cam);
    println!("irradiance towards the sun: SH {e_sh:.4e}, brute force {e_true:.4e}");
    assert!((e_sh / e_true - 1.0).abs() < 0.1, "{e_sh} vs {e_true}");

    // Render a white Lambertian sphere lit by it.
    let cam = Camera {
        eye: sun_cam.cross(Vec3::Y).normalize() * 3.0,
        target: Vec3::ZERO,
        up: Vec3::Y,
        vfov_deg: 45.0,
        width: 48,
        height: 48,
    };
    let model = Model::uv_sphere(1.0, 48, Material::basic([0.8; 3], 0.0, 1.0));
    let opts = RenderOptions {
        background: Background::Transparent,
        supersample: 1,
        lights: Vec::new(),
    };
    let out = render(&model, &pre, &cam, &opts).unwrap();
    assert_finite(&out.color, "render");
    assert!(channel_max(&out.color) <= env_max * 1.0001);
    // Normals of covered pixels, from the ray / unit-sphere hit.
    let fwd = (cam.target - cam.eye).normalize();
    let right = fwd.cross(cam.up).normalize();
    let up = right.cross(fwd);
    let focal = 0.5 * cam.height as f32 / (0.5 * cam.vfov_deg.to_radians()).tan();
    let (mut lit, mut dark) = (None::<(f32, f32, Vec3)>, None::<(f32, f32)>);
    for y in 0..cam.height {
        for x in 0..cam.width {
            let d = (fwd * focal
                + right * (x as f32 + 0.5 - 0.5 * cam.width as f32)
                + up * (0.5 * cam.height as f32 - y as f32 - 0.5))
                .normalize();
            let b = cam.eye.dot(d);
            let disc = b * b - (cam.eye.length_squared() - 1.0);
            if disc <= 0.05 || out.alpha[y * cam.width + x] < 1.0 {
                continue;
            }
            let n = (cam.eye + d * (-b - disc.sqrt())).normalize();
            let c = n.dot(sun_cam);
            let v = luminance(out.color.get(x, y));
            if lit.map_or(true, |l| c > l.0) {
                lit = Some((c, v, n));
            }
            if dark.map_or(true, |l| c < l.0) {
                dark = Some((c, v));
            }
        }
    }
    let (c, v, n) = lit.unwrap();
    let want = 0.8 * luminance(pre.irradiance(n)) / std::f32::consts::PI;
    println!(
        "render: facing the sun (cos {c:.3}) {v:.4e} vs {want:.4e}; away {:?}",
        dark
    );
    assert!((v / want - 1.0).abs() < 0.25, "{v} vs {want}");
    assert!(dark.unwrap().1 * 100.0 < v);
}

// ---------------------------------------------------------------------------
// All-black and all-saturated frames.

/// A frame that is black everywhere (code 0) or saturated everywhere (code 255)
/// holds no usable measurement. Every method returns a finite probe of the
/// frame's size: the warp method falls back on every matched face (and says
/// why), fusion keeps the black frame as measured (it did not clip) and never
/// goes below the white point where the frame is saturated.
#[test]
fn all_black_and_all_saturated_frames_give_finite_probes() {
    let s = small_world(128, 2, 3);
    let scene = scene_of(&s);
    let probes: Vec<HdrImage> = s.probes.iter().map(|p| p.hdr.clone()).collect();
    let (w, h) = (128, 64);
    let white = s.response.decode(1.0) / s.path_gain;
    for code in [0u8, 255] {
        let sdr = SdrImage::from_vec(w, h, vec![code; w * h * 3]).unwrap();
        let lin = pipeline::linearize(&sdr, &scene, &scene.frames[0]);
        for method in METHODS {
            let r = predict(&scene, 0, &sdr, &probes, method);
            let (out, warp, _, _) = r.unwrap_or_else(|e| panic!("{method:?} on code {code}: {e}"));
            assert_eq!((out.width(), out.height()), (w, h));
            assert_finite(&out, &format!("{method:?} on code {code}"));
            if let (Method::Warp, Some(wr)) = (method, &warp) {
                for f in wr.faces.iter().filter(|f| f.face.index() < 5) {
                    assert_eq!(f.source, "fallback", "{:?} on code {code}", f.face);
                    assert!(f.reason.is_some(), "{:?}: no reason given", f.face);
                }
            }
            if method == Method::Fusion {
                if code == 0 {
                    assert_eq!(out, lin, "a black frame did not clip: kept as measured");
                } else {
                    assert!(out.data().iter().all(|&v| v >= white * 0.999));
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------
// NaN, infinite and negative samples.

/// A little-endian RGB PFM of `w x h` with the given samples (bottom row first,
/// as the format stores it).
fn pfm_bytes(w: usize, h: usize, samples: &[f32]) -> Vec<u8> {
    let mut b = format!("PF\n{w} {h}\n-1.0\n").into_bytes();
    for v in samples {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b
}

/// NaN, +inf and a negative sample, each entry point (see the module docs):
/// `read_hdr` returns them as stored; `prefilter_to_dir` rejects the file
/// (`Error::Format` naming it and the count) and writes nothing;
/// `Prefiltered::from_env`, `warp_frame`, `flow_frame` and `fuse` reject the image
/// (`Error::Invalid` naming the input and the count); `pipeline::run` repairs the
/// probes and reports the repaired samples of every probe the frame used in
/// `FrameRecord::repaired_pixels`, with a finite output; the renderer under an
/// environment that answers NaN / infinite / negative radiance still writes finite,
/// non-negative pixels.
#[test]
fn invalid_samples_are_rejected_or_repaired_and_said_so() {
    let dir = tempfile::tempdir().unwrap();
    // Files: read as stored, refused by the prefilter.
    let (w, h) = (16, 8);
    let mut samples = vec![0.5f32; w * h * 3];
    samples[5] = f32::NAN;
    samples[40] = f32::INFINITY;
    samples[77] = -2.0;
    let bad = dir.path().join("bad_probe.pfm");
    std::fs::write(&bad, pfm_bytes(w, h, &samples)).unwrap();
    let img = io::read_hdr(&bad).unwrap();
    assert_eq!(img.count_invalid(), 3);
    let out = dir.path().join("prefiltered");
    let e = prefilter_to_dir(&bad, &out, &small_prefilter_opts()).unwrap_err();
    assert!(matches!(e, Error::Format { .. }), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains("bad_probe.pfm") && msg.contains("3 samples"),
        "{msg}"
    );
    assert!(!out.exists());
    // In memory.
    let msg = Prefiltered::from_env(&img, &small_prefilter_opts())
        .unwrap_err()
        .to_string();
    assert!(msg.contains("3 NaN"), "{msg}");

    let s = small_world(128, 2, 5);
    let scene = scene_of(&s);
    let sdr = &s.frames[0].sdr;
    let lin = pipeline::linearize(sdr, &scene, &scene.frames[0]);
    let frame_pose = scene.frames[0].pose;
    let mut broken = s.probes[0].hdr.clone();
    broken.set(10, 10, [f32::NAN, 1.0, 1.0]);
    broken.set(11, 10, [1.0, f32::INFINITY, 1.0]);
    broken.set(12, 10, [1.0, 1.0, -1.0]);
    let pp = PreparedProbe::new(
        Arc::new(broken.clone()),
        scene.probes[0].pose,
        ProbeTonemap::Camera,
        &scene.response,
        scene.path_gain,
    );
    let e = warp_frame(sdr, &lin, &frame_pose, &pp, &WarpParams::default(), 128, 64)
        .err()
        .expect("warp accepted a probe with NaN");
    assert!(
        matches!(e, Error::Invalid(_)) && e.to_string().contains("3 NaN"),
        "{e}"
    );
    let turned = rotate(
        &broken,
        frame_pose.from_other(&scene.probes[0].pose),
        128,
        64,
    );
    let bad_count = turned.count_invalid();
    assert!(bad_count > 0);
    let src = [Source {
        name: "probe_00".into(),
        image: &turned,
        distance_m: 1.0,
    }];
    let e = flow_frame(
        sdr,
        &lin,
        &src,
        &scene.response,
        scene.path_gain,
        &FlowMethodParams::default(),
    )
    .err()
    .expect("flow accepted a source with NaN");
    assert!(
        matches!(e, Error::Invalid(_)) && e.to_string().contains("probe_00"),
        "{e}"
    );
    let e = fuse(
        &Measured::new(sdr, &lin, 1.0),
        &turned,
        &FusionParams::default(),
    )
    .err()
    .expect("fusion accepted an estimate with NaN");
    assert!(
        matches!(e, Error::Invalid(_)) && e.to_string().contains("estimate"),
        "{e}"
    );

    // Through the pipeline: repaired and counted, whichever probe it is in.
    let scene_dir = dir.path().join("scene");
    s.write(&scene_dir).unwrap();
    let mut loaded = Scene::load(&scene_dir).unwrap();
    let used = loaded.probes_by_distance(loaded.frames[0].pose.position);
    let mut probe_samples = s.probes[used[1]].hdr.clone().into_vec();
    probe_samples[3] = f32::NAN;
    probe_samples[100] = f32::NEG_INFINITY;
    // PFM rows run bottom-up; the position of the bad samples does not matter.
    let pfm = dir.path().join("second_probe.pfm");
    std::fs::write(&pfm, pfm_bytes(128, 64, &probe_samples)).unwrap();
    loaded.probes[used[1]].hdr = Some(pfm);
    for method in [Method::Warp, Method::Flow] {
        let out_dir = dir.path().join(format!("run_{method:?}"));
        let params = RunParams {
            method,
            ..Default::default()
        };
        let rep = pipeline::run(&loaded, &out_dir, &params, &|_, _| {}).unwrap();
        let want = if method == Method::Warp { 0 } else { 2 };
        assert_eq!(
            rep.frames[0].repaired_pixels, want,
            "{method:?}: repaired samples of the probes used"
        );
        let written = io::read_hdr(&out_dir.join(format!("{}.exr", rep.frames[0].id))).unwrap();
        assert_finite(&written, &format!("{method:?} output"));
    }

    // The renderer never lets a bad environment through.
    use lumiprobe::render::ConstantEnv;
    let env = ConstantEnv {
        radiance: [f32::NAN, f32::INFINITY, -1.0],
    };
    let cam = Camera {
        eye: Vec3::new(0.0, 0.0, 3.0),
        target: Vec3::ZERO,
        up: Vec3::Y,
        vfov_deg: 40.0,
        width: 16,
        height: 16,
    };
    let model = Model::uv_sphere(1.0, 16, Material::basic([0.5; 3], 0.0, 0.5));
    let out = render(&model, &env, &cam, &RenderOptions::default()).unwrap();
    assert_finite(&out.color, "render under a NaN environment");
    assert!(out.coverage() > 0.2);
}

// ---------------------------------------------------------------------------
// Featureless probe faces.

/// A probe without texture (a smooth gradient: no SIFT feature on any face)
/// and a textured frame: the warp method matches nothing, every matched face
/// falls back to the probe turned by the known rotation, the report says
/// `fallback` with a reason naming the missing features, and the output is
/// finite and equals the turned probe away from the bottom face.
#[test]
fn featureless_probe_faces_fall_back_cleanly() {
    let s = small_world(128, 1, 7);
    let scene = scene_of(&s);
    let (w, h) = (128, 64);
    let probe = HdrImage::from_fn(w, h, |x, y| {
        let d = pixel_to_dir(x, y, w, h);
        [1.0 + 0.2 * d.y, 1.0 + 0.1 * d.x, 1.2]
    });
    let sdr = &s.frames[0].sdr;
    let lin = pipeline::linearize(sdr, &scene, &scene.frames[0]);
    let pp = PreparedProbe::new(
        Arc::new(probe.clone()),
        scene.probes[0].pose,
        ProbeTonemap::Camera,
        &scene.response,
        scene.path_gain,
    );
    let fpose = scene.frames[0].pose;
    let (out, rep) = warp_frame(sdr, &lin, &fpose, &pp, &WarpParams::default(), w, h).unwrap();
    assert_finite(&out, "warp");
    for f in rep.faces.iter().filter(|f| f.face.index() < 5) {
        assert_eq!(f.source, "fallback", "{:?}", f.face);
        let reason = f.reason.as_deref().unwrap_or("");
        assert!(reason.contains("features"), "{:?}: {reason}", f.face);
        assert!(f.homography.is_none());
    }
    let turned = rotate(&probe, fpose.from_other(&scene.probes[0].pose), w, h);
    for y in 8..h / 2 {
        for x in 0..w {
            let (a, b) = (out.get(x, y), turned.get(x, y));
            for k in 0..3 {
                assert!((a[k] - b[k]).abs() < 1e-4, "{x},{y}: {a:?} vs {b:?}");
            }
        }
    }
}

// ---------------------------------------------------------------------------
// Frames at, far from and between coincident probes.

/// Where the frame clipped: the fraction of its fully clipped pixels where `out`
/// is within 10% of `probe`, and per clipped region (the fusion's regions: code
/// 250 and up, every clipped pixel, a 1-pixel margin) the power above
/// the clip level of `out` and of `probe`.
fn clipped_agreement(
    sdr: &SdrImage,
    out: &HdrImage,
    probe: &HdrImage,
    white: f32,
) -> (f64, Vec<(f64, f64)>) {
    let (w, h) = (sdr.width(), sdr.height());
    let (mut n, mut close) = (0usize, 0usize);
    for y in 0..h {
        for x in 0..w {
            if sdr.get(x, y) == [255; 3] {
                n += 1;
                let (a, b) = (luminance(out.get(x, y)), luminance(probe.get(x, y)));
                close += usize::from((a - b).abs() <= 0.1 * b);
            }
        }
    }
    assert!(n > 0, "the frame clips nowhere");
    let mask = clip_mask(sdr, &Default::default(), 1);
    let (lab, regions) = components(&mask, w, h);
    let mut power = vec![(0.0f64, 0.0f64); regions];
    for (i, &l) in lab.iter().enumerate() {
        if l != u32::MAX {
            let (x, y) = (i % w, i / w);
            let da = pixel_solid_angle(y, w, h) as f64;
            let above = |img: &HdrImage| (luminance(img.get(x, y)) - white).max(0.0) as f64 * da;
            power[l as usize].0 += above(out);
            power[l as usize].1 += above(probe);
        }
    }
    (close as f64 / n as f64, power)
}

/// A frame taken exactly at a probe (same position and rotation; its SDR image is
/// the probe through the camera): distance 0 causes no division by zero and
/// every method gives a finite probe that, where the frame clipped, is the
/// probe's light: the power above the clip level in the clipped regions within
/// 5% of the probe's in total and in every region holding at least 1% of it.
/// Warp, flow and hybrid also match pixel by pixel (at least 90% of the fully
/// clipped pixels within 10%). Fusion is not asked to: it re-spreads each
/// region's power over the region in the shape of its estimate, shifted by the
/// offset between the estimate light's power centroid and the region's plain
/// centroid, which moves an asymmetric light by a pixel or two even when the
/// estimate is exactly aligned (a limitation of the fusion; the power is right).
#[test]
fn a_frame_exactly_at_a_probe() {
    let mut s = small_world(128, 2, 13);
    s.frames[0].pose = s.probes[0].pose.clone();
    s.frames[0].pose.id = "frame_000".into();
    s.frames[0].ground_truth = s.probes[0].hdr.clone();
    s.frames[0].sdr = simulate_sdr(&s.probes[0].hdr, s.path_gain, &s.response, 21);
    let scene = scene_of(&s);
    assert_eq!(
        scene.frames[0]
            .pose
            .position
            .distance(scene.probes[0].pose.position),
        0.0
    );
    let probes: Vec<HdrImage> = s.probes.iter().map(|p| p.hdr.clone()).collect();
    let clip_level = s.response.decode(250.0 / 255.0) / s.path_gain;
    for method in METHODS {
        let (out, ..) = predict(&scene, 0, &s.frames[0].sdr, &probes, method).unwrap();
        assert_finite(&out, &format!("{method:?}"));
        let (close, regions) = clipped_agreement(&s.frames[0].sdr, &out, &probes[0], clip_level);
        let (po, pp) = regions
            .iter()
            .fold((0.0, 0.0), |(a, b), r| (a + r.0, b + r.1));
        println!("{method:?}: {close:.3} of clipped pixels within 10%, power {po:.4} vs {pp:.4}");
        assert!(
            (po / pp - 1.0).abs() < 0.05,
            "{method:?}: power {po} vs {pp}"
        );
        for (i, &(o, p)) in regions.iter().enumerate() {
            if p >= 0.01 * pp {
                assert!(
                    (o / p - 1.0).abs() < 0.05,
                    "{method:?}: region {i}: {o} vs {p}"
                );
            }
        }
        if method != Method::Fusion {
            assert!(
                close >= 0.9,
                "{method:?}: only {close} of the clipped pixels match"
            );
        }
    }
}

/// A frame 1 km and 1e20 m (where squared distances overflow f32) from every
/// probe: the probes are still ordered (ties by index), every method gives a
/// finite probe, and the flow method's distance prior stays finite so its
/// probe labels remain selectable (the output is not just the SDR frame).
#[test]
fn a_frame_far_from_every_probe() {
    let s = small_world(128, 2, 17);
    let probes: Vec<HdrImage> = s.probes.iter().map(|p| p.hdr.clone()).collect();
    for far in [1e3f32, 1e20] {
        let mut scene = scene_of(&s);
        scene.frames[0].pose.position = Vec3::new(far, -far, 1.5);
        let order = scene.probes_by_distance(scene.frames[0].pose.position);
        let dist = |i: usize| {
            let p = scene.probes[i].pose.position.as_dvec3();
            p.distance(scene.frames[0].pose.position.as_dvec3())
        };
        assert!(dist(order[0]) <= dist(order[1]), "{order:?}");
        for method in METHODS {
            let (out, _, flow, _) = predict(&scene, 0, &s.frames[0].sdr, &probes, method)
                .unwrap_or_else(|e| panic!("{method:?} at {far} m: {e}"));
            assert_finite(&out, &format!("{method:?} at {far} m"));
            if let (Method::Flow, Some(fr)) = (method, flow) {
                let sdr_share = *fr.label_fractions.last().unwrap();
                assert!(
                    sdr_share < 0.5,
                    "at {far} m the flow method kept only the SDR frame ({sdr_share})"
                );
                assert!(fr.energy.is_finite());
            }
        }
    }
}

/// Two probes at the same position (different headings, the same light field):
/// the nearer one is the lower index, the flow / hybrid / fusion methods get a
/// finite probe for a frame elsewhere and for a frame at that very position
/// (both distances 0), and fusion finds no spurious light from the degenerate
/// triangulation (a zero baseline).
#[test]
fn two_probes_at_identical_positions() {
    let mut s = small_world(128, 2, 19);
    let mut twin = s.probes[0].pose.clone();
    twin.id = "probe_01".into();
    twin = lumiprobe::synth::Pose::new(
        twin.id,
        twin.position,
        [twin.yaw_pitch_roll_deg[0] + 70.0, 0.0, 0.0],
    );
    let p0 = pose_of(&s.probes[0].pose);
    let p1 = pose_of(&twin);
    s.probes[1].hdr = rotate(&s.probes[0].hdr, p1.from_other(&p0), 128, 64);
    s.probes[1].pose = twin;
    let probes: Vec<HdrImage> = s.probes.iter().map(|p| p.hdr.clone()).collect();
    let mut scene = scene_of(&s);
    assert_eq!(scene.probes[0].pose.position, scene.probes[1].pose.position);
    assert_eq!(
        scene.probes_by_distance(scene.frames[0].pose.position),
        vec![0, 1]
    );
    for at_probe in [false, true] {
        if at_probe {
            scene.frames[0].pose.position = scene.probes[0].pose.position;
        }
        for method in [Method::Flow, Method::Hybrid, Method::Fusion] {
            let (out, _, flow, fusion) =
                predict(&scene, 0, &s.frames[0].sdr, &probes, method).unwrap();
            assert_finite(
                &out,
                &format!("{method:?} (frame at the probes: {at_probe})"),
            );
            if let Some(fr) = flow {
                assert!(fr.energy.is_finite());
            }
            if let Some(fu) = fusion {
                assert!(fu.blobs.iter().all(|b| b.filled_power.is_finite()));
            }
        }
    }
}

// ---------------------------------------------------------------------------
// Tiny and odd panorama sizes.

fn catch<T>(what: &str, f: impl FnOnce() -> T) -> T {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(v) => v,
        Err(_) => panic!("{what} panicked"),
    }
}

/// Either a finite result of the expected size, or an error that names the
/// problem (the size).
fn ok_or_clear(what: &str, r: lumiprobe::Result<HdrImage>, w: usize, h: usize) {
    match r {
        Ok(img) => {
            assert_eq!((img.width(), img.height()), (w, h), "{what}");
            assert_finite(&img, what);
        }
        Err(e) => {
            let m = e.to_string();
            assert!(
                m.contains(&format!("{w}x{h}")) && m.contains("too small"),
                "{what}: unclear error {m}"
            );
        }
    }
}

/// Panoramas of 8x4, 33x17, 2x1, 1x1 and 3x2 through cube conversion, rotation,
/// SH projection, prefiltering, the metrics and the three methods: nothing
/// panics; the geometry stages keep a constant environment constant (cube faces
/// and round trip within 1e-5, SH band 0 = `c sqrt(4 pi)` within 1e-4, every
/// specular mip within 1% of `c`, irradiance `pi c` within 1%), identical images
/// score PSNR 100 and SSIM 1, and the methods either return a finite probe of the
/// frame's size or an error naming the size.
#[test]
fn tiny_and_odd_panoramas_work_or_fail_clearly() {
    let c = [0.7f32, 1.1, 2.3];
    let dir = tempfile::tempdir().unwrap();
    for (w, h) in [
        (8usize, 4usize),
        (33, 17),
        (2, 1),
        (1, 1),
        (3, 2),
        (64, 16),
        (200, 9),
    ] {
        let tag = format!("{w}x{h}");
        let img = HdrImage::from_fn(w, h, |_, _| c);
        for n in [1usize, 3, 8] {
            let faces = catch(&format!("{tag} to cube {n}"), || equirect_to_cube(&img, n));
            assert_eq!(faces.len(), 6);
            for f in &faces {
                assert_eq!((f.width(), f.height()), (n, n));
                for p in f.pixels() {
                    for k in 0..3 {
                        assert!((p[k] - c[k]).abs() < 1e-5, "{tag} face {n}: {p:?}");
                    }
                }
            }
            let back = catch(&format!("{tag} from cube {n}"), || {
                cube_to_equirect(&faces, w, h)
            });
            for p in back.pixels() {
                for k in 0..3 {
                    assert!((p[k] - c[k]).abs() < 1e-5, "{tag} back from {n}: {p:?}");
                }
            }
        }
        let r = ypr_to_mat(30.0, 10.0, 5.0);
        let turned = catch(&format!("{tag} rotate"), || rotate(&img, r, w, h));
        assert!(turned
            .pixels()
            .all(|p| (0..3).all(|k| (p[k] - c[k]).abs() < 1e-5)));
        let sh = Sh9::project(&img);
        let want0 = c[1] as f64 * (4.0 * std::f64::consts::PI).sqrt();
        assert!(
            ((sh.coeffs[0][1] as f64) - want0).abs() < 1e-4 * want0,
            "{tag}: {:?}",
            sh.coeffs[0]
        );
        let pre = catch(&format!("{tag} prefilter"), || {
            Prefiltered::from_env(&img, &small_prefilter_opts())
        });
        if w >= 8 && h >= 4 {
            let pre = pre.unwrap();
            for mip in &pre.specular.mips {
                for f in &mip.faces {
                    for p in f.pixels() {
                        assert!(
                            (p[1] - c[1]).abs() < 0.01 * c[1],
                            "{tag} mip {}: {p:?}",
                            mip.roughness
                        );
                    }
                }
            }
            // One SH sample per pixel: 4% off at 8x4, exact in the limit.
            let e = pre.irradiance(Vec3::Y)[1];
            let want = std::f32::consts::PI * c[1];
            assert!((e - want).abs() < 0.05 * want, "{tag}: E {e} vs {want}");
        } else {
            let e = pre.unwrap_err().to_string();
            assert!(e.contains(&tag) && e.contains("too small"), "{tag}: {e}");
            let file = dir.path().join(format!("tiny_{tag}.pfm"));
            io::write_hdr(&file, &img).unwrap();
            let e = prefilter_to_dir(&file, &dir.path().join("out"), &small_prefilter_opts())
                .unwrap_err();
            assert!(matches!(e, Error::Format { .. }), "{e}");
            assert!(e.to_string().contains(&format!("tiny_{tag}.pfm")), "{e}");
        }
        let cube = catch(&format!("{tag} specular"), || {
            prefilter_specular(&img, &small_prefilter_opts().specular)
        });
        assert!(cube
            .mips
            .iter()
            .all(|m| m.faces.iter().all(|f| f.count_invalid() == 0)));
        let m = eval::compare(&img, &img).unwrap();
        assert_eq!(m.psnr_tm, eval::PSNR_CAP_DB, "{tag}");
        assert!((m.ssim_tm - 1.0).abs() < 1e-12, "{tag}: ssim {}", m.ssim_tm);

        // The methods, on a probe with a lamp and a frame that clips it.
        let probe = HdrImage::from_fn(w, h, |x, y| {
            if (x + y) % 3 == 0 {
                [40.0; 3]
            } else {
                [0.3, 0.4, 0.5]
            }
        });
        let resp = lumiprobe::synth::data_response();
        let sdr = simulate_sdr(&probe, 0.5, &resp, 3);
        let lin = io::sdr_to_linear(&sdr, &resp, 0.5);
        let pose = Pose {
            position: Vec3::ZERO,
            world_from_camera: Mat3::IDENTITY,
        };
        let pp = PreparedProbe::new(
            Arc::new(probe.clone()),
            pose,
            ProbeTonemap::Camera,
            &resp,
            0.5,
        );
        let r = catch(&format!("{tag} warp"), || {
            warp_frame(&sdr, &lin, &pose, &pp, &WarpParams::default(), w, h).map(|r| r.0)
        });
        ok_or_clear(&format!("{tag} warp"), r, w, h);
        let src = [Source {
            name: "p".into(),
            image: &probe,
            distance_m: 0.5,
        }];
        let r = catch(&format!("{tag} flow"), || {
            flow_frame(&sdr, &lin, &src, &resp, 0.5, &FlowMethodParams::default()).map(|r| r.0)
        });
        ok_or_clear(&format!("{tag} flow"), r, w, h);
        let white = resp.decode(1.0) / 0.5;
        let r = catch(&format!("{tag} fusion"), || {
            fuse(
                &Measured::new(&sdr, &lin, white),
                &probe,
                &FusionParams::default(),
            )
            .map(|r| r.0)
        });
        ok_or_clear(&format!("{tag} fusion"), r, w, h);
    }
}

// ---------------------------------------------------------------------------
// Poses.

/// `poses.json` with one probe and one frame whose row-major
/// `world_from_camera` is `m`.
fn poses_json(m: &str) -> String {
    format!(
        r#"{{"scene":"t","camera":{{"response":"srgb","path_gain":1}},
        "probes":[{{"id":"p0","position":[0,0,1.5],"world_from_camera":[[1,0,0],[0,0,-1],[0,1,0]]}}],
        "frames":[{{"id":"f_odd","position":[1,0,1.5],"world_from_camera":{m},"sdr":"f.png"}}]}}"#
    )
}

/// Rotations in `poses.json` that are not rotations: a sheared or scaled matrix
/// is replaced by the nearest rotation (determinant 1) with a warning naming the
/// entry and the deviation; a mirror (determinant -1, e.g. a flipped axis) and
/// an overflowing entry are errors naming the file and the entry, never turned
/// into some rotation. In memory, the warp method given a non-rotation still
/// returns a finite probe.
#[test]
fn non_orthonormal_rotations_are_repaired_or_rejected() {
    let file = Path::new("/capture/poses.json");
    let root = Path::new("/capture");
    for m in [
        "[[1.2,0.3,0],[0,0,-0.9],[0.1,1,0]]",
        "[[2,0,0],[0,0,-2],[0,2,0]]",
    ] {
        let s = Scene::parse(&poses_json(m), root, file).unwrap();
        let r = s.frames[0].pose.world_from_camera;
        assert!((r.determinant() - 1.0).abs() < 1e-4, "{m}");
        assert!((r * r.transpose()).abs_diff_eq(Mat3::IDENTITY, 1e-4), "{m}");
        assert!(
            s.warnings
                .iter()
                .any(|w| w.contains("f_odd") && w.contains("orthonormal")),
            "{m}: {:?}",
            s.warnings
        );
    }
    for (m, what) in [
        ("[[1,0,0],[0,0,1],[0,1,0]]", "reflection"),
        ("[[-1,0,0],[0,0,-1],[0,1,0]]", "reflection"),
        ("[[1e39,0,0],[0,0,-1],[0,1,0]]", "rotation"),
    ] {
        let e = Scene::parse(&poses_json(m), root, file)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("poses.json") && e.contains("f_odd") && e.contains(what),
            "{m}: {e}"
        );
    }
    // In memory: a sheared pose is used as given, and the result stays finite.
    let s = small_world(128, 1, 23);
    let scene = scene_of(&s);
    let mut pose = scene.frames[0].pose;
    pose.world_from_camera =
        pose.world_from_camera * Mat3::from_cols(Vec3::X, Vec3::new(0.4, 1.0, 0.0), Vec3::Z);
    let lin = pipeline::linearize(&s.frames[0].sdr, &scene, &scene.frames[0]);
    let pp = PreparedProbe::new(
        Arc::new(s.probes[0].hdr.clone()),
        scene.probes[0].pose,
        ProbeTonemap::Camera,
        &scene.response,
        scene.path_gain,
    );
    let (out, _) = warp_frame(
        &s.frames[0].sdr,
        &lin,
        &pose,
        &pp,
        &WarpParams::default(),
        128,
        64,
    )
    .unwrap();
    assert_finite(&out, "warp with a sheared pose");
}

// ---------------------------------------------------------------------------
// Brackets and half floats (the rest is in tests/merge.rs and tests/io_formats.rs).

/// A bracket made of nothing but copies of one exposure (the same file listed
/// three times): merged as that exposure alone (equal to the single-frame merge
/// within 1e-6 relative), with a warning about the repeated exposure time.
#[test]
fn a_bracket_of_nothing_but_duplicates_is_the_single_exposure() {
    let s = small_world(64, 1, 29);
    let one = Exposure {
        name: PathBuf::from("ev0.jpg"),
        image: simulate_sdr(&s.probes[0].hdr, s.path_gain, &s.response, 1),
        time_s: 1.0 / 60.0,
    };
    let curve = ResponseCurve::from_response(&s.response);
    let single = merge(std::slice::from_ref(&one), &curve, &MergeOptions::default()).unwrap();
    let triple = merge(
        &[one.clone(), one.clone(), one.clone()],
        &curve,
        &MergeOptions::default(),
    )
    .unwrap();
    for (a, b) in triple.image.data().iter().zip(single.image.data()) {
        assert!((a - b).abs() <= 1e-6 * b.abs().max(1e-6), "{a} vs {b}");
    }
    assert_eq!(triple.flags, single.flags);
    assert!(
        triple
            .report
            .warnings
            .iter()
            .any(|w| w.contains("same exposure time")),
        "{:?}",
        triple.report.warnings
    );
}

/// Half-float EXR output of a large *negative* sample (-1e6, which a half would
/// turn into -inf): an error naming the file and the magnitude by default, and
/// -65504 with `Overflow::Clamp`.
#[test]
fn negative_half_float_overflow_is_an_error_or_a_clamp() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("negative.exr");
    let mut img = HdrImage::from_fn(4, 4, |_, _| [0.5; 3]);
    img.set(1, 2, [-1e6, 0.5, 0.5]);
    let half = ExrWriteOptions {
        half: true,
        on_overflow: Overflow::Error,
        ..Default::default()
    };
    let msg = exr::write(&p, &img, &half).unwrap_err().to_string();
    assert!(
        msg.contains("negative.exr") && msg.contains("1000000"),
        "{msg}"
    );
    assert!(!p.exists());
    let clamp = ExrWriteOptions {
        half: true,
        on_overflow: Overflow::Clamp,
        ..Default::default()
    };
    exr::write(&p, &img, &clamp).unwrap();
    assert_eq!(io::read_hdr(&p).unwrap().get(1, 2), [-65504.0, 0.5, 0.5]);
}

// ---------------------------------------------------------------------------
// Property tests of the numeric kernels (64 cases each, small images).

/// 64 cases from a fixed seed, so every run (and CI) tests the same inputs;
/// `PROPTEST_CASES` and `PROPTEST_SEED` widen or move the search by hand.
fn config() -> ProptestConfig {
    let env = |k: &str| std::env::var(k).ok().and_then(|s| s.parse::<u64>().ok());
    ProptestConfig {
        cases: env("PROPTEST_CASES").unwrap_or(64) as u32,
        failure_persistence: None,
        rng_seed: proptest::test_runner::RngSeed::Fixed(env("PROPTEST_SEED").unwrap_or(2024)),
        ..ProptestConfig::default()
    }
}

/// A smooth, positive panorama: `base + a . (x, y, z, x z)` (at least 0.2).
fn smooth_env(w: usize, h: usize, base: f32, a: [f32; 4]) -> HdrImage {
    HdrImage::from_fn(w, h, |x, y| {
        let d = pixel_to_dir(x, y, w, h);
        let v = base + a[0] * d.x + a[1] * d.y + a[2] * d.z + a[3] * d.x * d.z;
        [v, 0.5 * v + 0.1, 1.5 * v]
    })
}

/// Finite samples of every magnitude, sign and kind (zero, subnormal, max).
fn sample() -> impl Strategy<Value = f32> + Clone {
    prop_oneof![
        -1e30f32..1e30f32,
        0.0f32..1.0,
        Just(0.0f32),
        Just(-0.0f32),
        Just(f32::MAX),
        Just(f32::MIN_POSITIVE / 8.0),
        any::<f32>().prop_filter("finite", |v| v.is_finite()),
    ]
}

fn image(values: impl Strategy<Value = f32> + Clone + 'static) -> impl Strategy<Value = HdrImage> {
    (1usize..9, 1usize..7).prop_flat_map(move |(w, h)| {
        prop::collection::vec(values.clone(), w * h * 3)
            .prop_map(move |v| HdrImage::from_vec(w, h, v).unwrap())
    })
}

fn rotation() -> impl Strategy<Value = Mat3> {
    (-180.0f32..180.0, -90.0f32..90.0, -180.0f32..180.0).prop_map(|(y, p, r)| ypr_to_mat(y, p, r))
}

fn unit_dir() -> impl Strategy<Value = Vec3> {
    (-1.0f32..1.0, 0.0f32..std::f32::consts::TAU).prop_map(|(z, phi)| {
        let r = (1.0 - z * z).sqrt();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    })
}

fn sh9() -> impl Strategy<Value = Sh9> {
    prop::array::uniform9(prop::array::uniform3(-2.0f32..2.0)).prop_map(|coeffs| Sh9 { coeffs })
}

/// Grey image (r = g = b, so luminance = value) of log-uniform values.
fn grey_values() -> impl Strategy<Value = Vec<f32>> {
    prop::collection::vec(-6.0f32..6.0, 2..64)
        .prop_map(|v| v.into_iter().map(|e| 10f32.powf(e)).collect())
}

fn grey_image(v: &[f32]) -> HdrImage {
    HdrImage::from_fn(v.len(), 1, |x, _| [v[x]; 3])
}

/// Whether `out[i]` never decreases where `inp[i]` increases.
fn order_kept(inp: &[f32], out: &[f32]) -> bool {
    let mut idx: Vec<usize> = (0..inp.len()).collect();
    idx.sort_by(|&a, &b| inp[a].total_cmp(&inp[b]));
    idx.windows(2).all(|p| out[p[1]] >= out[p[0]])
}

proptest! {
    #![proptest_config(config())]

    /// Equirect -> cube -> equirect keeps a smooth environment within 1% away from
    /// the poles (two bilinear resamplings of a 64x32 panorama through 24 to 40
    /// pixel faces).
    #[test]
    fn prop_equirect_cube_round_trip(
        base in 1.0f32..2.0,
        a in prop::array::uniform4(-0.2f32..0.2),
        n in 24usize..40,
    ) {
        let (w, h) = (64, 32);
        let img = smooth_env(w, h, base, a);
        let faces = equirect_to_cube(&img, n);
        let back = cube_to_equirect(&faces, w, h);
        for y in 4..h - 4 {
            for x in 0..w {
                let (p, q) = (img.get(x, y), back.get(x, y));
                for k in 0..3 {
                    prop_assert!((p[k] - q[k]).abs() <= 0.01 * p[k], "{x},{y}: {p:?} vs {q:?}");
                }
            }
        }
    }

    /// Float EXR and PFM (both byte orders) return every finite sample bit for
    /// bit; half EXR keeps normal half-range values within 2^-11 relative.
    #[test]
    fn prop_image_io_round_trips(img in image(sample()), half in image(1e-4f32..6e4)) {
        let limits = io::Limits::default();
        let bytes = exr::encode(&img, Path::new("p.exr"), &ExrWriteOptions::default()).unwrap();
        let back = io::decode_hdr(&bytes, Path::new("p.exr"), &limits).unwrap();
        prop_assert_eq!((back.width(), back.height()), (img.width(), img.height()));
        for (a, b) in back.data().iter().zip(img.data()) {
            prop_assert_eq!(a.to_bits(), b.to_bits());
        }
        for endian in [io::pfm::Endian::Little, io::pfm::Endian::Big] {
            let bytes = io::pfm::encode(&img, endian);
            let back = io::decode_hdr(&bytes, Path::new("p.pfm"), &limits).unwrap();
            prop_assert_eq!((back.width(), back.height()), (img.width(), img.height()));
            for (a, b) in back.data().iter().zip(img.data()) {
                prop_assert_eq!(a.to_bits(), b.to_bits());
            }
        }
        let opts = ExrWriteOptions { half: true, on_overflow: Overflow::Error, ..Default::default() };
        let bytes = exr::encode(&half, Path::new("h.exr"), &opts).unwrap();
        let back = io::decode_hdr(&bytes, Path::new("h.exr"), &limits).unwrap();
        for (a, b) in back.data().iter().zip(half.data()) {
            prop_assert!((a - b).abs() <= b * 2f32.powi(-11) * 1.0001, "{a} vs {b}");
        }
    }

    /// Every tone map keeps the order of grey values (brighter in, never darker
    /// out), stays in [0, 1], and so do the camera responses.
    #[test]
    fn prop_tone_maps_are_monotone(v in grey_values(), key in 0.05f32..0.5, ev in -8.0f32..8.0,
                                   white in 0.5f32..100.0) {
        use lumiprobe::tonemap::{exposure_srgb, reinhard_global, EncodeLut, Reinhard05, Response};
        let img = grey_image(&v);
        let green = |out: Vec<f32>| -> Vec<f32> { out.chunks_exact(3).map(|c| c[1]).collect() };
        let maps = [
            ("reinhard02", green(reinhard_global(&img, key, None, None))),
            ("reinhard02 white", green(reinhard_global(&img, key, Some(white), None))),
            ("reinhard02 fixed log-average", green(reinhard_global(&img, key, None, Some(white)))),
            ("reinhard05", green(Reinhard05::default().apply(&img))),
            ("exposure", green(exposure_srgb(&img, ev))),
        ];
        for (name, out) in &maps {
            prop_assert!(out.iter().all(|o| (0.0..=1.0).contains(o)), "{name}: {out:?}");
            prop_assert!(order_kept(&v, out), "{name} reorders {v:?} into {out:?}");
        }
        let table: Vec<f32> = (0..256).map(|i| (i as f32 / 255.0).powf(2.2) * 2.0).collect();
        for r in [
            Response::Srgb,
            Response::Gamma { gamma: 2.2 },
            lumiprobe::synth::data_response(),
            Response::Table { linear: table },
        ] {
            let scaled: Vec<f32> = v.iter().map(|x| x * 1e-3).collect();
            let enc: Vec<f32> = scaled.iter().map(|&x| r.encode(x)).collect();
            prop_assert!(order_kept(&scaled, &enc), "{r:?}");
            let lut = EncodeLut::new(&r, 1e-3, 1024);
            let enc: Vec<f32> = v.iter().map(|&x| lut.encode(x)).collect();
            prop_assert!(order_kept(&v, &enc), "{r:?} LUT");
            prop_assert!(enc.iter().all(|o| (0.0..=1.0).contains(o)));
        }
    }

    /// SH rotation: the rotated coefficients evaluate to the original at the
    /// rotated direction, composing rotations composes the maps, band energies
    /// are kept, and projecting a rotated panorama gives the rotated projection.
    #[test]
    fn prop_sh_rotation_is_equivariant(sh in sh9(), a in rotation(), b in rotation(), d in unit_dir(),
                                       base in 1.0f32..2.0, k in prop::array::uniform4(-0.2f32..0.2)) {
        let ra = sh.rotate(a);
        let (x, y) = (ra.eval(d), sh.eval(a * d));
        for c in 0..3 {
            prop_assert!((x[c] - y[c]).abs() < 1e-3, "{x:?} vs {y:?}");
        }
        let ab = ra.rotate(b);
        let direct = sh.rotate(a * b);
        for i in 0..9 {
            for c in 0..3 {
                prop_assert!((ab.coeffs[i][c] - direct.coeffs[i][c]).abs() < 1e-3);
            }
        }
        for l in 0..3 {
            let (e0, e1) = (sh.band_energy(l), ra.band_energy(l));
            prop_assert!((e0 - e1).abs() <= 1e-4 * e0.max(1.0), "band {l}: {e0} vs {e1}");
        }
        let (w, h) = (64, 32);
        let img = smooth_env(w, h, base, k);
        let p = Sh9::project(&rotate(&img, a, w, h));
        let q = Sh9::project(&img).rotate(a);
        let scale = q.coeffs[0][2].abs();
        for i in 0..9 {
            for c in 0..3 {
                let (u, v) = (p.coeffs[i][c], q.coeffs[i][c]);
                prop_assert!((u - v).abs() < 0.02 * scale, "k{i} c{c}: {u} vs {v}");
            }
        }
    }

    /// SSIM of an image with itself is exactly 1, SSIM is symmetric, at most 1
    /// and finite.
    #[test]
    fn prop_ssim_identity_and_symmetry(
        (w, h, a, b) in (1usize..24, 1usize..16).prop_flat_map(|(w, h)| (
            Just(w),
            Just(h),
            prop::collection::vec(0.0f32..=1.0, w * h),
            prop::collection::vec(0.0f32..=1.0, w * h),
        ))
    ) {
        prop_assert_eq!(eval::ssim(&a, &a, w, h), 1.0);
        let (ab, ba) = (eval::ssim(&a, &b, w, h), eval::ssim(&b, &a, w, h));
        prop_assert!(ab.is_finite());
        prop_assert!((ab - ba).abs() <= 1e-12, "{ab} vs {ba}");
        prop_assert!(ab <= 1.0 + 1e-12);
    }

    /// MSE / PSNR of the metrics: an image against itself scores MSE 0, PSNR
    /// 100 (the cap), SSIM 1, log-luminance RMSE 0 and irradiance error 0; any
    /// prediction scores MSE >= 0 with PSNR = min(100, 10 log10(1 / MSE)); a
    /// prediction k times too bright errs more as k grows, and its log-luminance
    /// RMSE never exceeds |log10 k|.
    #[test]
    fn prop_mse_and_psnr(
        gt in prop::collection::vec(-2.0f32..2.0, 16 * 8 * 3),
        noise in prop::collection::vec(-1.0f32..1.0, 16 * 8 * 3),
        k1 in 1.0f32..4.0,
        dk in 0.0f32..4.0,
    ) {
        let (w, h) = (16, 8);
        let gt = HdrImage::from_vec(w, h, gt.into_iter().map(|e| 10f32.powf(e)).collect()).unwrap();
        let same = eval::compare(&gt, &gt).unwrap();
        prop_assert_eq!(same.mse_tm, 0.0);
        prop_assert_eq!(same.psnr_tm, eval::PSNR_CAP_DB);
        prop_assert_eq!(same.ssim_tm, 1.0);
        prop_assert_eq!(same.log_lum_rmse, 0.0);
        prop_assert_eq!(same.irradiance_rel_err, 0.0);
        let noisy = HdrImage::from_vec(
            w,
            h,
            gt.data().iter().zip(&noise).map(|(g, n)| g * 2f32.powf(*n)).collect(),
        )
        .unwrap();
        let m = eval::compare(&noisy, &gt).unwrap();
        prop_assert!(m.mse_tm >= 0.0 && m.mse_tm.is_finite());
        let want = if m.mse_tm > 0.0 { (10.0 * (1.0 / m.mse_tm).log10()).min(100.0) } else { 100.0 };
        prop_assert!((m.psnr_tm - want).abs() < 1e-9, "{} vs {want}", m.psnr_tm);
        prop_assert!(m.psnr_tm <= eval::PSNR_CAP_DB);
        let scaled = |k: f32| HdrImage::from_vec(w, h, gt.data().iter().map(|v| v * k).collect()).unwrap();
        let (m1, m2) = (eval::compare(&scaled(k1), &gt).unwrap(), eval::compare(&scaled(k1 + dk), &gt).unwrap());
        prop_assert!(m1.mse_tm <= m2.mse_tm + 1e-12, "{} then {}", m1.mse_tm, m2.mse_tm);
        prop_assert!(m1.psnr_tm >= m2.psnr_tm - 1e-9);
        prop_assert!(m1.log_lum_rmse <= (k1 as f64).log10() + 1e-6, "{} vs {}", m1.log_lum_rmse, (k1 as f64).log10());
    }
}
