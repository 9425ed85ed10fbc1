//! Option groups and argument parsers the commands share: the warp and flow
//! methods' tuning options, sizes, shards, finite numbers, the progress bar,
//! and how every command reads an HDR input.

use clap::Args;
use lumiprobe::cv::{Detector, Estimator};
use lumiprobe::image::io;
use lumiprobe::pipeline::{Method, RunParams};
use lumiprobe::warp::{CandidateMode, ProbeTonemap};
use lumiprobe::{Error, HdrImage, Result};
use std::path::{Path, PathBuf};

#[derive(Args, Clone)]
#[command(next_help_heading = TUNING_WARP)]
pub(crate) struct WarpOpts {
    /// Yaw rotations of the probe (step 90°/N).
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().yaw_steps)]
    pub(crate) yaw_steps: usize,
    /// Feature detector (Debian's OpenCV has no SURF).
    #[arg(long, value_enum, default_value_t = Detector::Sift)]
    pub(crate) detector: Detector,
    /// Keep at most this many features per face (0 = all).
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().max_features)]
    pub(crate) max_features: i32,
    /// Detector threshold (SIFT contrast; 0 = OpenCV default 0.04).
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().detector_threshold)]
    pub(crate) detector_threshold: f64,
    /// Gaussian blur (pixels) before detection, against sensor noise.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::warp::WarpParams::default().blur_sigma)]
    pub(crate) blur_sigma: f32,
    /// Candidates per face when matching by pose.
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().pose_candidates)]
    pub(crate) pose_candidates: usize,
    /// FLANN leaf checks per query (0 = exact brute-force matching).
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().flann_checks)]
    pub(crate) flann_checks: i32,
    /// Lowe ratio-test threshold.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::warp::WarpParams::default().ratio)]
    pub(crate) ratio: f32,
    /// Robust homography estimator.
    #[arg(long, value_enum, default_value_t = Estimator::Ransac)]
    pub(crate) estimator: Estimator,
    /// RANSAC inlier threshold in face pixels.
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().ransac_threshold)]
    pub(crate) ransac_threshold: f64,
    /// Most RANSAC iterations per candidate face.
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().ransac_iters)]
    pub(crate) ransac_iters: i32,
    /// Fewest inliers to trust a face's homography.
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().min_inliers)]
    pub(crate) min_inliers: usize,
    /// Which probe faces a frame face is matched with.
    #[arg(long, value_enum, default_value_t = CandidateMode::Pose)]
    pub(crate) candidates: CandidateMode,
    /// How probes are tone-mapped for matching.
    #[arg(long, value_enum, default_value_t = ProbeTonemap::Camera)]
    pub(crate) probe_tonemap: ProbeTonemap,
    /// Half-extent of matched face images (1 = the 90° face; more adds a margin).
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::warp::WarpParams::default().face_extent)]
    pub(crate) face_extent: f32,
    /// Cube face size (default: a quarter of the panorama width, at most
    /// `--max-face-size`).
    #[arg(long)]
    pub(crate) face_size: Option<usize>,
    /// Largest automatic face size: wider panoramas are matched at this working
    /// resolution.
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().max_face_size)]
    pub(crate) max_face_size: usize,
}

impl WarpOpts {
    pub(crate) fn params(&self) -> lumiprobe::warp::WarpParams {
        lumiprobe::warp::WarpParams {
            yaw_steps: self.yaw_steps.max(1),
            detector: self.detector,
            ratio: self.ratio,
            estimator: self.estimator,
            ransac_threshold: self.ransac_threshold,
            ransac_iters: self.ransac_iters,
            flann_checks: self.flann_checks,
            face_extent: self.face_extent,
            min_inliers: self.min_inliers,
            candidates: self.candidates,
            probe_tonemap: self.probe_tonemap,
            face_size: self.face_size,
            max_face_size: self.max_face_size,
            max_features: self.max_features,
            detector_threshold: self.detector_threshold,
            blur_sigma: self.blur_sigma,
            pose_candidates: self.pose_candidates,
            ..Default::default()
        }
    }
}

