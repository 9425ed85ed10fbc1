//! The warp method (thesis Part II): per cube face, a homography found by matching
//! features of the SDR frame against the nearest probe's tone-mapped faces, applied
//! to the probe's HDR radiance.
//!
//! The probe is cut into cube faces at `yaw_steps` yaw offsets (multiples of
//! `90° / yaw_steps`, so the side faces of all rotations cover every heading),
//! tone-mapped to 8 bit, and its features are indexed once per probe, rotation and
//! face. Each side face of the frame is matched against side faces, its top face
//! only against top faces; the bottom face (tripod, operator) comes from the SDR
//! frame itself. A homography is kept only if it passes geometric checks, otherwise
//! the face falls back to the probe rotated by the known relative rotation.
//! Warping never resamples a face image: each output pixel maps through the
//! homography to a direction of the probe panorama, which is sampled in float.

mod geometry;
pub mod probe;

pub use probe::{PreparedProbe, ProbeTonemap};

use crate::cv::{self, DetectParams, Detector, Estimator, Features};
use crate::error::Result;
use crate::image::{HdrImage, SdrImage};
use crate::scene::Pose;
use crate::sphere::{sample_dir, ypr_to_mat, CubeFace, FACES};
use glam::{DMat3, DVec3, Mat3, Vec3};
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Which probe faces a frame face is matched against.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum CandidateMode {
    /// Only the `pose_candidates` probe faces that the known relative rotation says
    /// overlap most (fast; needs poses, which every scene has).
    Pose,
    /// Every side face of every rotation (the thesis's exhaustive search).
    All,
}

/// Settings of the warp method.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WarpParams {
    /// Yaw rotations of the probe (step `90° / yaw_steps`).
    pub yaw_steps: usize,
    /// Cube face size in pixels; `None` uses a quarter of the panorama width, at
    /// most `max_face_size`.
    pub face_size: Option<usize>,
    /// Largest face size chosen automatically: features of wider panoramas are
    /// matched at this working resolution (homographies are in face coordinates,
    /// so they apply at any output size). SIFT on a 7776-pixel-wide panorama's
    /// 1944-pixel faces takes about 0.9 GB per face and finds nothing a 1024-pixel
    /// face does not.
    #[serde(default = "default_max_face_size")]
    pub max_face_size: usize,
    /// Feature detector.
    pub detector: Detector,
    /// Keep at most this many features per face (0 = no limit).
    pub max_features: i32,
    /// Detector threshold (SIFT contrast threshold; 0 = OpenCV's default 0.04).
    pub detector_threshold: f64,
    /// Gaussian blur (pixels) of both images before detection, against sensor noise.
    pub blur_sigma: f32,
    /// Half-extent of the matched face images in face coordinates: 1 is the 90° face,
    /// more adds a margin so features near face edges are matched too.
    pub face_extent: f32,
    /// FLANN leaf checks per query; 0 matches by exact brute force instead.
    pub flann_checks: i32,
    /// Lowe ratio-test threshold.
    pub ratio: f32,
    /// Robust estimator for the homography.
    pub estimator: Estimator,
    /// RANSAC inlier threshold in face pixels.
    pub ransac_threshold: f64,
    /// Most RANSAC iterations per candidate (each costs a 9x9 eigen-solve).
    pub ransac_iters: i32,
    /// Fewest inliers for a homography to be trusted.
    pub min_inliers: usize,
    /// Smallest inlier fraction of the ratio-test matches.
    pub min_inlier_ratio: f32,
    /// Largest mean distance, in face widths, between where the homography and the
    /// known rotation put the face corners.
    pub max_prior_deviation: f32,
    /// How far beyond its face (in face half-widths) a homography may be followed
    /// before the output falls back to the rotated probe.
    pub extrapolate: f32,
    /// Width, in face half-widths, of the cross-fade between neighbouring faces.
    pub seam_blend: f32,
    /// Candidate selection.
    pub candidates: CandidateMode,
    /// Candidates per face in [`CandidateMode::Pose`].
    pub pose_candidates: usize,
    /// How probes are turned into 8-bit images for matching.
    pub probe_tonemap: ProbeTonemap,
    /// Where the frame clipped in the bottom face (which otherwise is the frame),
    /// the output is the probe's radiance: at least the frame's (on, the warp
    /// method's own output: the frame measured a lower bound there) or the probe's
    /// alone (off: the hybrid, whose flow stage compares its sources with the frame,
    /// and a source that copies the frame's measured channels would win that
    /// comparison without having seen what clipped).
    #[serde(default = "yes")]
    pub bottom_bounded_by_frame: bool,
}

