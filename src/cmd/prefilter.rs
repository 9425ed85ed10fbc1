//! `lumiprobe prefilter`: IBL prefiltering of a probe.

use super::args::*;
use lumiprobe::Result;
use std::path::PathBuf;

/// Arguments of `lumiprobe prefilter`.
#[derive(clap::Args)]
pub struct PrefilterArgs {
    /// HDR probe (equirect .exr/.hdr/.pfm).
    pub probe: PathBuf,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub cube: super::CubeArgs,
    /// One file per cube face, or one strip of six faces per cube.
    #[arg(long, value_enum, default_value_t = Layout::Faces)]
    pub layout: Layout,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: PrefilterArgs, quiet: bool) -> Result<()> {
    let PrefilterArgs {
        probe,
        out,
        cube:
            super::CubeArgs {
                face_size,
                mips,
                samples,
            },
        layout,
    } = a;
    use lumiprobe::ibl::export::{prefilter_image_to_dir, FaceLayout, PrefilterOptions};
    let mut opts = PrefilterOptions::default();
    opts.specular.face_size = face_size;
    opts.specular.mip_count = mips;
    opts.specular.samples = samples;
    opts.layout = match layout {
        Layout::Faces => FaceLayout::Faces,
        Layout::Strip => FaceLayout::Strip,
    };
    let start = std::time::Instant::now();
    let env = read_input(&probe)?;
    let rep = prefilter_image_to_dir(&env, &probe, &out, &opts, start)?;
    if !quiet {
        eprintln!(
            "prefiltered {} in {:.2} s: {} files in {}",
            probe.display(),
            rep.prefilter_seconds,
            rep.files.len(),
            out.display()
        );
    }
    Ok(())
}
