//! `lumiprobe cube`: an equirectangular panorama to cube faces.

use super::args::*;
use lumiprobe::image::io;
use lumiprobe::Result;
use std::path::PathBuf;

/// Arguments of `lumiprobe cube`.
#[derive(clap::Args)]
pub struct CubeArgs {
    /// Input HDR panorama.
    pub input: PathBuf,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Face size in pixels (default: width / 4).
    #[arg(long)]
    pub size: Option<usize>,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: CubeArgs, _quiet: bool) -> Result<()> {
    let CubeArgs { input, out, size } = a;
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
    Ok(())
}
