//! `lumiprobe init`: a capture folder described as a manifest.

use lumiprobe::{Error, Result};
use std::path::PathBuf;

/// Arguments of `lumiprobe init`.
#[derive(clap::Args)]
pub struct InitArgs {
    /// The capture folder.
    pub folder: PathBuf,
    /// Where to write the manifest (default: FOLDER/lumiprobe.toml).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace an existing manifest.
    #[arg(long)]
    pub force: bool,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: InitArgs, quiet: bool) -> Result<()> {
    let InitArgs { folder, out, force } = a;
    let text = lumiprobe::scene::manifest::Manifest::draft(&folder)?;
    let path = out.unwrap_or_else(|| folder.join("lumiprobe.toml"));
    if path.exists() && !force {
        return Err(Error::Invalid(format!(
            "{} exists; pass --force to replace it",
            path.display()
        )));
    }
    lumiprobe::fsutil::write_atomic(&path, text.as_bytes())?;
    // Check that the draft reads back.
    lumiprobe::scene::manifest::Manifest::load(&path)?;
    if !quiet {
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
