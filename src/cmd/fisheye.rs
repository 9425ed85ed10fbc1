//! `lumiprobe fisheye`: dual-fisheye images stitched to an equirectangular panorama.

use super::args::*;
use lumiprobe::image::io;
use lumiprobe::{Error, Result};
use std::path::PathBuf;

/// Arguments of `lumiprobe fisheye`.
#[derive(clap::Args)]
pub struct FisheyeArgs {
    /// Input image (.jpg/.png, or .exr/.hdr/.pfm).
    pub input: PathBuf,
    /// Output image, same kind as the input.
    pub output: PathBuf,
    /// Lens field of view in degrees (at least 180).
    #[arg(long, value_parser = parse_finite, default_value_t = 195.0)]
    pub fov: f32,
    /// Width in degrees of the cross-fade where both lenses see.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::capture::fisheye::DEFAULT_BLEND_DEG)]
    pub blend: f32,
    /// Output size WxH (default: the input's size).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(usize, usize)>,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: FisheyeArgs, quiet: bool) -> Result<()> {
    let FisheyeArgs {
        input,
        output,
        fov,
        blend,
        size,
    } = a;
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
    if !quiet {
        eprintln!("wrote {}", output.display());
    }
    Ok(())
}
