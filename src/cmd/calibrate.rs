//! `lumiprobe calibrate`: the SDR frames' exposure gain against the probes, for
//! the whole walk or frame by frame.

use lumiprobe::capture::calibrate::{calibrate_gain, CalibrateOptions};
use lumiprobe::capture::exposure::{walk_exposure, ExposureOptions};
use lumiprobe::Result;
use std::path::PathBuf;

/// Code ranges with fewer blocks than this do not count in the response's
/// spread.
const MIN_LEVEL_BLOCKS: usize = 50;

/// A short name of a response for the report.
fn response_name(r: &lumiprobe::tonemap::Response) -> String {
    let s = format!("{r:?}");
    s.split_whitespace()
        .next()
        .unwrap_or("")
        .trim_end_matches('{')
        .to_string()
}

/// Arguments of `lumiprobe calibrate`.
#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// Scene folder (with poses.json) or the poses.json itself.
    pub scene: PathBuf,
    /// Each frame's exposure and white balance (a camera with auto-exposure),
    /// smoothed along the walk: a table on stdout, one row per frame.
    #[arg(long)]
    pub per_frame: bool,
    /// With --per-frame: also write the frames' gains as JSON to this file.
    #[arg(long, requires = "per_frame")]
    pub json: Option<PathBuf>,
    /// With --per-frame: match the probe and the frame before to each frame by
    /// optical flow before comparing them (truer gains where the walk nears
    /// lamps; see docs/consumer-video.md).
    #[arg(long, requires = "per_frame")]
    pub follow_flow: bool,
    /// With --per-frame: fit the camera's lens vignetting (a falloff towards
    /// each lens's rim, lenses along the camera's front and back) and take it
    /// out of the gains (see docs/consumer-video.md).
    #[arg(long, requires = "per_frame")]
    pub vignetting: bool,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: CalibrateArgs, quiet: bool) -> Result<()> {
    let CalibrateArgs {
        scene,
        per_frame,
        json,
        follow_flow,
        vignetting,
    } = a;
    let scene = lumiprobe::pipeline::plan::load_scene(&scene, !quiet)?;
    if per_frame {
        let opts = ExposureOptions {
            follow_flow,
            vignetting,
            ..ExposureOptions::default()
        };
        let w = walk_exposure(&scene, &opts)?;
        println!("frame      EV vs scene  white balance (r/g, b/g)  sigma EV  blocks  note");
        let ln2 = std::f64::consts::LN_2;
        for (k, f) in scene.frames.iter().enumerate() {
            let g = w.gain[k];
            let lum = 0.2126 * g[0] + 0.7152 * g[1] + 0.0722 * g[2];
            let m = &w.measured[k];
            let note = if w.outliers.contains(&k) {
                "outlier: its neighbours' gain"
            } else if w.filled.contains(&k) {
                "nothing measured: nearest frame's gain"
            } else {
                ""
            };
            println!(
                "{:<10} {:>+11.3}  {:>10.3} {:>10.3}    {:>8.3}  {:>6}  {note}",
                f.id,
                (lum as f64 / scene.path_gain as f64).ln() / ln2,
                g[0] / g[1],
                g[2] / g[1],
                m.sigma / ln2,
                m.blocks,
            );
        }
        println!(
            "{}: exposure moved {:.2} EV along the walk (measurements' spread {:.1}x their noise): {}",
            scene.name,
            w.swing_ev,
            w.spread_over_noise,
            if w.varies() {
                "it moved along the walk (per-frame gains are worth using)"
            } else {
                "one gain serves the walk"
            }
        );
        if let Some(k) = w.vignetting {
            println!(
                "lens vignetting fitted to the walk: 1 - {k:.2} (angle from the nearer lens axis / 90 deg)^2, \
                 {:.2} EV at the seam; taken out of the gains above",
                -(1.0 - k).max(1e-6).log2()
            );
        }
        // The response the frames were decoded with, against the walk itself.
        let misfit = w.response_misfit_ev(MIN_LEVEL_BLOCKS);
        let levels: Vec<String> = w
            .response_fit
            .iter()
            .map(|l| {
                format!(
                    "{:.0}-{:.0}: {:+.2} ({})",
                    l.codes.0, l.codes.1, l.median_ev, l.blocks
                )
            })
            .collect();
        println!(
            "response ({}): the frames' blocks against the probes by mean code, each frame's gain taken out, \
             median EV (blocks): {}; spread over ranges of {MIN_LEVEL_BLOCKS}+ blocks {misfit:.2} EV \
             (0 where the response is the frames'; see docs/consumer-video.md)",
            response_name(&scene.response),
            levels.join(", "),
        );
        if let Some(path) = json {
            let rows: Vec<serde_json::Value> = scene
                .frames
                .iter()
                .zip(&w.gain)
                .zip(&w.measured)
                .zip(&w.relative)
                .zip(&w.sigma)
                .map(|((((f, g), m), r), s)| {
                    let raw = m.log_gain.map(|v| v.exp());
                    serde_json::json!({"id": f.id, "gain": g, "measured": raw, "sigma": m.sigma, "blocks": m.blocks,
                        "step_log": r.log_luminance_gain, "step_sigma": r.sigma, "step_blocks": r.blocks, "solved_sigma": s})
                })
                .collect();
            let doc = serde_json::json!({
                "scene_gain": scene.path_gain,
                "spread_over_noise": w.spread_over_noise,
                "swing_ev": w.swing_ev,
                "response_fit": w.response_fit,
                "vignetting": w.vignetting,
                "response_misfit_ev": misfit,
                "varies": w.varies(),
                "outliers": w.outliers,
                "filled": w.filled,
                "frames": rows,
            });
            let text = serde_json::to_string_pretty(&doc).expect("JSON of numbers and strings");
            lumiprobe::fsutil::write_atomic(&path, text.as_bytes())?;
        }
        return Ok(());
    }
    let est = calibrate_gain(&scene, &CalibrateOptions::default())?;
    println!(
        "{}: recovered gain {:.5} from {} frames (spread: log IQR {:.3}); scene file says {:.5} ({:+.2}%)",
        scene.name,
        est.gain,
        est.frames_used,
        est.log_iqr,
        scene.path_gain,
        100.0 * (est.gain / scene.path_gain - 1.0)
    );
    Ok(())
}
