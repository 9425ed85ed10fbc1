//! `lumiprobe` command line: one subcommand per workflow step.

use clap::{Args, Parser, Subcommand};
use lumiprobe::cv::{Detector, Estimator};
use lumiprobe::image::io;
use lumiprobe::pipeline::{self, Method, RunParams};
use lumiprobe::scene::Scene;
use lumiprobe::warp::{CandidateMode, ProbeTonemap};
use lumiprobe::{Error, HdrImage, Result};
use std::path::{Path, PathBuf};

mod cmd;

#[derive(Parser)]
#[command(
    name = "lumiprobe",
    version,
    about = "HDR light probes at every frame of a 360° SDR walk"
)]
struct Cli {
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// No progress output.
    #[arg(long, short, global = true)]
    quiet: bool,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Args, Clone)]
#[command(next_help_heading = TUNING_WARP)]
struct WarpOpts {
    /// Yaw rotations of the probe (step 90°/N).
    #[arg(long, default_value_t = 4)]
    yaw_steps: usize,
    /// Feature detector (Debian's OpenCV has no SURF).
    #[arg(long, value_enum, default_value_t = Detector::Sift)]
    detector: Detector,
    /// Keep at most this many features per face (0 = all).
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().max_features)]
    max_features: i32,
    /// Detector threshold (SIFT contrast; 0 = OpenCV default 0.04).
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().detector_threshold)]
    detector_threshold: f64,
    /// Gaussian blur (pixels) before detection, against sensor noise.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::warp::WarpParams::default().blur_sigma)]
    blur_sigma: f32,
    /// Candidates per face when matching by pose.
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().pose_candidates)]
    pose_candidates: usize,
    /// FLANN leaf checks per query (0 = exact brute-force matching).
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().flann_checks)]
    flann_checks: i32,
    /// Lowe ratio-test threshold.
    #[arg(long, value_parser = parse_finite, default_value_t = 0.7)]
    ratio: f32,
    /// Robust homography estimator.
    #[arg(long, value_enum, default_value_t = Estimator::Ransac)]
    estimator: Estimator,
    /// RANSAC inlier threshold in face pixels.
    #[arg(long, default_value_t = 3.0)]
    ransac_threshold: f64,
    /// Most RANSAC iterations per candidate face.
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().ransac_iters)]
    ransac_iters: i32,
    /// Fewest inliers to trust a face's homography.
    #[arg(long, default_value_t = 12)]
    min_inliers: usize,
    /// Which probe faces a frame face is matched with.
    #[arg(long, value_enum, default_value_t = CandidateMode::Pose)]
    candidates: CandidateMode,
    /// How probes are tone-mapped for matching.
    #[arg(long, value_enum, default_value_t = ProbeTonemap::Camera)]
    probe_tonemap: ProbeTonemap,
    /// Half-extent of matched face images (1 = the 90° face; more adds a margin).
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::warp::WarpParams::default().face_extent)]
    face_extent: f32,
    /// Cube face size (default: a quarter of the panorama width, at most
    /// `--max-face-size`).
    #[arg(long)]
    face_size: Option<usize>,
    /// Largest automatic face size: wider panoramas are matched at this working
    /// resolution.
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().max_face_size)]
    max_face_size: usize,
}

impl WarpOpts {
    fn params(&self) -> lumiprobe::warp::WarpParams {
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
struct FlowOpts {
    /// DIS optical-flow preset.
    #[arg(long, value_enum, default_value_t = lumiprobe::flow::dense::FlowPreset::Fast)]
    flow_preset: lumiprobe::flow::dense::FlowPreset,
    /// Weight of the graph cut's seam cost.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().lambda)]
    lambda: f32,
    /// Data cost of the SDR label (thesis: 500).
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().sdr_cost)]
    sdr_cost: f32,
    /// Graph-cut moves.
    #[arg(long, value_enum, default_value_t = lumiprobe::flow::graphcut::Optimizer::Expansion)]
    optimizer: lumiprobe::flow::graphcut::Optimizer,
    /// Most expansion/swap cycles.
    #[arg(long, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().max_cycles)]
    max_cycles: usize,
    /// Ablation: cheapest label per pixel, no smoothness.
    #[arg(long)]
    no_smoothness: bool,
    /// Base method whose output fills clipped regions in `--method fusion`.
    #[arg(long, value_enum, default_value_t = Method::Flow)]
    fusion_base: Method,
    /// Box radius over which the colour term is averaged (0 = per pixel).
    #[arg(long, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().dc_radius)]
    dc_radius: usize,
    /// Seam-cost weight where the SDR frame measured (did not clip), relative to clipped regions
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().seam_measured)]
    seam_measured: f32,
    /// Weight of the colour term where the SDR frame clipped (a label darker than
    /// the clip level contradicts the frame there).
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().clipped_dc_weight)]
    clipped_dc_weight: f32,
    /// Constant cost of a label change between pixels where the SDR frame clipped.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().clipped_potts)]
    clipped_potts: f32,
    /// Weight of the log-exposure seam cost where the SDR frame clipped.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().seam_clipped)]
    seam_clipped: f32,
    /// Let the graph cut relabel measured (unclipped) pixels too; by default they
    /// keep the label their data cost prefers and the cut decides only clipped ones.
    #[arg(long)]
    cut_measured: bool,
    /// Weight of the colour term against the confidence and distance terms.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().dc_weight)]
    dc_weight: f32,
    /// Widest frame the flow method processes at full resolution; wider frames run
    /// flow and graph cut at 1/k size (0 = always full resolution).
    #[arg(long, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().work_width)]
    flow_work_width: usize,
    /// Largest angle (degrees) between the probes' directions to a clipped light for
    /// it to count as distant and keep the rotation's alignment (0 = off).
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().distant_light_deg)]
    distant_light_deg: f32,
    /// How far around a clipped light (degrees of longitude) its light is looked for.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().light_ring_deg)]
    light_ring_deg: f32,
    /// Hybrid: how far (degrees of longitude) from a clipped light the warp stage may
    /// have moved it; a distant light there is put back where the rotation puts it.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().light_reach_deg)]
    light_reach_deg: f32,
}

