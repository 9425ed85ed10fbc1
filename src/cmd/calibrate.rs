//! `lumiprobe calibrate`: the SDR frames' exposure gain against the probes.

use lumiprobe::Result;
use std::path::PathBuf;

/// Arguments of `lumiprobe calibrate`.
#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// Scene folder (with poses.json) or the poses.json itself.
    pub scene: PathBuf,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: CalibrateArgs, quiet: bool) -> Result<()> {
    let CalibrateArgs { scene } = a;
    let scene = lumiprobe::pipeline::plan::load_scene(&scene, !quiet)?;
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
    Ok(())
}
