//! `lumiprobe run`: a scene's frames predicted by a method, resumable.

use super::args::*;
use lumiprobe::pipeline::{self, Method};
use lumiprobe::{Error, Result};
use std::path::PathBuf;

/// Whether `run --calibrate` gives each frame its own exposure.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FrameExposure {
    /// One gain for the walk.
    Off,
    /// Each frame's own gain and white balance.
    On,
    /// Each frame's own when the walk's solved exposure moved by more than
    /// `capture::exposure::MIN_SWING_EV`.
    Auto,
}

/// Arguments of `lumiprobe run`.
#[derive(clap::Args)]
pub struct RunArgs {
    /// Scene folder (with poses.json), the poses.json itself, or a manifest
    /// (.toml, see `lumiprobe init`).
    pub scene: PathBuf,
    /// Output folder (default: the manifest's `output.folder`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Method (default: the manifest's, else fusion).
    #[arg(long, value_enum)]
    pub method: Option<Method>,
    /// Print what would be done (stages given, cached or to compute; frames
    /// up to date) and stop.
    #[arg(long)]
    pub dry_run: bool,
    /// Run only shard I of N (frames I, I+N, I+2N, ...), e.g. `--shard
    /// $SLURM_ARRAY_TASK_ID/16`; shards may share the output folder.
    #[arg(long, value_parser = parse_shard)]
    pub shard: Option<(usize, usize)>,
    /// Working size WxH (default: the frames' size).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(usize, usize)>,
    /// Recover the frames' exposure gain against the probes (`lumiprobe
    /// calibrate`) instead of trusting the scene file's.
    #[arg(long)]
    pub calibrate: bool,
    /// With --calibrate, each frame's own exposure (auto-exposing cameras): off (default), on, auto
    #[arg(long, value_enum, default_value_t = FrameExposure::Off, requires = "calibrate", hide_possible_values = true, hide_default_value = true)]
    pub frame_exposure: FrameExposure,
    /// With --frame-exposure, fit the lenses' vignetting and divide it out
    /// (an experiment, off until it wins: hidden from --help;
    /// docs/consumer-video.md)
    #[arg(long, requires = "calibrate", hide = true)]
    pub vignetting: bool,
    /// Compression of the per-frame EXR files: auto, zip, piz or none. By default (`auto`) PIZ under
    /// 4096 pixels wide, where it is both smaller and faster to write than ZIP
    /// (kitchen at 512x256), and ZIP from there, the smallest at 7776x3888 (a
    /// quarter of the raw size, where PIZ writes 3x faster at 1.2x ZIP's
    /// size); none when a trial band shows the frame would not shrink below
    /// 85% (the warp and flow methods' outputs); none is the fastest.
    #[arg(long, value_enum, default_value_t = lumiprobe::pipeline::RunParams::default().exr_compression, hide_possible_values = true)]
    pub exr_compression: lumiprobe::image::io::ExrCompression,
    /// A setting without a flag of its own, as KEY=VALUE (a path into the
    /// settings of `report.json`), e.g. `fusion.walk.mode=two_sided` or
    /// `fusion.ledger=full`; repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Memory (GiB) for the frames computed at once; fewer run at once beyond it, with the same outputs [default: 3/4 of the free memory]
    #[arg(long, value_name = "GIB")]
    pub memory_limit: Option<f64>,
    #[command(flatten)]
    pub warp: WarpOpts,
    #[command(flatten)]
    pub flow: FlowOpts,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: RunArgs, quiet: bool) -> Result<()> {
    let RunArgs {
        scene,
        out,
        method,
        size,
        calibrate,
        frame_exposure,
        vignetting,
        exr_compression,
        dry_run,
        shard,
        set,
        memory_limit,
        warp,
        flow,
    } = a;
    let memory_limit = match memory_limit {
        None => None,
        Some(g) if g.is_finite() && g > 0.0 => Some((g * (1u64 << 30) as f64) as u64),
        Some(g) => {
            return Err(Error::Invalid(format!(
                "--memory-limit {g}: expected a positive number of GiB, e.g. 4"
            )))
        }
    };
    if vignetting && frame_exposure == FrameExposure::Off {
        return Err(Error::Invalid(
            "--vignetting is fitted with each frame's own exposure: give --frame-exposure on (or auto)"
                .into(),
        ));
    }
    let is_manifest = scene.extension().is_some_and(|e| e == "toml");
    let (mut scene, out, method, size) = if is_manifest {
        let m = lumiprobe::scene::manifest::Manifest::load(&scene)?;
        let (prepared, plan) = lumiprobe::pipeline::plan::prepare(&m, dry_run)?;
        if !quiet || dry_run {
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
            lumiprobe::scene::Scene::load(&scene)?,
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
        if !quiet {
            eprintln!(
                "calibrated gain {:.5} from {} frames (log IQR {:.3}; scene file: {:.5})",
                est.gain, est.frames_used, est.log_iqr, scene.path_gain
            );
        }
        scene.path_gain = est.gain;
        if frame_exposure != FrameExposure::Off {
            let w = lumiprobe::capture::exposure::walk_exposure(
                &scene,
                &lumiprobe::capture::exposure::ExposureOptions {
                    vignetting,
                    ..Default::default()
                },
            )?;
            let used = frame_exposure == FrameExposure::On || w.varies();
            if !quiet {
                eprintln!(
                    "frames' exposure moved {:.2} EV along the walk: {}",
                    w.swing_ev,
                    if used {
                        "each frame's own gain used"
                    } else {
                        "one gain for the walk"
                    }
                );
            }
            if !used && vignetting && !quiet {
                eprintln!(
                    "warning: --vignetting not applied: the frames' exposure did not vary beyond its noise, so one gain is used for the walk (give --frame-exposure on to fit it anyway)"
                );
            }
            if used {
                scene.vignetting = w.vignetting.map(|k| k as f32);
                if let (Some(k), false) = (w.vignetting, quiet) {
                    eprintln!("lens vignetting fitted to the walk: 1 - {k:.2} rim, divided out of the frames");
                }
                for (f, g) in scene.frames.iter_mut().zip(&w.gain) {
                    if g.iter().all(|v| v.is_finite() && *v > 0.0) {
                        f.gain = Some(*g);
                    }
                }
            }
        }
    }
    let mut params = run_params(method, size, &warp, &flow).with_settings(&set)?;
    params.exr_compression = exr_compression;
    params.memory_limit = memory_limit;
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
            &progress_printer(quiet, "frames"),
        )?,
        None => pipeline::run(&scene, &out, &params, &progress_printer(quiet, "frames"))?,
    };
    for w in report
        .warnings
        .iter()
        .filter(|w| !scene.warnings.contains(w))
    {
        eprintln!("warning: {w}");
    }
    if !quiet {
        println!("{}", run_summary(&report, &out));
    }
    Ok(())
}