fn yes() -> bool {
    true
}

fn default_max_face_size() -> usize {
    1024
}

impl Default for WarpParams {
    fn default() -> Self {
        WarpParams {
            yaw_steps: 4,
            face_size: None,
            max_face_size: default_max_face_size(),
            detector: Detector::Sift,
            max_features: 300,
            detector_threshold: 0.02,
            blur_sigma: 1.0,
            face_extent: 1.0,
            flann_checks: 32,
            ratio: 0.7,
            estimator: Estimator::Ransac,
            ransac_threshold: 3.0,
            ransac_iters: 1000,
            min_inliers: 12,
            min_inlier_ratio: 0.2,
            max_prior_deviation: 0.35,
            extrapolate: 0.5,
            seam_blend: 0.08,
            candidates: CandidateMode::Pose,
            pose_candidates: 2,
            probe_tonemap: ProbeTonemap::Camera,
            bottom_bounded_by_frame: true,
        }
    }
}

impl WarpParams {
    /// Face size used for a panorama `width` pixels wide.
    pub fn face_size_for(&self, width: usize) -> usize {
        self.face_size
            .unwrap_or((width / 4).min(self.max_face_size).max(8))
    }
    /// Feature detection settings.
    pub fn detect_params(&self) -> DetectParams {
        DetectParams {
            detector: self.detector,
            max_features: self.max_features,
            threshold: self.detector_threshold,
            blur_sigma: self.blur_sigma,
        }
    }
    /// Side of the matched face images in pixels for face size `n`.
    pub fn match_size(&self, n: usize) -> usize {
        ((n as f32 * self.face_extent.max(1.0)).round() as usize).max(8)
    }
    /// Yaw of rotation step `k` in degrees.
    pub fn yaw_deg(&self, k: usize) -> f32 {
        k as f32 * 90.0 / self.yaw_steps.max(1) as f32
    }
}

/// The probe face a frame face was matched with.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    /// Yaw rotation step of the probe.
    pub yaw_step: usize,
    /// The probe face (in the rotated probe's axes).
    pub face: CubeFace,
}

/// What happened to one face of one frame.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FaceReport {
    /// The frame face.
    pub face: CubeFace,
    /// Where its pixels came from: `homography`, `fallback` or `sdr`.
    pub source: String,
    /// The accepted candidate, if any.
    pub candidate: Option<Candidate>,
    /// Features detected on the frame face.
    pub features: usize,
    /// Ratio-test matches with the best candidate.
    pub matches: usize,
    /// RANSAC inliers of the best candidate.
    pub inliers: usize,
    /// Mean reprojection error of the inliers in face pixels.
    pub reprojection_error: f32,
    /// Why the face fell back, when it did.
    pub reason: Option<String>,
    /// The homography (probe face pixels -> frame face pixels), row-major.
    pub homography: Option<[f64; 9]>,
}

/// Wall-clock time per stage, in milliseconds.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct WarpTimings {
    /// Cutting and 8-bit conversion of the frame's faces.
    pub tonemap_ms: f64,
    /// Feature detection on the frame's faces.
    pub features_ms: f64,
    /// Probe features computed for this frame (zero once cached).
    pub probe_features_ms: f64,
    /// Descriptor matching and homography fitting.
    pub matching_ms: f64,
    /// Warping the HDR probe through the homographies and stitching the panorama.
    pub warp_stitch_ms: f64,
}

/// The warp method's result for one frame.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WarpReport {
    /// One entry per cube face.
    pub faces: Vec<FaceReport>,
    /// Stage timings.
    pub timings: WarpTimings,
}