#[derive(Args, Clone)]
#[command(next_help_heading = TUNING_FLOW)]
pub(crate) struct FlowOpts {
    /// DIS optical-flow preset.
    #[arg(long, value_enum, default_value_t = lumiprobe::flow::dense::FlowPreset::Fast)]
    pub(crate) flow_preset: lumiprobe::flow::dense::FlowPreset,
    /// Weight of the graph cut's seam cost.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().lambda)]
    pub(crate) lambda: f32,
    /// Data cost of the SDR label (thesis: 500).
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().sdr_cost)]
    pub(crate) sdr_cost: f32,
    /// Graph-cut moves.
    #[arg(long, value_enum, default_value_t = lumiprobe::flow::graphcut::Optimizer::Expansion)]
    pub(crate) optimizer: lumiprobe::flow::graphcut::Optimizer,
    /// Most expansion/swap cycles.
    #[arg(long, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().max_cycles)]
    pub(crate) max_cycles: usize,
    /// Ablation: cheapest label per pixel, no smoothness.
    #[arg(long)]
    pub(crate) no_smoothness: bool,
    /// Base method whose output fills clipped regions in `--method fusion`.
    #[arg(long, value_enum, default_value_t = Method::Flow)]
    pub(crate) fusion_base: Method,
    /// Box radius over which the colour term is averaged (0 = per pixel).
    #[arg(long, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().dc_radius)]
    pub(crate) dc_radius: usize,
    /// Seam-cost weight where the SDR frame measured (did not clip), relative to clipped regions
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().seam_measured)]
    pub(crate) seam_measured: f32,
    /// Weight of the colour term where the SDR frame clipped (a label darker than
    /// the clip level contradicts the frame there).
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().clipped_dc_weight)]
    pub(crate) clipped_dc_weight: f32,
    /// Constant cost of a label change between pixels where the SDR frame clipped.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().clipped_potts)]
    pub(crate) clipped_potts: f32,
    /// Weight of the log-exposure seam cost where the SDR frame clipped.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().seam_clipped)]
    pub(crate) seam_clipped: f32,
    /// Let the graph cut relabel measured (unclipped) pixels too; by default they
    /// keep the label their data cost prefers and the cut decides only clipped ones.
    #[arg(long)]
    pub(crate) cut_measured: bool,
    /// Weight of the colour term against the confidence and distance terms.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().dc_weight)]
    pub(crate) dc_weight: f32,
    /// Widest frame the flow method processes at full resolution; wider frames run
    /// flow and graph cut at 1/k size (0 = always full resolution).
    #[arg(long, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().work_width)]
    pub(crate) flow_work_width: usize,
    /// Largest angle (degrees) between the probes' directions to a clipped light for
    /// it to count as distant and keep the rotation's alignment (0 = off).
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().distant_light_deg)]
    pub(crate) distant_light_deg: f32,
    /// How far around a clipped light (degrees of longitude) its light is looked for.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().light_ring_deg)]
    pub(crate) light_ring_deg: f32,
    /// Hybrid: how far (degrees of longitude) from a clipped light the warp stage may
    /// have moved it; a distant light there is put back where the rotation puts it.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().light_reach_deg)]
    pub(crate) light_reach_deg: f32,
}

impl FlowOpts {
    pub(crate) fn params(&self) -> lumiprobe::flow::method::FlowMethodParams {
        let mut p = lumiprobe::flow::method::FlowMethodParams {
            lambda: self.lambda,
            sdr_cost: self.sdr_cost,
            optimizer: self.optimizer,
            max_cycles: self.max_cycles,
            no_smoothness: self.no_smoothness,
            dc_radius: self.dc_radius,
            seam_measured: self.seam_measured,
            clipped_dc_weight: self.clipped_dc_weight,
            clipped_potts: self.clipped_potts,
            seam_clipped: self.seam_clipped,
            measured_decides: !self.cut_measured,
            dc_weight: self.dc_weight,
            work_width: self.flow_work_width,
            distant_light_deg: self.distant_light_deg,
            light_ring_deg: self.light_ring_deg,
            light_reach_deg: self.light_reach_deg,
            ..Default::default()
        };
        p.flow.preset = self.flow_preset;
        p
    }
}

pub(crate) fn parse_vec3(s: &str) -> std::result::Result<[f32; 3], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|t| t.trim().parse::<f32>().map_err(|e| format!("{t:?}: {e}")))
        .collect::<std::result::Result<_, _>>()?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
        _ => Err(format!(
            "expected x,y,z with three finite numbers, got {s:?}"
        )),
    }
}

/// Settings of a run from the command line's method, size and option groups.
pub(crate) fn run_params(
    method: Method,
    size: Option<(usize, usize)>,
    warp: &WarpOpts,
    flow: &FlowOpts,
) -> RunParams {
    RunParams {
        method,
        size,
        warp: warp.params(),
        flow: flow.params(),
        fusion_base: flow.fusion_base,
        ..Default::default()
    }
}

