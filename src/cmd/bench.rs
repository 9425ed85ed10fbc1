//! `lumiprobe bench`: the method timed per frame, with a stage breakdown, and the error-against-time sweep.

use super::args::*;
use lumiprobe::image::io;
use lumiprobe::pipeline::Method;
use lumiprobe::{Error, Result};
use std::path::PathBuf;

/// Arguments of `lumiprobe bench`.
#[derive(clap::Args)]
pub struct BenchArgs {
    /// Scene folder.
    pub scene: PathBuf,
    /// Working size WxH (default: the frames' size).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(usize, usize)>,
    /// Threads for the timed runs.
    #[arg(long, default_value_t = 1)]
    pub bench_threads: usize,
    /// Repetitions over all frames.
    #[arg(long, default_value_t = 3)]
    pub repeats: usize,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Method (the same default as `run`).
    #[arg(long, value_enum, default_value_t = Method::Fusion)]
    pub method: Method,
    /// A setting as KEY=VALUE, as for `corpus` (`fusion.ledger="full"`);
    /// repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Error against run time: vary the settings that trade time for quality
    /// (method, size 256..2048 wide, yaw rotations, detector, ratio, flow preset,
    /// graph-cut cycles, smoothness, fusion base) one at a time around the given
    /// ones, time and score each on the scene, and mark the Pareto front.
    #[arg(long)]
    pub sweep: bool,
    /// Folder for the sweep's sweep.csv, sweep.json, sweep.txt and sweep.png.
    #[arg(long, requires = "sweep")]
    pub report: Option<PathBuf>,
    /// Internal to `--sweep`: time and score these settings (JSON) in this
    /// process, printing the JSON report.
    #[arg(long, hide = true)]
    pub point_json: Option<String>,
    #[command(flatten)]
    pub warp: WarpOpts,
    #[command(flatten)]
    pub flow: FlowOpts,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: BenchArgs, quiet: bool) -> Result<()> {
    let BenchArgs {
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
    } = a;
    let scene_dir = scene;
    let scene = lumiprobe::pipeline::plan::load_scene(&scene_dir, !quiet)?;
    let params = run_params(method, size, &warp, &flow).with_settings(&set)?;
    if let Some(js) = point_json {
        let p: lumiprobe::pipeline::RunParams =
            serde_json::from_str(&js).map_err(|e| Error::Invalid(format!("--point-json: {e}")))?;
        let r = lumiprobe::pipeline::bench::bench_scored(&scene, &p, bench_threads, 1, true)?;
        println!(
            "{}",
            serde_json::to_string(&r).map_err(|e| Error::Internal(format!("JSON: {e}")))?
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
        let exe =
            std::env::current_exe().map_err(|e| Error::Internal(format!("own executable: {e}")))?;
        let measure = |pt: &sweep::SweepPoint| -> lumiprobe::error::Result<
            lumiprobe::pipeline::bench::BenchReport,
        > {
            let js = serde_json::to_string(&pt.params)
                .map_err(|e| Error::Internal(format!("settings: {e}")))?;
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
            println!("{}", lumiprobe::error::to_json(&rows)?);
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
            let js = lumiprobe::error::to_json(&rows)?;
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
        println!("{}", lumiprobe::error::to_json(&r)?);
    } else {
        let ws = &r.warp_stages;
        let fs = &r.flow_stages;
        println!(
            "{} {}x{} {:?}, {} thread(s), {} frames x {}: mean {:.1} ms/frame (median {:.1})",
            r.scene,
            r.size.0,
            r.size.1,
            r.method,
            r.threads,
            r.frames,
            r.repeats,
            r.mean_ms,
            r.median_ms
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
    Ok(())
}