/// How one frame face gets its pixels.
#[derive(Clone, Copy, Debug)]
enum FaceMap {
    /// Through `hinv` (frame face px -> probe face px) into probe face `cand`.
    Homography {
        hinv: DMat3,
        rot: Mat3,
        face: CubeFace,
    },
    /// The probe rotated by the known relative rotation.
    Fallback,
    /// The linearised SDR frame.
    Sdr,
}

/// Face coordinate of pixel position `x` (centre of pixel `i` at `i`) in a matched
/// face image of `m` pixels spanning `[-e, e]`.
#[inline]
pub(crate) fn px_to_fc(x: f32, m: usize, e: f32) -> f32 {
    e * (2.0 * (x + 0.5) / m as f32 - 1.0)
}

/// 8-bit gray image of `face` (extent `e`, `m` pixels) of a `w x h` panorama whose
/// pixel `i` holds the display values `px(i)` in [0, 1], seen by a camera rotated
/// by `r`.
pub(crate) fn gray_face(
    w: usize,
    h: usize,
    face: CubeFace,
    m: usize,
    e: f32,
    r: Mat3,
    px: impl Fn(usize) -> [f32; 3],
) -> Vec<u8> {
    let lut = geometry::face_lookup(face, m, e, r, w, h);
    lut.iter()
        .map(|&[x, y]| {
            let c = crate::sphere::sample_px_by(w, h, x, y, &px);
            ((0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]).clamp(0.0, 1.0) * 255.0 + 0.5) as u8
        })
        .collect()
}

/// Display values in [0, 1] of an 8-bit frame (codes / 255).
pub fn sdr_display(sdr: &SdrImage) -> HdrImage {
    let data = sdr.data().iter().map(|&c| c as f32 / 255.0).collect();
    HdrImage::from_vec(sdr.width(), sdr.height(), data).expect("size matches")
}

fn homography_to_dmat(h: &[f64; 9]) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(h[0], h[3], h[6]),
        DVec3::new(h[1], h[4], h[7]),
        DVec3::new(h[2], h[5], h[8]),
    )
}

#[inline]
fn apply_h(h: &DMat3, x: f64, y: f64) -> Option<(f64, f64)> {
    let p = *h * DVec3::new(x, y, 1.0);
    if p.z.abs() < 1e-12 || p.z <= 0.0 || !p.is_finite() {
        None
    } else {
        Some((p.x / p.z, p.y / p.z))
    }
}

/// Where a known rotation puts frame-face coordinates `(a, b)` in probe face `g`
/// rotated by `rot` (frame camera -> probe camera is `rel`).
fn rotation_prediction(
    rel: Mat3,
    rot: Mat3,
    f: CubeFace,
    g: CubeFace,
    a: f32,
    b: f32,
) -> Option<(f32, f32)> {
    let dp = rot.transpose() * (rel * f.dir(a, b));
    g.project(dp)
}

/// Checks a fitted homography, given as its inverse (frame face coordinates -> probe
/// face coordinates); returns why it is rejected.
fn check_homography(
    hinv: &DMat3,
    rel: Mat3,
    rot: Mat3,
    f: CubeFace,
    g: CubeFace,
    p: &WarpParams,
) -> Option<String> {
    if !hinv.is_finite() || hinv.determinant().abs() < 1e-12 {
        return Some("singular homography".into());
    }
    let corners = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)];
    let mut q = [(0.0f64, 0.0f64); 4];
    for (i, &(x, y)) in corners.iter().enumerate() {
        match apply_h(hinv, x, y) {
            Some(v) => q[i] = v,
            None => return Some("face corner maps behind the probe".into()),
        }
    }
    // Convex, same orientation as the face, sensible area.
    let mut area = 0.0;
    for i in 0..4 {
        let (a, b, c) = (q[i], q[(i + 1) % 4], q[(i + 2) % 4]);
        let cross = (b.0 - a.0) * (c.1 - b.1) - (b.1 - a.1) * (c.0 - b.0);
        if cross <= 0.0 {
            return Some("homography folds or mirrors the face".into());
        }
        area += a.0 * b.1 - b.0 * a.1;
    }
    let ratio = 0.5 * area / 4.0;
    if !(0.25..=4.0).contains(&ratio) {
        return Some(format!("homography scales the face area by {ratio:.2}"));
    }
    // Agreement with the known rotation, in face widths (a face is 2 units wide).
    let mut dev = 0.0;
    for (i, &(x, y)) in corners.iter().enumerate() {
        match rotation_prediction(rel, rot, f, g, x as f32, y as f32) {
            Some((px, py)) => {
                dev += ((px as f64 - q[i].0).powi(2) + (py as f64 - q[i].1).powi(2)).sqrt()
            }
            None => return Some("candidate face does not face the frame face".into()),
        }
    }
    let dev = dev / 4.0 / 2.0;
    if dev > p.max_prior_deviation as f64 {
        return Some(format!(
            "homography departs from the known rotation by {dev:.2} face widths"
        ));
    }
    None
}