/// The glTF files (.glb, .gltf) of a folder, sorted by name.
pub(crate) fn model_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            matches!(
                p.extension()
                    .and_then(|e| e.to_str())
                    .map(|e| e.to_ascii_lowercase())
                    .as_deref(),
                Some("glb" | "gltf")
            )
        })
        .collect();
    v.sort();
    if v.is_empty() {
        return Err(Error::Invalid(format!(
            "{}: no .glb or .gltf model",
            dir.display()
        )));
    }
    Ok(v)
}

pub(crate) fn parse_shard(s: &str) -> std::result::Result<(usize, usize), String> {
    let (i, n) = s
        .split_once('/')
        .ok_or_else(|| format!("expected I/N, got {s:?}"))?;
    let i: usize = i.trim().parse().map_err(|e| format!("{s:?}: {e}"))?;
    let n: usize = n.trim().parse().map_err(|e| format!("{s:?}: {e}"))?;
    if n == 0 || i >= n {
        return Err(format!("{s:?}: need 0 <= I < N"));
    }
    Ok((i, n))
}

/// A number option that must be finite (no NaN or infinity).
pub(crate) fn parse_finite(s: &str) -> std::result::Result<f32, String> {
    let v: f32 = s
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a number"))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("{s:?} is not a finite number"))
    }
}

pub(crate) fn parse_size(s: &str) -> std::result::Result<(usize, usize), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("size {s:?} is not WxH"))?;
    let w: usize = w
        .parse()
        .map_err(|_| format!("width {w:?} is not a number"))?;
    let h: usize = h
        .parse()
        .map_err(|_| format!("height {h:?} is not a number"))?;
    let (mw, mh) = lumiprobe::scene::MAX_PANORAMA;
    if w < 8 || h < 4 || w > mw || h > mh {
        return Err(format!("size {w}x{h} is outside 8x4 .. {mw}x{mh}"));
    }
    Ok((w, h))
}

pub(crate) fn progress_printer(quiet: bool, label: &'static str) -> impl Fn(usize, usize) + Sync {
    move |done, total| {
        if !quiet {
            use std::io::Write;
            let width = 30;
            let filled = if total > 0 {
                done * width / total
            } else {
                width
            };
            eprint!(
                "\r{label} [{}{}] {done}/{total}",
                "#".repeat(filled),
                ".".repeat(width - filled)
            );
            if done == total {
                eprintln!();
            }
            let _ = std::io::stderr().flush();
        }
    }
}

/// The method named in a run folder's report.json, for labelling eval rows.
pub(crate) fn report_method(dir: &Path) -> Option<String> {
    let text = std::fs::read_to_string(dir.join("report.json")).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    v["params"]["method"].as_str().map(|s| s.to_string())
}

/// Reads an HDR input as every command does: NaN, infinite and negative samples
/// repaired, with one warning that counts them.
pub(crate) fn read_input(path: &Path) -> Result<HdrImage> {
    let (img, warning) = io::read_hdr_repaired(path)?;
    if let Some(w) = warning {
        eprintln!("{w}");
    }
    Ok(img)
}

/// Help headings of the methods' tuning options: listed by `--help-all` only,
/// so that everyday `--help` fits one screen.
pub(crate) const TUNING_WARP: &str = "Warp method tuning";
pub(crate) const TUNING_FLOW: &str = "Flow method tuning";

/// How cube faces are written.
#[derive(Clone, Copy, clap::ValueEnum)]
pub(crate) enum Layout {
    /// One file per cube face.
    Faces,
    /// One 6n x n strip per cube.
    Strip,
}

/// One line on a finished run: frames computed and resumed, the computed
/// frames' mean time (none when every frame was up to date).
pub(crate) fn run_summary(
    report: &lumiprobe::pipeline::RunReport,
    out: &std::path::Path,
) -> String {
    let computed: Vec<&lumiprobe::pipeline::FrameRecord> = report
        .frames
        .iter()
        .filter(|f| !report.resumed.contains(&f.id))
        .collect();
    let time = if computed.is_empty() {
        "all up to date".to_string()
    } else {
        let ms = computed.iter().map(|f| f.total_ms).sum::<f64>() / computed.len() as f64;
        format!("{} computed at {ms:.1} ms per frame", computed.len())
    };
    let homog: usize = computed
        .iter()
        .filter_map(|f| f.warp.as_ref())
        .map(|w| w.faces.iter().filter(|x| x.source == "homography").count())
        .sum();
    let faces = if homog > 0 {
        format!(", {homog} faces used a homography")
    } else {
        String::new()
    };
    format!(
        "{}: {} frames ({} resumed, {time}){faces}; report: {}",
        report.scene,
        report.frames.len(),
        report.resumed.len(),
        out.join("report.json").display()
    )
}
