//! `lumiprobe compare`: two HDR images compared.

use super::args::*;
use lumiprobe::Result;
use std::path::PathBuf;

/// Arguments of `lumiprobe compare`.
#[derive(clap::Args)]
pub struct CompareArgs {
    /// Prediction.
    pub a: PathBuf,
    /// Reference.
    pub b: PathBuf,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: CompareArgs, _quiet: bool) -> Result<()> {
    let CompareArgs { a, b } = a;
    let pa = read_input(&a)?;
    let pb = read_input(&b)?;
    let m = lumiprobe::eval::compare_resized(&pa, &pb)?;
    println!("{}", lumiprobe::error::to_json(&m)?);
    Ok(())
}