impl FlowOpts {
    fn params(&self) -> lumiprobe::flow::method::FlowMethodParams {
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

#[derive(Subcommand)]
enum Cmd {
    /// Predict an HDR probe for every frame of a scene.
    Run {
        /// Scene folder (with poses.json), the poses.json itself, or a manifest
        /// (.toml, see `lumiprobe init`).
        scene: PathBuf,
        /// Output folder (default: the manifest's `output.folder`).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Method (default: the manifest's, else fusion).
        #[arg(long, value_enum)]
        method: Option<Method>,
        /// Print what would be done (stages given, cached or to compute; frames
        /// up to date) and stop.
        #[arg(long)]
        dry_run: bool,
        /// Run only shard I of N (frames I, I+N, I+2N, ...), e.g. `--shard
        /// $SLURM_ARRAY_TASK_ID/16`; shards may share the output folder.
        #[arg(long, value_parser = parse_shard)]
        shard: Option<(usize, usize)>,
        /// Working size WxH (default: the frames' size).
        #[arg(long, value_parser = parse_size)]
        size: Option<(usize, usize)>,
        /// Recover the frames' exposure gain against the probes (`lumiprobe
        /// calibrate`) instead of trusting the scene file's.
        #[arg(long)]
        calibrate: bool,
        /// Compression of the per-frame EXR files. On lumiprobe's outputs ZIP is
        /// the smallest (a quarter of the raw size for kitchen at 7776x3888) and
        /// PIZ writes 3x faster at 1.2x ZIP's size; none is the fastest.
        #[arg(long, value_enum, default_value_t = lumiprobe::pipeline::RunParams::default().exr_compression)]
        exr_compression: lumiprobe::image::io::ExrCompression,
        /// A setting without a flag of its own, as KEY=VALUE (a path into the
        /// settings of `report.json`), e.g. `fusion.walk.mode=two_sided` or
        /// `fusion.ledger=full`; repeatable.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        #[command(flatten)]
        warp: WarpOpts,
        #[command(flatten)]
        flow: FlowOpts,
    },
    /// Synthesize a small scene, run every method on it and print the scores.
    Demo {
        /// Folder for the scene and the predictions.
        #[arg(long, default_value = "lumiprobe-demo")]
        out: PathBuf,
        /// Panorama width of the synthetic scene.
        #[arg(long, default_value_t = 512)]
        width: usize,
        /// Frames along the walk.
        #[arg(long, default_value_t = 8)]
        frames: usize,
        /// Seed of the synthetic scene.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Time the method per frame (probe features cached) with a stage breakdown.
    Bench {
        /// Scene folder.
        scene: PathBuf,
        /// Working size WxH (default: the frames' size).
        #[arg(long, value_parser = parse_size)]
        size: Option<(usize, usize)>,
        /// Threads for the timed runs.
        #[arg(long, default_value_t = 1)]
        bench_threads: usize,
        /// Repetitions over all frames.
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
        /// Method (the same default as `run`).
        #[arg(long, value_enum, default_value_t = Method::Fusion)]
        method: Method,
        /// A setting as KEY=VALUE, as for `corpus` (`fusion.ledger="full"`);
        /// repeatable.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Error against run time: vary the settings that trade time for quality
        /// (method, size 256..2048 wide, yaw rotations, detector, ratio, flow preset,
        /// graph-cut cycles, smoothness, fusion base) one at a time around the given
        /// ones, time and score each on the scene, and mark the Pareto front.
        #[arg(long)]
        sweep: bool,
        /// Folder for the sweep's sweep.csv, sweep.json, sweep.txt and sweep.png.
        #[arg(long, requires = "sweep")]
        report: Option<PathBuf>,
        /// Internal to `--sweep`: time and score these settings (JSON) in this
        /// process, printing the JSON report.
        #[arg(long, hide = true)]
        point_json: Option<String>,
        #[command(flatten)]
        warp: WarpOpts,
        #[command(flatten)]
        flow: FlowOpts,
    },
    /// Run methods on every scene of one or more corpora and score them with the
    /// worst case: one row per scene and method, totals per split, a plot.
    Corpus {
        /// Corpus folders (holding corpus.json) or folders of scene folders (each
        /// holding a poses.json; split "shared").
        #[arg(required = true)]
        roots: Vec<PathBuf>,
        /// Output folder: OUT/<scene>/<method> per run, corpus.txt, corpus.csv,
        /// corpus.json and corpus_worst_irradiance.png.
        #[arg(long)]
        out: PathBuf,
        /// Methods, comma-separated.
        #[arg(long, value_enum, value_delimiter = ',', default_values_t = [Method::Warp, Method::Flow, Method::Hybrid, Method::Fusion])]
        methods: Vec<Method>,
        /// Working size WxH (default: the frames' size).
        #[arg(long, value_parser = parse_size)]
        size: Option<(usize, usize)>,
        /// Compression of the per-frame EXR files (as for `run`).
        #[arg(long, value_enum, default_value_t = lumiprobe::pipeline::RunParams::default().exr_compression)]
        exr_compression: lumiprobe::image::io::ExrCompression,
        /// Only the scenes of these splits, comma-separated (default: all).
        #[arg(long, value_enum, value_delimiter = ',')]
        split: Vec<lumiprobe::pipeline::corpus::Split>,
        /// A setting as KEY=VALUE, KEY a path into the run's settings
        /// (`fusion.max_angle_deg=5`); repeatable.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        #[command(flatten)]
        warp: WarpOpts,
        #[command(flatten)]
        flow: FlowOpts,
    },
    /// Score predictions against the scene's ground truth, with both baselines.
    Eval {
        /// Scene folder.
        scene: PathBuf,
        /// Prediction folder(s) from `lumiprobe run`; `LABEL=DIR` names a row.
        #[arg(long, required = true)]
        pred: Vec<String>,
        /// Print JSON (table and per-frame scores) instead of the text table.
        #[arg(long)]
        json: bool,
        /// Rescale each prediction to the truth's global scale first (one factor
        /// per folder, reported): for runs on probes merged from brackets, whose
        /// absolute scale is unknowable.
        #[arg(long)]
        rescale: bool,
        /// Folder of glTF models (.glb/.gltf): also render each lit by every
        /// prediction, baseline and the ground truth, and score the renders (the
        /// thesis's Table 5.1).
        #[arg(long)]
        models: Option<PathBuf>,
        /// Frames rendered per scene with `--models` (spread over the walk; 0 = all).
        #[arg(long, default_value_t = 5)]
        render_frames: usize,
        /// Render size in pixels with `--models`.
        #[arg(long, default_value_t = 256)]
        render_size: usize,
        /// Folder for the report: eval.json, error_vs_distance.csv and .png, and
        /// renders.json with `--models`.
        #[arg(long)]
        report: Option<PathBuf>,
    },
    /// Prefilter a probe for image-based lighting: SH irradiance, irradiance cube,
    /// GGX specular mips and the split-sum BRDF table, as EXR/JSON files.
    Prefilter {
        /// HDR probe (equirect .exr/.hdr/.pfm).
        probe: PathBuf,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        cube: cmd::CubeArgs,
        /// One file per cube face, or one strip of six faces per cube.
        #[arg(long, value_enum, default_value_t = Layout::Faces)]
        layout: Layout,
    },
    /// Render a glTF model lit by a probe (CPU rasterizer, split-sum IBL).
    Render {
        /// glTF 2.0 model (.glb or .gltf).
        model: PathBuf,
        /// HDR probe lighting it (equirect).
        #[arg(long)]
        probe: PathBuf,
        /// Output path; `<out>.exr` (linear) and `<out>.png` (tone-mapped) are written.
        #[arg(long)]
        out: PathBuf,
        /// Image size in pixels (square).
        #[arg(long, default_value_t = 512)]
        size: usize,
        /// Direction the camera looks along, x,y,z in the probe's axes (x right, y up,
        /// -z forward); the model is framed automatically.
        #[arg(long, value_parser = parse_vec3, default_value = "0,-0.35,-1", allow_hyphen_values = true)]
        view: [f32; 3],
        /// Vertical field of view in degrees.
        #[arg(long, value_parser = parse_finite, default_value_t = 35.0)]
        fov: f32,
        /// Transparent background instead of the probe.
        #[arg(long)]
        transparent: bool,
        /// Exposure of the PNG in EV.
        #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
        exposure: f32,
    },
    /// Write a run's probes as engines load them: equirect .hdr/.exr, KTX2
    /// prefiltered cubes, SH for three.js; world-aligned (+Y or +Z up) or per camera.
    Export(cmd::export::ExportArgs),
    /// The manifest's cache: `cache gc MANIFEST` removes what no run of it would
    /// read again.
    Cache(cmd::cache::CacheArgs),
    /// Composite a glTF model, lit by each frame's probe, over the SDR frames (the
    /// thesis's viewer as PNGs and, with ffmpeg, an MP4).
    Composite {
        /// Scene folder.
        scene: PathBuf,
        /// Probes per frame (a `lumiprobe run` output folder).
        #[arg(long)]
        pred: PathBuf,
        /// glTF 2.0 model.
        #[arg(long)]
        model: PathBuf,
        /// World position x,y,z (metres, z up) where the model stands.
        #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
        at: [f32; 3],
        /// Model size: radius of its bounding sphere in metres.
        #[arg(long, value_parser = parse_finite, default_value_t = 0.25)]
        radius: f32,
        /// Turn of the model about the world's up axis, degrees.
        #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
        yaw: f32,
        /// Output folder (frame PNGs, composite.mp4).
        #[arg(long)]
        out: PathBuf,
        /// Output size WxH.
        #[arg(long, value_parser = parse_size, default_value = "640x360")]
        size: (usize, usize),
        /// Frames per second of the video.
        #[arg(long, default_value_t = 10)]
        fps: u32,
    },
    /// Draft a manifest (lumiprobe.toml) for a capture folder: probes (HDR files or
    /// bracket folders), frames (a folder or a video), poses.json when present.
    Init {
        /// The capture folder.
        folder: PathBuf,
        /// Where to write the manifest (default: FOLDER/lumiprobe.toml).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Replace an existing manifest.
        #[arg(long)]
        force: bool,
    },
    /// Find every frame's and probe's pose with COLMAP (pinhole views cut from the
    /// panoramas); with reference poses in the scene, report the errors after a
    /// similarity alignment.
    Localize {
        /// Scene folder (with poses.json) or the poses.json itself.
        scene: PathBuf,
        /// Working folder (views, COLMAP database, model, logs).
        #[arg(long)]
        work: PathBuf,
        /// Write the recovered poses here (dataset layout, COLMAP's frame of reference).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Pinhole views per panorama.
        #[arg(long, default_value_t = 8)]
        views: usize,
        /// View size in pixels.
        #[arg(long, default_value_t = 256)]
        view_size: usize,
        /// Field of view of each view, degrees.
        #[arg(long, value_parser = parse_finite, default_value_t = 120.0)]
        fov: f32,
        /// Read the COLMAP model already in WORK instead of running COLMAP.
        #[arg(long)]
        reuse: bool,
    },
    /// Recover the SDR frames' exposure gain against the probes (radiance =
    /// response⁻¹(code) / gain) and compare it with the scene's documented gain.
    Calibrate {
        /// Scene folder (with poses.json) or the poses.json itself.
        scene: PathBuf,
    },
    /// Convert a side-by-side dual-fisheye image (two-lens 360° cameras such as
    /// the Gear 360) to an equirect panorama: 8-bit in, 8-bit out; HDR in, HDR out.
    Fisheye {
        /// Input image (.jpg/.png, or .exr/.hdr/.pfm).
        input: PathBuf,
        /// Output image, same kind as the input.
        output: PathBuf,
        /// Lens field of view in degrees (at least 180).
        #[arg(long, value_parser = parse_finite, default_value_t = 195.0)]
        fov: f32,
        /// Width in degrees of the cross-fade where both lenses see.
        #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::capture::fisheye::DEFAULT_BLEND_DEG)]
        blend: f32,
        /// Output size WxH (default: the input's size).
        #[arg(long, value_parser = parse_size)]
        size: Option<(usize, usize)>,
    },
    /// Merge exposure brackets into one HDR panorama (Debevec-Malik response
    /// recovery, hat-weighted merge); reports what clipped even in the darkest frame.
    Merge(lumiprobe::capture::MergeArgs),
    /// Scores for two HDR panoramas (the second is the reference).
    Compare {
        /// Prediction.
        a: PathBuf,
        /// Reference.
        b: PathBuf,
    },
    /// Convert between HDR formats (.exr, .hdr, .pfm) by extension; NaN, infinite
    /// and negative samples are repaired (zero; +inf the brightest finite sample)
    /// with a warning that counts them.
    Convert {
        /// Input file.
        input: PathBuf,
        /// Output file.
        output: PathBuf,
        /// Compression when the output is EXR.
        #[arg(long, value_enum, default_value_t = lumiprobe::image::io::ExrCompression::Zip)]
        exr_compression: lumiprobe::image::io::ExrCompression,
    },
    /// Tone-map an HDR image to an 8-bit PNG/JPEG.
    Tonemap {
        /// Input HDR file.
        input: PathBuf,
        /// Output 8-bit file.
        output: PathBuf,
        /// Operator.
        #[arg(long, value_enum, default_value_t = Operator::Reinhard05)]
        operator: Operator,
        /// Exposure in EV for `exposure`.
        #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
        ev: f32,
    },
    /// Cut a panorama into six cube faces (`<stem>_<face>.<ext>`).
    Cube {
        /// Input HDR panorama.
        input: PathBuf,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Face size in pixels (default: width / 4).
        #[arg(long)]
        size: Option<usize>,
    },
    /// Rotate a panorama by yaw/pitch/roll in degrees.
    Rotate {
        /// Input HDR panorama.
        input: PathBuf,
        /// Output HDR panorama.
        output: PathBuf,
        /// Yaw (right positive).
        #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
        yaw: f32,
        /// Pitch (up positive).
        #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
        pitch: f32,
        /// Roll (clockwise positive).
        #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
        roll: f32,
    },
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum Layout {
    /// One file per cube face.
    Faces,
    /// One 6n x n strip per cube.
    Strip,
}

fn parse_vec3(s: &str) -> std::result::Result<[f32; 3], String> {
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

#[derive(Clone, Copy, clap::ValueEnum)]
enum Operator {
    Reinhard05,
    Reinhard,
    Exposure,
}

/// Settings of a run from the command line's method, size and option groups.
fn run_params(
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
fn model_files(dir: &Path) -> Result<Vec<PathBuf>> {
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

fn parse_shard(s: &str) -> std::result::Result<(usize, usize), String> {
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
fn parse_finite(s: &str) -> std::result::Result<f32, String> {
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

fn parse_size(s: &str) -> std::result::Result<(usize, usize), String> {
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

fn progress_printer(quiet: bool, label: &'static str) -> impl Fn(usize, usize) + Sync {
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
fn report_method(dir: &Path) -> Option<String> {
    let text = std::fs::read_to_string(dir.join("report.json")).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    v["params"]["method"].as_str().map(|s| s.to_string())
}

/// Reads an HDR input as every command does: NaN, infinite and negative samples
/// repaired, with one warning that counts them.
fn read_input(path: &Path) -> Result<HdrImage> {
    let (img, warning) = io::read_hdr_repaired(path)?;
    if let Some(w) = warning {
        eprintln!("{w}");
    }
    Ok(img)
}

/// Help headings of the methods' tuning options: listed by `--help-all` only,
/// so that everyday `--help` fits one screen.
const TUNING_WARP: &str = "Warp method tuning";
const TUNING_FLOW: &str = "Flow method tuning";

/// The command line with the tuning options hidden from `--help` (they still
/// parse), and a line saying where they are.
fn compact_help(cmd: clap::Command) -> clap::Command {
    let tuning = |a: &clap::Arg| matches!(a.get_help_heading(), Some(h) if h == TUNING_WARP || h == TUNING_FLOW);
    cmd.mut_subcommands(|sub| {
        let hidden = sub.get_arguments().any(tuning);
        let sub = sub.mut_args(|a| if tuning(&a) { a.hide(true) } else { a });
        if hidden {
            sub.after_help("The warp and flow methods' tuning options: --help-all.")
        } else {
            sub
        }
    })
}

fn main() {
    use clap::{CommandFactory, FromArgMatches};
    // `--help-all` is `--help` with every option shown.
    let mut args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    let all = args.iter().any(|a| a == "--help-all");
    for a in args.iter_mut().filter(|a| *a == "--help-all") {
        *a = "--help".into();
    }
    let cmd = if all {
        Cli::command()
    } else {
        compact_help(Cli::command())
    };
    let cli = Cli::from_arg_matches(&cmd.get_matches_from(args)).unwrap_or_else(|e| e.exit());
    if let Some(n) = cli.threads {
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build_global();
    }
    if let Err(e) = real_main(cli) {
        eprintln!("lumiprobe: {e}");
        std::process::exit(1);
    }
}

/// One line on a finished run: frames computed and resumed, the computed
/// frames' mean time (none when every frame was up to date).
fn run_summary(report: &pipeline::RunReport, out: &std::path::Path) -> String {
    let computed: Vec<&pipeline::FrameRecord> = report
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

fn real_main(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::Run {
            scene,
            out,
            method,
            size,
            calibrate,
            exr_compression,
            dry_run,
            shard,
            set,
            warp,
            flow,
        } => {
            let is_manifest = scene.extension().is_some_and(|e| e == "toml");
            let (mut scene, out, method, size) = if is_manifest {
                let m = lumiprobe::scene::manifest::Manifest::load(&scene)?;
                let (prepared, plan) = lumiprobe::pipeline::plan::prepare(&m, dry_run)?;
                if !cli.quiet || dry_run {
                    print!("{}", plan.to_text());
                }
                let mm = match m.output.method.as_str() {
                    "warp" => Method::Warp,
                    "flow" => Method::Flow,
                    "hybrid" => Method::Hybrid,
                    _ => Method::Fusion,
                };
                let out = out.unwrap_or_else(|| m.output.folder.clone());
                match prepared {
                    Some(s) => (s, out, method.unwrap_or(mm), size.or(m.output.size)),
                    None => return Ok(()),
                }
            } else {
                let out = out.ok_or_else(|| {
                    Error::Invalid("--out is required unless the scene is a manifest".into())
                })?;
                (
                    Scene::load(&scene)?,
                    out,
                    method.unwrap_or(Method::Fusion),
                    size,
                )
            };
            for w in &scene.warnings {
                eprintln!("warning: {w}");
            }
            if calibrate {
                let est = lumiprobe::capture::calibrate::calibrate_gain(
                    &scene,
                    &lumiprobe::capture::calibrate::CalibrateOptions::default(),
                )?;
                if !cli.quiet {
                    eprintln!(
                        "calibrated gain {:.5} from {} frames (log IQR {:.3}; scene file: {:.5})",
                        est.gain, est.frames_used, est.log_iqr, scene.path_gain
                    );
                }
                scene.path_gain = est.gain;
            }
            let mut params = run_params(method, size, &warp, &flow).with_settings(&set)?;
            params.exr_compression = exr_compression;
            if dry_run {
                let pending = pipeline::pending_frames(&scene, &out, &params)?;
                println!(
                    "frames: {} of {} to compute into {} ({} up to date)",
                    pending.len(),
                    scene.frames.len(),
                    out.display(),
                    scene.frames.len() - pending.len()
                );
                return Ok(());
            }
            let report = match shard {
                Some((i, n)) => pipeline::run_shard(
                    &scene,
                    &out,
                    &params,
                    i,
                    n,
                    &progress_printer(cli.quiet, "frames"),
                )?,
                None => pipeline::run(
                    &scene,
                    &out,
                    &params,
                    &progress_printer(cli.quiet, "frames"),
                )?,
            };
            for w in report
                .warnings
                .iter()
                .filter(|w| !scene.warnings.contains(w))
            {
                eprintln!("warning: {w}");
            }
            if !cli.quiet {
                println!("{}", run_summary(&report, &out));
            }
        }
        Cmd::Demo {
            out,
            width,
            frames,
            seed,
        } => {
            if !(64..=4096).contains(&width) {
                return Err(Error::Invalid(format!(
                    "demo width {width} is outside 64..4096"
                )));
            }
            let synth = lumiprobe::synth::SynthParams {
                width,
                n_frames: frames.max(1),
                seed,
                name: "demo".into(),
                ..Default::default()
            };
            let ev = lumiprobe::pipeline::demo::demo(
                &out,
                &synth,
                &[Method::Warp, Method::Flow, Method::Hybrid, Method::Fusion],
                &progress_printer(cli.quiet, "frames"),
            )?;
            println!(
                "demo scene ({} frames, {}x{}) in {}",
                ev.frames.len(),
                width,
                width / 2,
                out.display()
            );
            print!("{}", ev.table.to_text());
        }
        Cmd::Bench {
            scene,
            size,
            bench_threads,
            repeats,
            json,
            method,
            set,
            sweep,
            report,
            point_json,
            warp,
            flow,
        } => {
            let scene_dir = scene;
            let scene = lumiprobe::pipeline::plan::load_scene(&scene_dir, !cli.quiet)?;
            let params = run_params(method, size, &warp, &flow).with_settings(&set)?;
            if let Some(js) = point_json {
                let p: lumiprobe::pipeline::RunParams = serde_json::from_str(&js)
                    .map_err(|e| Error::Invalid(format!("--point-json: {e}")))?;
                let r =
                    lumiprobe::pipeline::bench::bench_scored(&scene, &p, bench_threads, 1, true)?;
                println!(
                    "{}",
                    serde_json::to_string(&r).map_err(|e| Error::Invalid(e.to_string()))?
                );
                return Ok(());
            }
            if sweep {
                use lumiprobe::pipeline::sweep;
                let frame_size = match scene.frames.first() {
                    Some(f) => {
                        let s = io::read_sdr(&f.sdr)?;
                        (s.width(), s.height())
                    }
                    None => (0, 0),
                };
                let points = sweep::plan(&params, frame_size);
                eprintln!(
                    "sweep: {} settings on {} ({} frames, {} thread(s))",
                    points.len(),
                    scene.name,
                    scene.frames.len(),
                    bench_threads
                );
                // Each point in a fresh process, so memory peaks and warm-up costs
                // are its own.
                let exe = std::env::current_exe().map_err(|e| Error::Invalid(e.to_string()))?;
                let measure = |pt: &sweep::SweepPoint| -> lumiprobe::error::Result<
                    lumiprobe::pipeline::bench::BenchReport,
                > {
                    let js = serde_json::to_string(&pt.params)
                        .map_err(|e| Error::Invalid(e.to_string()))?;
                    let out = std::process::Command::new(&exe)
                        .arg("-q")
                        .arg("bench")
                        .arg(&scene_dir)
                        .arg("--bench-threads")
                        .arg(bench_threads.to_string())
                        .arg("--point-json")
                        .arg(&js)
                        .output()
                        .map_err(|e| Error::io(&exe, e))?;
                    if !out.status.success() {
                        return Err(Error::Invalid(format!(
                            "sweep point {} {}: {}",
                            pt.axis,
                            pt.value,
                            String::from_utf8_lossy(&out.stderr).trim()
                        )));
                    }
                    serde_json::from_slice(&out.stdout).map_err(|e| {
                        Error::Invalid(format!(
                            "sweep point {} {}: bad report: {e}",
                            pt.axis, pt.value
                        ))
                    })
                };
                let rows = sweep::run(&scene, &points, measure, |r| {
                    eprintln!(
                        "  {:<14} {:<22} {:>9.1} ms/frame  log RMSE {:.4}  PSNR {:.2}",
                        r.axis, r.value, r.ms_per_frame, r.quality.log_lum_rmse, r.quality.psnr_tm
                    )
                })?;
                let text = sweep::to_text(&rows);
                if json {
                    println!(
                        "{}",
                        serde_json::to_string_pretty(&rows)
                            .map_err(|e| Error::Invalid(e.to_string()))?
                    );
                } else {
                    print!("{text}");
                }
                if let Some(dir) = report {
                    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
                    lumiprobe::fsutil::write_atomic(
                        &dir.join("sweep.csv"),
                        sweep::to_csv(&rows).as_bytes(),
                    )?;
                    lumiprobe::fsutil::write_atomic(&dir.join("sweep.txt"), text.as_bytes())?;
                    let js = serde_json::to_string_pretty(&rows)
                        .map_err(|e| Error::Invalid(e.to_string()))?;
                    lumiprobe::fsutil::write_atomic(&dir.join("sweep.json"), js.as_bytes())?;
                    io::write_sdr(
                        &dir.join("sweep.png"),
                        &sweep::plot(&rows, &scene.name).draw(900, 560),
                    )?;
                    eprintln!("wrote {}/sweep.{{csv,json,txt,png}}", dir.display());
                }
                return Ok(());
            }
            let r = lumiprobe::pipeline::bench::bench(&scene, &params, bench_threads, repeats)?;
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&r).map_err(|e| Error::Invalid(e.to_string()))?
                );
            } else {
                let ws = &r.warp_stages;
                let fs = &r.flow_stages;
                println!(
                    "{} {}x{} {:?}, {} thread(s), {} frames x {}: mean {:.1} ms/frame (median {:.1})",
                    r.scene, r.size.0, r.size.1, r.method, r.threads, r.frames, r.repeats, r.mean_ms, r.median_ms
                );
                if let Some(c) = r.cpu_ms {
                    println!("  CPU time of the worker thread: {c:.1} ms/frame");
                }
                if ws.features_ms + ws.warp_stitch_ms > 0.0 {
                    println!(
                        "  warp: tonemap {:.1}, features {:.1}, matching {:.1}, warp+stitch {:.1} ms",
                        ws.tonemap_ms, ws.features_ms, ws.matching_ms, ws.warp_stitch_ms
                    );
                }
                if fs.flow_ms + fs.graphcut_ms > 0.0 {
                    println!(
                        "  flow: tonemap {:.1}, flow {:.1}, warp+costs {:.1}, graph cut {:.1} ms",
                        fs.tonemap_ms, fs.flow_ms, fs.warp_ms, fs.graphcut_ms
                    );
                }
                if r.fusion_ms > 0.0 {
                    println!(
                        "  fusion (lights carried to the frame + fill): {:.2} ms; finding a probe \
                         pair's lights {:.1} ms once per pair ({} pairs)",
                        r.fusion_ms, r.pair_lights_ms, r.light_pairs
                    );
                }
                println!(
                    "  probe load+preparation {:.1} ms once per probe; peak RSS {}",
                    r.probe_prepare_ms,
                    r.peak_rss_mib
                        .map(|m| format!("{m:.0} MiB"))
                        .unwrap_or_else(|| "n/a".into())
                );
            }
        }
        Cmd::Corpus {
            roots,
            out,
            methods,
            size,
            exr_compression,
            split,
            set,
            warp,
            flow,
        } => {
            use lumiprobe::pipeline::corpus;
            // The same settings as `run` with these options, per method.
            let mut params = run_params(Method::Fusion, size, &warp, &flow);
            params.exr_compression = exr_compression;
            let params = params.with_settings(&set)?;
            let quiet = cli.quiet;
            let report = corpus::run_corpus(
                &roots,
                &out,
                &corpus::CorpusOptions {
                    methods,
                    params,
                    splits: split,
                },
                &|line| {
                    if !quiet {
                        eprintln!("{line}");
                    }
                },
                &progress_printer(quiet, "frames"),
            )?;
            print!("{}", corpus::to_text(&report));
            let failed = report.failed().len();
            if failed > 0 {
                return Err(Error::Invalid(format!(
                    "{failed} of {} scene and method rows failed (see {})",
                    report.rows.len(),
                    out.join("corpus.txt").display()
                )));
            }
        }
        Cmd::Eval {
            scene,
            pred,
            json,
            rescale,
            models,
            render_frames,
            render_size,
            report,
        } => {
            let scene = lumiprobe::pipeline::plan::load_scene(&scene, !cli.quiet)?;
            let labelled: Vec<(String, PathBuf)> = pred
                .iter()
                .map(|p| match p.split_once('=') {
                    Some((l, d)) => (l.to_string(), PathBuf::from(d)),
                    None => {
                        let label =
                            report_method(Path::new(p)).unwrap_or_else(|| "prediction".into());
                        (label, PathBuf::from(p))
                    }
                })
                .collect();
            let refs: Vec<(String, &Path)> = labelled
                .iter()
                .map(|(l, d)| (l.clone(), d.as_path()))
                .collect();
            let ev = if rescale {
                lumiprobe::pipeline::evaluate::evaluate_rescaled(&scene, &refs)?
            } else {
                use lumiprobe::pipeline::evaluate::{scale_factors, scale_warning};
                for ((label, dir), (_, f)) in refs.iter().zip(scale_factors(&scene, &refs)?) {
                    if let Some(w) = scale_warning(label, dir, f) {
                        eprintln!("{w}");
                    }
                }
                lumiprobe::pipeline::evaluate::evaluate(&scene, &refs)?
            };
            if !json {
                for (l, f) in &ev.scales {
                    println!("{l}: rescaled by {f:.5}");
                }
            }
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&ev).map_err(|e| Error::Invalid(e.to_string()))?
                );
            } else {
                println!("scene {}", ev.scene);
                print!("{}", ev.table.to_text());
                print!("{}", lumiprobe::pipeline::evaluate::distance_table(&ev, 3));
            }
            let renders = match &models {
                Some(dir) => {
                    let files = model_files(dir)?;
                    let opts = lumiprobe::pipeline::render_eval::RenderEvalOptions {
                        frames: render_frames,
                        size: render_size,
                        ..Default::default()
                    };
                    let re = lumiprobe::pipeline::render_eval::render_eval(
                        &scene, &refs, &files, &opts,
                    )?;
                    if !json {
                        println!("renders (lit by each probe vs by the ground truth)");
                        print!("{}", re.to_text());
                    }
                    Some(re)
                }
                None => None,
            };
            if let Some(dir) = report {
                std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
                let js =
                    serde_json::to_vec_pretty(&ev).map_err(|e| Error::Invalid(e.to_string()))?;
                lumiprobe::fsutil::write_atomic(&dir.join("eval.json"), &js)?;
                let csv = lumiprobe::pipeline::evaluate::distance_csv(&ev);
                lumiprobe::fsutil::write_atomic(
                    &dir.join("error_vs_distance.csv"),
                    csv.as_bytes(),
                )?;
                let plot = lumiprobe::pipeline::evaluate::distance_plot(&ev, renders.as_ref());
                io::write_sdr(&dir.join("error_vs_distance.png"), &plot.draw(800, 500))?;
                if let Some(re) = &renders {
                    let js =
                        serde_json::to_vec_pretty(re).map_err(|e| Error::Invalid(e.to_string()))?;
                    lumiprobe::fsutil::write_atomic(&dir.join("renders.json"), &js)?;
                }
            }
        }
        Cmd::Composite {
            scene,
            pred,
            model,
            at,
            radius,
            yaw,
            out,
            size,
            fps,
        } => {
            use lumiprobe::pipeline::composite::{composite, CompositeOptions};
            let scene = lumiprobe::pipeline::plan::load_scene(&scene, !cli.quiet)?;
            let opts = CompositeOptions {
                at: glam::Vec3::from(at),
                radius,
                yaw_deg: yaw,
                width: size.0,
                height: size.1,
                ..Default::default()
            };
            let rep = composite(&scene, &pred, &model, &out, &opts, fps)?;
            for w in &rep.warnings {
                eprintln!("{w}");
            }
            if !cli.quiet {
                eprintln!(
                    "{} frames in {}{}{}",
                    rep.frames.len(),
                    out.display(),
                    rep.video
                        .as_ref()
                        .map(|v| format!(", video {}", v.display()))
                        .unwrap_or_else(|| ", no ffmpeg: no video".into()),
                    if rep.skipped.is_empty() {
                        String::new()
                    } else {
                        format!(
                            ", skipped (model behind or too close): {}",
                            rep.skipped.join(" ")
                        )
                    }
                );
            }
        }
        Cmd::Prefilter {
            probe,
            out,
            cube:
                cmd::CubeArgs {
                    face_size,
                    mips,
                    samples,
                },
            layout,
        } => {
            use lumiprobe::ibl::export::{prefilter_image_to_dir, FaceLayout, PrefilterOptions};
            let mut opts = PrefilterOptions::default();
            opts.specular.face_size = face_size;
            opts.specular.mip_count = mips;
            opts.specular.samples = samples;
            opts.layout = match layout {
                Layout::Faces => FaceLayout::Faces,
                Layout::Strip => FaceLayout::Strip,
            };
            let start = std::time::Instant::now();
            let env = read_input(&probe)?;
            let rep = prefilter_image_to_dir(&env, &probe, &out, &opts, start)?;
            if !cli.quiet {
                eprintln!(
                    "prefiltered {} in {:.2} s: {} files in {}",
                    probe.display(),
                    rep.prefilter_seconds,
                    rep.files.len(),
                    out.display()
                );
            }
        }
        Cmd::Render {
            model,
            probe,
            out,
            size,
            view,
            fov,
            transparent,
            exposure,
        } => {
            use lumiprobe::render::{
                render, write_render, Background, Camera, Model, RenderOptions,
            };
            let m = Model::load(&model)?;
            let env_img = read_input(&probe)?;
            let env = lumiprobe::ibl::export::Prefiltered::from_env(
                &env_img,
                &lumiprobe::ibl::export::PrefilterOptions::default(),
            )?;
            let cam = Camera::framing(&m.bounds(), glam::Vec3::from(view), fov, size, size);
            let opts = RenderOptions {
                background: if transparent {
                    Background::Transparent
                } else {
                    Background::Environment
                },
                ..Default::default()
            };
            let r = render(&m, &env, &cam, &opts)?;
            let (a, b) = write_render(&out, &r, exposure)?;
            if !cli.quiet {
                eprintln!("wrote {} and {}", a.display(), b.display());
            }
        }
        Cmd::Init { folder, out, force } => {
            let text = lumiprobe::scene::manifest::Manifest::draft(&folder)?;
            let path = out.unwrap_or_else(|| folder.join("lumiprobe.toml"));
            if path.exists() && !force {
                return Err(Error::Invalid(format!(
                    "{} exists; pass --force to replace it",
                    path.display()
                )));
            }
            lumiprobe::fsutil::write_atomic(&path, text.as_bytes())?;
            // Check that the draft reads back.
            lumiprobe::scene::manifest::Manifest::load(&path)?;
            if !cli.quiet {
                eprintln!("wrote {}", path.display());
            }
        }
        Cmd::Localize {
            scene,
            work,
            out,
            views,
            view_size,
            fov,
            reuse,
        } => {
            use lumiprobe::capture::localize::{localize, pose_errors, LocalizeOptions, Panorama};
            let scene = lumiprobe::pipeline::plan::load_scene(&scene, !cli.quiet)?;
            let opts = LocalizeOptions {
                views,
                view_size,
                fov_deg: fov,
                reuse_model: reuse,
                ..Default::default()
            };
            let t0 = std::time::Instant::now();
            let mut panos = Vec::new();
            for p in &scene.probes {
                // The bracket nearest mid-grey, else the HDR through the frames' camera.
                let files: Vec<&Path> = p.brackets.iter().map(|b| b.file.as_path()).collect();
                let image = match lumiprobe::capture::localize::mid_grey_bracket(&files)? {
                    Some(img) => img,
                    None => {
                        let (hdr, _) = lumiprobe::pipeline::load_probe(
                            &scene,
                            scene.probes.iter().position(|q| q.id == p.id).unwrap_or(0),
                            None,
                        )?;
                        io::linear_to_sdr(&hdr, &scene.response, scene.path_gain)
                    }
                };
                panos.push(Panorama {
                    id: p.id.clone(),
                    is_probe: true,
                    image,
                });
            }
            for f in &scene.frames {
                panos.push(Panorama {
                    id: f.id.clone(),
                    is_probe: false,
                    image: io::read_sdr(&f.sdr)?,
                });
            }
            let loc = localize(&panos, &work, &opts)?;
            let secs = t0.elapsed().as_secs_f64();
            let reference: Vec<(String, lumiprobe::scene::Pose)> = scene
                .probes
                .iter()
                .map(|p| (p.id.clone(), p.pose))
                .chain(scene.frames.iter().map(|f| (f.id.clone(), f.pose)))
                .collect();
            for l in &loc {
                if l.source != lumiprobe::capture::localize::PoseSource::Registered {
                    println!(
                        "{}: {:?} ({} views registered)",
                        l.id, l.source, l.views_registered
                    );
                }
            }
            match pose_errors(&loc, &reference) {
                Some((e, _)) => println!(
                    "{}: {} panoramas, {} registered, {} interpolated, {} missing; after a similarity alignment: position error median {:.3} m, max {:.3} m; after aligning orientations: rotation error median {:.2} deg, max {:.2} deg; relative rotation error between panoramas median {:.2} deg; {:.0} s",
                    scene.name, loc.len(), e.registered, e.interpolated, e.missing,
                    e.median_pos_m, e.max_pos_m, e.median_rot_deg, e.max_rot_deg, e.median_rel_rot_deg, secs
                ),
                None => println!("{}: too few registered panoramas to align ({:.0} s)", scene.name, secs),
            }
            if let Some(path) = out {
                let entry = |id: &str, pose: &lumiprobe::scene::Pose, extra: serde_json::Value| {
                    let m = pose.world_from_camera;
                    let rows: Vec<[f32; 3]> = (0..3)
                        .map(|i| [m.x_axis[i], m.y_axis[i], m.z_axis[i]])
                        .collect();
                    let mut v = serde_json::json!({"id": id, "position": pose.position.to_array(), "world_from_camera": rows});
                    if let (Some(o), Some(e)) = (v.as_object_mut(), extra.as_object()) {
                        for (k, x) in e {
                            o.insert(k.clone(), x.clone());
                        }
                    }
                    v
                };
                let mut probes = Vec::new();
                let mut frames = Vec::new();
                for l in &loc {
                    let Some(pose) = &l.pose else { continue };
                    if l.is_probe {
                        let p = scene
                            .probes
                            .iter()
                            .find(|p| p.id == l.id)
                            .expect("same ids");
                        probes.push(entry(
                            &l.id,
                            pose,
                            serde_json::json!({"hdr": p.hdr, "pose_source": l.source}),
                        ));
                    } else {
                        let f = scene
                            .frames
                            .iter()
                            .find(|f| f.id == l.id)
                            .expect("same ids");
                        frames.push(entry(
                            &l.id,
                            pose,
                            serde_json::json!({"sdr": f.sdr, "pose_source": l.source}),
                        ));
                    }
                }
                let js = serde_json::json!({"scene": scene.name, "probes": probes, "frames": frames,
                    "camera": {"response": format!("{:?}", scene.response), "path_gain": scene.path_gain}});
                lumiprobe::fsutil::write_atomic(
                    &path,
                    serde_json::to_string_pretty(&js)
                        .map_err(|e| Error::Invalid(e.to_string()))?
                        .as_bytes(),
                )?;
            }
        }
        Cmd::Calibrate { scene } => {
            let scene = lumiprobe::pipeline::plan::load_scene(&scene, !cli.quiet)?;
            let est = lumiprobe::capture::calibrate::calibrate_gain(
                &scene,
                &lumiprobe::capture::calibrate::CalibrateOptions::default(),
            )?;
            println!(
                "{}: recovered gain {:.5} from {} frames (spread: log IQR {:.3}); scene file says {:.5} ({:+.2}%)",
                scene.name,
                est.gain,
                est.frames_used,
                est.log_iqr,
                scene.path_gain,
                100.0 * (est.gain / scene.path_gain - 1.0)
            );
        }
        Cmd::Fisheye {
            input,
            output,
            fov,
            blend,
            size,
        } => {
            use lumiprobe::capture::fisheye::{dual_fisheye_to_equirect, DualFisheye};
            let cfg = DualFisheye {
                blend_deg: blend,
                ..DualFisheye::new(fov)
            };
            let named = |e: Error| match e {
                Error::Invalid(m) => Error::Invalid(format!("{}: {m}", input.display())),
                other => other,
            };
            if io::Format::from_extension(&input).is_some_and(|f| f.is_hdr()) {
                let img = read_input(&input)?;
                let (w, h) = size.unwrap_or((img.width(), img.height()));
                let out = dual_fisheye_to_equirect(&img, &cfg, w, h).map_err(named)?;
                io::write_hdr(&output, &out)?;
            } else {
                let img = io::read_sdr(&input)?;
                let (w, h) = size.unwrap_or((img.width(), img.height()));
                let out = dual_fisheye_to_equirect(&img, &cfg, w, h).map_err(named)?;
                io::write_sdr(&output, &out)?;
            }
            if !cli.quiet {
                eprintln!("wrote {}", output.display());
            }
        }
        Cmd::Export(args) => cmd::export::run(args, cli.quiet)?,
        Cmd::Cache(args) => cmd::cache::run(args, cli.quiet)?,
        Cmd::Merge(args) => {
            lumiprobe::capture::run_merge(&args, cli.quiet)?;
        }
        Cmd::Compare { a, b } => {
            let pa = read_input(&a)?;
            let pb = read_input(&b)?;
            let m = lumiprobe::eval::compare_resized(&pa, &pb)?;
            println!(
                "{}",
                serde_json::to_string_pretty(&m).map_err(|e| Error::Invalid(e.to_string()))?
            );
        }
        Cmd::Convert {
            input,
            output,
            exr_compression,
        } => {
            let img = read_input(&input)?;
            let exr = io::ExrWriteOptions {
                compression: exr_compression,
                ..Default::default()
            };
            io::write_hdr_with(&output, &img, &exr)?;
        }
        Cmd::Tonemap {
            input,
            output,
            operator,
            ev,
        } => {
            let img = read_input(&input)?;
            let (w, h) = (img.width(), img.height());
            let codes = match operator {
                // Straight to 8 bits: no float copy of a large panorama.
                Operator::Reinhard05 => {
                    lumiprobe::tonemap::Reinhard05::default().apply_quantized(&img)
                }
                Operator::Reinhard => lumiprobe::tonemap::quantize(
                    &lumiprobe::tonemap::reinhard_global(&img, 0.18, None, None),
                ),
                Operator::Exposure => {
                    lumiprobe::tonemap::quantize(&lumiprobe::tonemap::exposure_srgb(&img, ev))
                }
            };
            drop(img);
            io::write_sdr(&output, &lumiprobe::SdrImage::from_vec(w, h, codes)?)?;
        }
        Cmd::Cube { input, out, size } => {
            let img = read_input(&input)?;
            let n = size.unwrap_or(img.width() / 4).max(1);
            let stem = input
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "face".into());
            let ext = input
                .extension()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "exr".into());
            for (f, face) in lumiprobe::sphere::FACES
                .iter()
                .zip(lumiprobe::sphere::cube::equirect_to_cube(&img, n))
            {
                io::write_hdr(&out.join(format!("{stem}_{}.{ext}", f.name())), &face)?;
            }
        }
        Cmd::Rotate {
            input,
            output,
            yaw,
            pitch,
            roll,
        } => {
            let img = read_input(&input)?;
            let r = lumiprobe::sphere::ypr_to_mat(yaw, pitch, roll);
            let out: HdrImage = lumiprobe::sphere::rotate(&img, r, img.width(), img.height());
            io::write_hdr(&output, &out)?;
        }
    }
    Ok(())
}
