//! `lumiprobe` command line: one subcommand per workflow step.

use clap::{Args, Parser, Subcommand};
use lumiprobe::cv::{Detector, Estimator};
use lumiprobe::image::io;
use lumiprobe::pipeline::{self, Method, RunParams};
use lumiprobe::scene::Scene;
use lumiprobe::warp::{CandidateMode, ProbeTonemap};
use lumiprobe::{Error, HdrImage, Result};
use std::path::{Path, PathBuf};

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
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().blur_sigma)]
    blur_sigma: f32,
    /// Candidates per face when matching by pose.
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().pose_candidates)]
    pose_candidates: usize,
    /// FLANN leaf checks per query (0 = exact brute-force matching).
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().flann_checks)]
    flann_checks: i32,
    /// Lowe ratio-test threshold.
    #[arg(long, default_value_t = 0.7)]
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
    #[arg(long, default_value_t = lumiprobe::warp::WarpParams::default().face_extent)]
    face_extent: f32,
    /// Cube face size (default: a quarter of the panorama width).
    #[arg(long)]
    face_size: Option<usize>,
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
            max_features: self.max_features,
            detector_threshold: self.detector_threshold,
            blur_sigma: self.blur_sigma,
            pose_candidates: self.pose_candidates,
            ..Default::default()
        }
    }
}

#[derive(Args, Clone)]
struct FlowOpts {
    /// DIS optical-flow preset.
    #[arg(long, value_enum, default_value_t = lumiprobe::flow::dense::FlowPreset::Fast)]
    flow_preset: lumiprobe::flow::dense::FlowPreset,
    /// Weight of the graph cut's seam cost.
    #[arg(long, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().lambda)]
    lambda: f32,
    /// Data cost of the SDR label (thesis: 500).
    #[arg(long, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().sdr_cost)]
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
    /// What a clipped region inherits from the base method's light in `--method fusion`.
    #[arg(long, value_enum, default_value_t = lumiprobe::fusion::FusionParams::default().transfer)]
    fusion_transfer: lumiprobe::fusion::Transfer,
    /// Box radius over which the colour term is averaged (0 = per pixel).
    #[arg(long, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().dc_radius)]
    dc_radius: usize,
    /// Seam-cost weight where the SDR frame measured (did not clip), relative to clipped regions
    #[arg(long, default_value_t = lumiprobe::flow::method::FlowMethodParams::default().seam_measured)]
    seam_measured: f32,
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
        /// Scene folder (with poses.json) or the poses.json itself.
        scene: PathBuf,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Method.
        #[arg(long, value_enum, default_value_t = Method::Warp)]
        method: Method,
        /// Working size WxH (default: the frames' size).
        #[arg(long, value_parser = parse_size)]
        size: Option<(usize, usize)>,
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
        /// Method.
        #[arg(long, value_enum, default_value_t = Method::Warp)]
        method: Method,
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
    },
    /// Scores for two HDR panoramas (the second is the reference).
    Compare {
        /// Prediction.
        a: PathBuf,
        /// Reference.
        b: PathBuf,
    },
    /// Convert between HDR formats (.exr, .hdr, .pfm) by extension.
    Convert {
        /// Input file.
        input: PathBuf,
        /// Output file.
        output: PathBuf,
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
        #[arg(long, default_value_t = 0.0)]
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
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        yaw: f32,
        /// Pitch (up positive).
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        pitch: f32,
        /// Roll (clockwise positive).
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        roll: f32,
    },
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
        fusion: lumiprobe::fusion::FusionParams {
            transfer: flow.fusion_transfer,
            ..Default::default()
        },
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
    if w < 8 || h < 4 || w > 65536 || h > 32768 {
        return Err(format!("size {w}x{h} is outside 8x4 .. 65536x32768"));
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

fn write_display(path: &Path, w: usize, h: usize, v: &[f32]) -> Result<()> {
    let img = lumiprobe::SdrImage::from_vec(w, h, lumiprobe::tonemap::quantize(v))?;
    io::write_sdr(path, &img)
}

/// The method named in a run folder's report.json, for labelling eval rows.
fn report_method(dir: &Path) -> Option<String> {
    let text = std::fs::read_to_string(dir.join("report.json")).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    v["params"]["method"].as_str().map(|s| s.to_string())
}

fn main() {
    let cli = Cli::parse();
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

fn real_main(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::Run {
            scene,
            out,
            method,
            size,
            warp,
            flow,
        } => {
            let scene = Scene::load(&scene)?;
            for w in &scene.warnings {
                eprintln!("warning: {w}");
            }
            let params = run_params(method, size, &warp, &flow);
            let report = pipeline::run(
                &scene,
                &out,
                &params,
                &progress_printer(cli.quiet, "frames"),
            )?;
            if !cli.quiet {
                let n = report.frames.len().max(1) as f64;
                let mean_ms: f64 = report.frames.iter().map(|f| f.total_ms).sum::<f64>() / n;
                let homog: usize = report
                    .frames
                    .iter()
                    .filter_map(|f| f.warp.as_ref())
                    .map(|w| w.faces.iter().filter(|x| x.source == "homography").count())
                    .sum();
                println!(
                    "{}: {} frames ({} resumed), {:.1} ms per frame, {} faces used a homography; report: {}",
                    report.scene,
                    report.frames.len(),
                    report.resumed.len(),
                    mean_ms,
                    homog,
                    out.join("report.json").display()
                );
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
            warp,
            flow,
        } => {
            let scene = Scene::load(&scene)?;
            let params = run_params(method, size, &warp, &flow);
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
                    println!("  fusion (light placement + fill): {:.2} ms", r.fusion_ms);
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
        Cmd::Eval { scene, pred, json } => {
            let scene = Scene::load(&scene)?;
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
            let ev = lumiprobe::pipeline::evaluate::evaluate(&scene, &refs)?;
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&ev).map_err(|e| Error::Invalid(e.to_string()))?
                );
            } else {
                println!("scene {}", ev.scene);
                print!("{}", ev.table.to_text());
            }
        }
        Cmd::Compare { a, b } => {
            let pa = io::read_hdr(&a)?;
            let pb = io::read_hdr(&b)?;
            let m = lumiprobe::eval::compare_resized(&pa, &pb)?;
            println!(
                "{}",
                serde_json::to_string_pretty(&m).map_err(|e| Error::Invalid(e.to_string()))?
            );
        }
        Cmd::Convert { input, output } => {
            let img = io::read_hdr(&input)?;
            io::write_hdr(&output, &img)?;
        }
        Cmd::Tonemap {
            input,
            output,
            operator,
            ev,
        } => {
            let img = io::read_hdr(&input)?;
            let v = match operator {
                Operator::Reinhard05 => lumiprobe::tonemap::Reinhard05::default().apply(&img),
                Operator::Reinhard => lumiprobe::tonemap::reinhard_global(&img, 0.18, None, None),
                Operator::Exposure => lumiprobe::tonemap::exposure_srgb(&img, ev),
            };
            write_display(&output, img.width(), img.height(), &v)?;
        }
        Cmd::Cube { input, out, size } => {
            let img = io::read_hdr(&input)?;
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
            let img = io::read_hdr(&input)?;
            let r = lumiprobe::sphere::ypr_to_mat(yaw, pitch, roll);
            let out: HdrImage = lumiprobe::sphere::rotate(&img, r, img.width(), img.height());
            io::write_hdr(&output, &out)?;
        }
    }
    Ok(())
}
