//! `lumiprobe composite`: a model composited into the SDR frames, lit by each frame's probe.

use super::args::*;
use lumiprobe::Result;
use std::path::PathBuf;

/// Arguments of `lumiprobe composite`.
#[derive(clap::Args)]
pub struct CompositeArgs {
    /// Scene folder.
    pub scene: PathBuf,
    /// Probes per frame (a `lumiprobe run` output folder).
    #[arg(long)]
    pub pred: PathBuf,
    /// glTF 2.0 model.
    #[arg(long)]
    pub model: PathBuf,
    /// World position x,y,z (metres, z up) where the model stands.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub at: [f32; 3],
    /// Model size: radius of its bounding sphere in metres.
    #[arg(long, value_parser = parse_finite, default_value_t = 0.25)]
    pub radius: f32,
    /// Turn of the model about the world's up axis, degrees.
    #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
    pub yaw: f32,
    /// Output folder (frame PNGs, composite.mp4).
    #[arg(long)]
    pub out: PathBuf,
    /// Output size WxH.
    #[arg(long, value_parser = parse_size, default_value = "640x360")]
    pub size: (usize, usize),
    /// Frames per second of the video.
    #[arg(long, default_value_t = 10)]
    pub fps: u32,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: CompositeArgs, quiet: bool) -> Result<()> {
    let CompositeArgs {
        scene,
        pred,
        model,
        at,
        radius,
        yaw,
        out,
        size,
        fps,
    } = a;
    use lumiprobe::pipeline::composite::{composite, CompositeOptions};
    let scene = lumiprobe::pipeline::plan::load_scene(&scene, !quiet)?;
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
    if !quiet {
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
    Ok(())
}
