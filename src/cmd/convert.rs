//! `lumiprobe convert`: an HDR image converted between formats.

use super::args::*;
use lumiprobe::image::io;
use lumiprobe::Result;
use std::path::PathBuf;

/// Arguments of `lumiprobe convert`.
#[derive(clap::Args)]
pub struct ConvertArgs {
    /// Input file.
    pub input: PathBuf,
    /// Output file.
    pub output: PathBuf,
    /// Compression when the output is EXR.
    #[arg(long, value_enum, default_value_t = lumiprobe::image::io::ExrCompression::Zip)]
    pub exr_compression: lumiprobe::image::io::ExrCompression,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: ConvertArgs, _quiet: bool) -> Result<()> {
    let ConvertArgs {
        input,
        output,
        exr_compression,
    } = a;
    let img = read_input(&input)?;
    let exr = io::ExrWriteOptions {
        compression: exr_compression,
        ..Default::default()
    };
    io::write_hdr_with(&output, &img, &exr)?;
    Ok(())
}
