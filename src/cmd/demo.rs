//! `lumiprobe demo`: the thesis workflow end to end on a synthetic or shared scene.

use super::args::*;
use lumiprobe::pipeline::Method;
use lumiprobe::{Error, Result};
use std::path::PathBuf;

/// Arguments of `lumiprobe demo`.
#[derive(clap::Args)]
pub struct DemoArgs {
    /// Folder for the scene and the predictions.
    #[arg(long, default_value = "lumiprobe-demo")]
    pub out: PathBuf,
    /// Panorama width of the synthetic scene.
    #[arg(long, default_value_t = 512)]
    pub width: usize,
    /// Frames along the walk.
    #[arg(long, default_value_t = 8)]
    pub frames: usize,
    /// Seed of the synthetic scene.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: DemoArgs, quiet: bool) -> Result<()> {
    let DemoArgs {
        out,
        width,
        frames,
        seed,
    } = a;
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
        &progress_printer(quiet, "frames"),
    )?;
    println!(
        "demo scene ({} frames, {}x{}) in {}",
        ev.frames.len(),
        width,
        width / 2,
        out.display()
    );
    print!("{}", ev.table.to_text());
    Ok(())
}