/// Probe faces worth matching with frame face `f`, best first.
fn candidates_for(f: CubeFace, rel: Mat3, p: &WarpParams) -> Vec<Candidate> {
    let (nf, _, _) = f.basis();
    let target = rel * nf; // frame face normal in probe axes
    let faces: Vec<CubeFace> = if f == CubeFace::Top {
        vec![CubeFace::Top]
    } else {
        FACES[..4].to_vec()
    };
    let mut all: Vec<(f32, Candidate)> = Vec::new();
    for k in 0..p.yaw_steps.max(1) {
        let rot = ypr_to_mat(p.yaw_deg(k), 0.0, 0.0);
        for &g in &faces {
            let (ng, _, _) = g.basis();
            let score = target.dot(rot * ng);
            all.push((
                score,
                Candidate {
                    yaw_step: k,
                    face: g,
                },
            ));
        }
    }
    all.sort_by(|a, b| b.0.total_cmp(&a.0));
    match p.candidates {
        CandidateMode::All => all.into_iter().map(|c| c.1).collect(),
        CandidateMode::Pose => all
            .into_iter()
            .take(p.pose_candidates.max(1))
            .map(|c| c.1)
            .collect(),
    }
}

struct FaceResult {
    report: FaceReport,
    map: FaceMap,
    tonemap_ms: f64,
    features_ms: f64,
    probe_features_ms: f64,
    matching_ms: f64,
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

fn match_face(
    f: CubeFace,
    sdr: &SdrImage,
    n: usize,
    rel: Mat3,
    probe: &PreparedProbe,
    p: &WarpParams,
) -> Result<FaceResult> {
    let m = p.match_size(n);
    let e = p.face_extent.max(1.0);
    // Probe faces first (cached after the first frame): a frame face whose candidates
    // are all featureless (a plain ceiling) is not worth detecting features on.
    let mut probe_features_ms = 0.0;
    let mut cands = Vec::new();
    for cand in candidates_for(f, rel, p) {
        let t2 = Instant::now();
        let (pf, computed) = probe.face_features(cand.yaw_step, cand.face, m, p)?;
        if computed {
            probe_features_ms += ms(t2);
        }
        if pf.features.len() >= p.min_inliers.max(4) {
            cands.push((cand, pf));
        }
    }
    if cands.is_empty() {
        return Ok(FaceResult {
            report: FaceReport {
                face: f,
                source: "fallback".into(),
                candidate: None,
                features: 0,
                matches: 0,
                inliers: 0,
                reprojection_error: 0.0,
                reason: Some("probe faces have too few features; face skipped".into()),
                homography: None,
            },
            map: FaceMap::Fallback,
            tonemap_ms: 0.0,
            features_ms: 0.0,
            probe_features_ms,
            matching_ms: 0.0,
        });
    }
    let t0 = Instant::now();
    // The frame's display values (codes / 255, as `sdr_display`), read from the codes.
    let codes = sdr.data();
    let gray = gray_face(sdr.width(), sdr.height(), f, m, e, Mat3::IDENTITY, |i| {
        let c = &codes[3 * i..3 * i + 3];
        [
            c[0] as f32 / 255.0,
            c[1] as f32 / 255.0,
            c[2] as f32 / 255.0,
        ]
    });
    let tonemap_ms = ms(t0);
    let t1 = Instant::now();
    let feats: Features = cv::detect(&gray, m, m, &p.detect_params())?;
    // Pixels per face-coordinate unit, to express thresholds and errors in pixels.
    let px_per_unit = m as f64 / (2.0 * e as f64);
    let to_fc = |(x, y): (f32, f32)| (px_to_fc(x, m, e), px_to_fc(y, m, e));
    let features_ms = ms(t1);
    let mut matching_ms = 0.0;
    let mut best: Option<(usize, FaceReport, FaceMap)> = None;
    let mut last_reason = if feats.len() < 4 {
        Some(format!("only {} features on the frame face", feats.len()))
    } else {
        None
    };
    if feats.len() >= 4 {
        for (cand, pf) in cands {
            let t3 = Instant::now();
            let pairs = pf.index.match_ratio(&feats, p.ratio)?;
            let rot = ypr_to_mat(p.yaw_deg(cand.yaw_step), 0.0, 0.0);
            let mut report = FaceReport {
                face: f,
                source: "fallback".into(),
                candidate: Some(cand),
                features: feats.len(),
                matches: pairs.len(),
                inliers: 0,
                reprojection_error: 0.0,
                reason: None,
                homography: None,
            };
            if pairs.len() < p.min_inliers.max(4) {
                last_reason = Some(format!("{} matches with the best probe face", pairs.len()));
                matching_ms += ms(t3);
                continue;
            }
            // Keep only matches the known rotation allows (up to the same deviation the
            // final check accepts): most wrong matches go before RANSAC sees them.
            let max_dev = 2.0 * p.max_prior_deviation;
            let (mut src, mut dst) = (
                Vec::with_capacity(pairs.len()),
                Vec::with_capacity(pairs.len()),
            );
            for &(q, t) in &pairs {
                let (ta, tb) = to_fc(feats.point(q));
                let (pa, pb) = to_fc(pf.features.point(t));
                if let Some((ea, eb)) = rotation_prediction(rel, rot, f, cand.face, ta, tb) {
                    if (ea - pa).hypot(eb - pb) <= max_dev {
                        src.push((pa, pb));
                        dst.push((ta, tb));
                    }
                }
            }
            report.matches = src.len();
            if src.len() < p.min_inliers.max(4) {
                last_reason = Some(format!(
                    "{} of {} matches agree with the known rotation",
                    src.len(),
                    pairs.len()
                ));
                matching_ms += ms(t3);
                continue;
            }
            let fitted = cv::find_homography(
                &src,
                &dst,
                p.ransac_threshold / px_per_unit,
                p.ransac_iters.max(1),
                0.995,
                p.estimator,
            )?;
            matching_ms += ms(t3);
            let Some(h) = fitted else {
                last_reason = Some("no homography found".into());
                continue;
            };
            let inliers = h.inliers.iter().filter(|&&m| m != 0).count();
            let hm = homography_to_dmat(&h.h);
            let mut err = 0.0;
            for (i, &m) in h.inliers.iter().enumerate() {
                if m != 0 {
                    if let Some((x, y)) = apply_h(&hm, src[i].0 as f64, src[i].1 as f64) {
                        err +=
                            ((x - dst[i].0 as f64).powi(2) + (y - dst[i].1 as f64).powi(2)).sqrt();
                    }
                }
            }
            report.inliers = inliers;
            report.reprojection_error = if inliers > 0 {
                (err / inliers as f64 * px_per_unit) as f32
            } else {
                f32::INFINITY
            };
            let reason = if inliers < p.min_inliers {
                Some(format!("{inliers} inliers (need {})", p.min_inliers))
            } else if (inliers as f32) < p.min_inlier_ratio * pairs.len() as f32 {
                Some(format!("{inliers} of {} matches are inliers", pairs.len()))
            } else if !(report.reprojection_error <= p.ransac_threshold as f32) {
                Some(format!(
                    "reprojection error {:.2} px",
                    report.reprojection_error
                ))
            } else if !hm.is_finite() || hm.determinant().abs() < 1e-12 {
                Some("singular homography".into())
            } else {
                check_homography(&hm.inverse(), rel, rot, f, cand.face, p)
            };
            if let Some(r) = reason {
                last_reason = Some(r);
                continue;
            }
            report.homography = Some(h.h);
            report.source = "homography".into();
            let better = best.as_ref().map_or(true, |b| inliers > b.0);
            if better {
                let map = FaceMap::Homography {
                    hinv: hm.inverse(),
                    rot,
                    face: cand.face,
                };
                best = Some((inliers, report, map));
            }
            // Candidates come best-aligned first: a clear winner ends the search.
            if inliers >= 2 * p.min_inliers && inliers * 2 >= src.len() {
                break;
            }
        }
    }
    let (report, map) = match best {
        Some((_, r, m)) => (r, m),
        None => (
            FaceReport {
                face: f,
                source: "fallback".into(),
                candidate: None,
                features: feats.len(),
                matches: 0,
                inliers: 0,
                reprojection_error: 0.0,
                reason: last_reason,
                homography: None,
            },
            FaceMap::Fallback,
        ),
    };
    Ok(FaceResult {
        report,
        map,
        tonemap_ms,
        features_ms,
        probe_features_ms,
        matching_ms,
    })
}

/// Predicts the HDR panorama at a frame with the warp method.
///
/// `sdr` is the frame (any size), `sdr_linear` the same frame linearised to radiance
/// (used for the bottom face), `pose` its pose, `probe` the nearest probe prepared
/// for matching. The output has `out_w x out_h` pixels. A probe or linearised
/// frame with NaN, infinite or negative samples is an [`Error::Invalid`](crate::Error::Invalid).
pub fn warp_frame(
    sdr: &SdrImage,
    sdr_linear: &HdrImage,
    pose: &Pose,
    probe: &PreparedProbe,
    p: &WarpParams,
    out_w: usize,
    out_h: usize,
) -> Result<(HdrImage, WarpReport)> {
    use rayon::prelude::*;
    if (sdr.width(), sdr.height()) != (sdr_linear.width(), sdr_linear.height()) {
        return Err(crate::error::Error::Invalid(format!(
            "warp: the frame is {}x{} but its linearised copy is {}x{}",
            sdr.width(),
            sdr.height(),
            sdr_linear.width(),
            sdr_linear.height()
        )));
    }
    for (what, img) in [("probe", &*probe.image), ("linearised frame", sdr_linear)] {
        let bad = img.count_invalid();
        if bad > 0 {
            return Err(crate::error::Error::Invalid(format!(
                "warp: the {what} has {bad} NaN, infinite or negative samples \
                 (re-export it from its source, or run it through `lumiprobe convert`, which repairs them)"
            )));
        }
    }
    let n = p.face_size_for(sdr.width());
    let rel = pose.from_other(&probe.pose);
    let matched: Vec<Result<FaceResult>> = FACES[..5]
        .par_iter()
        .map(|&f| match_face(f, sdr, n, rel, probe, p))
        .collect();
    let mut maps = [FaceMap::Sdr; 6];
    let mut faces = Vec::with_capacity(6);
    let mut timings = WarpTimings::default();
    for (i, r) in matched.into_iter().enumerate() {
        let r = r?;
        maps[i] = r.map;
        timings.tonemap_ms += r.tonemap_ms;
        timings.features_ms += r.features_ms;
        timings.probe_features_ms += r.probe_features_ms;
        timings.matching_ms += r.matching_ms;
        faces.push(r.report);
    }
    faces.push(FaceReport {
        face: CubeFace::Bottom,
        source: "sdr".into(),
        candidate: None,
        features: 0,
        matches: 0,
        inliers: 0,
        reprojection_error: 0.0,
        reason: None,
        homography: None,
    });
    let t = Instant::now();
    let out = stitch(&maps, rel, probe, sdr, sdr_linear, p, out_w, out_h);
    timings.warp_stitch_ms = ms(t);
    Ok((out, WarpReport { faces, timings }))
}

/// 8-bit code from which an SDR channel counts as clipped ([`crate::image::censor`]).
pub use crate::image::censor::CLIP_CODE;

/// Value of a frame face's mapping into the probe in direction `d` (frame axes),
/// or `None` when the mapping does not reach that direction. The frame's own face
/// ([`FaceMap::Sdr`]) is read by [`stitch`], which knows where the frame clipped;
/// here it gives `None`.
#[inline]
fn face_value(
    map: &FaceMap,
    a: f32,
    b: f32,
    d: Vec3,
    rel: Mat3,
    probe: &HdrImage,
    extrapolate: f32,
) -> Option<[f32; 3]> {
    match map {
        FaceMap::Sdr => None,
        FaceMap::Fallback => Some(sample_dir(probe, rel * d)),
        FaceMap::Homography { hinv, rot, face } => {
            let (qa, qb) = apply_h(hinv, a as f64, b as f64)?;
            let (qa, qb) = (qa as f32, qb as f32);
            if qa.abs().max(qb.abs()) > 1.0 + extrapolate || !qa.is_finite() || !qb.is_finite() {
                return None;
            }
            Some(sample_dir(probe, *rot * face.dir(qa, qb)))
        }
    }
}

/// Assembles the output panorama: each pixel takes the mapping of the cube face it
/// falls on, cross-faded with the neighbouring face's mapping near face edges. The
/// SDR face reads the frame's own pixel (output and frame share their size) or
/// samples it when the sizes differ; either way, where the frame clipped, the
/// probe supplies the light (see [`WarpParams::bottom_bounded_by_frame`]). The
/// geometry comes from the shared stitch map when it is small enough to keep,
/// else it is made row by row.
fn stitch(
    maps: &[FaceMap; 6],
    rel: Mat3,
    probe: &PreparedProbe,
    sdr: &SdrImage,
    sdr_linear: &HdrImage,
    p: &WarpParams,
    w: usize,
    h: usize,
) -> HdrImage {
    use rayon::prelude::*;
    let geo = geometry::stitch_map(w, h, p.seam_blend);
    let same_size = sdr_linear.width() == w && sdr_linear.height() == h;
    let codes = sdr.data();
    let hdr = &probe.image;
    let mut out = HdrImage::new(w, h);
    out.rows_mut()
        .enumerate()
        .par_bridge()
        .for_each(|(row, line)| {
            let mut own = geometry::RowMap::default();
            let (dirs, start, taps) = match &geo {
                Some(g) => (
                    &g.dirs[row * w..(row + 1) * w],
                    &g.start[row * w..(row + 1) * w + 1],
                    &g.taps[..],
                ),
                None => {
                    geometry::stitch_row(row, w, h, p.seam_blend, &mut own);
                    (&own.dirs[..], &own.start[..], &own.taps[..])
                }
            };
            for col in 0..w {
                let i = row * w + col;
                let d = dirs[col];
                let mut acc = [0.0f32; 3];
                for t in &taps[start[col] as usize..start[col + 1] as usize] {
                    let v = match &maps[t.face as usize] {
                        FaceMap::Sdr => {
                            // The frame's own pixel, or (sizes differ) its sample in
                            // this direction, with the codes of the nearest pixel.
                            let (v, j) = if same_size {
                                (sdr_linear.get(col, row), i)
                            } else {
                                let (u, vv) = crate::sphere::dir_to_uv(d);
                                let (fw, fh) = (sdr.width(), sdr.height());
                                let fx = ((u * fw as f32) as usize).min(fw - 1);
                                let fy = ((vv * fh as f32) as usize).min(fh - 1);
                                (sample_dir(sdr_linear, d), fy * fw + fx)
                            };
                            // Near-white SDR codes are only a lower bound on radiance
                            // (the sensor clipped).
                            let clipped = crate::image::censor::Censor::default()
                                .any_clipped(&codes[3 * j..3 * j + 3]);
                            if clipped {
                                // The true radiance is at least what the SDR shows; the
                                // probe supplies the part above the white point.
                                let f = sample_dir(hdr, rel * d);
                                if p.bottom_bounded_by_frame {
                                    [v[0].max(f[0]), v[1].max(f[1]), v[2].max(f[2])]
                                } else {
                                    f
                                }
                            } else {
                                v
                            }
                        }
                        m => face_value(m, t.a, t.b, d, rel, hdr, p.extrapolate)
                            .unwrap_or_else(|| sample_dir(hdr, rel * d)),
                    };
                    for k in 0..3 {
                        acc[k] += t.w * v[k];
                    }
                }
                line[3 * col..3 * col + 3].copy_from_slice(&acc);
            }
        });
    out
}

#[cfg(test)]
mod tests;
