//! `lumiprobe rotate`: a panorama rotated.

use super::args::*;
use lumiprobe::image::io;
use lumiprobe::Result;
use std::path::PathBuf;

/// Arguments of `lumiprobe rotate`.
#[derive(clap::Args)]
pub struct RotateArgs {
    /// Input HDR panorama.
    pub input: PathBuf,
    /// Output HDR panorama.
    pub output: PathBuf,
    /// Yaw (right positive).
    #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
    pub yaw: f32,
    /// Pitch (up positive).
    #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
    pub pitch: f32,
    /// Roll (clockwise positive).
    #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
    pub roll: f32,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: RotateArgs, _quiet: bool) -> Result<()> {
    let RotateArgs {
        input,
        output,
        yaw,
        pitch,
        roll,
    } = a;
    let img = read_input(&input)?;
    let r = lumiprobe::sphere::ypr_to_mat(yaw, pitch, roll);
    let out: lumiprobe::HdrImage = lumiprobe::sphere::rotate(&img, r, img.width(), img.height());
    io::write_hdr(&output, &out)?;
    Ok(())
}
