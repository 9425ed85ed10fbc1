//! `lumiprobe cache gc`: the cache entries a manifest no longer uses.

use clap::{Args, Subcommand};
use lumiprobe::pipeline::plan::cache_gc;
use lumiprobe::scene::manifest::Manifest;
use lumiprobe::Result;
use std::path::PathBuf;

/// Arguments of `lumiprobe cache`.
#[derive(Args)]
pub struct CacheArgs {
    #[command(subcommand)]
    cmd: CacheCmd,
}

#[derive(Subcommand)]
enum CacheCmd {
    /// Remove what the manifest's cache (<output>/cache/) holds of inputs or
    /// settings that have changed since: merges, responses, localizations,
    /// gains and extracted frames no run of the manifest would read again.
    Gc {
        /// The manifest (lumiprobe.toml).
        manifest: PathBuf,
        /// List what would be removed, remove nothing.
        #[arg(long)]
        dry_run: bool,
    },
}

/// Runs the command; prints what was (or would be) removed unless `quiet`.
pub fn run(a: CacheArgs, quiet: bool) -> Result<()> {
    match a.cmd {
        CacheCmd::Gc { manifest, dry_run } => {
            let m = Manifest::load(&manifest)?;
            let rep = cache_gc(&m, dry_run)?;
            if !quiet {
                for p in &rep.stale {
                    eprintln!(
                        "{} {}",
                        if dry_run { "would remove" } else { "removed" },
                        p.display()
                    );
                }
                eprintln!(
                    "{} {} entries ({:.1} MB), kept {}",
                    if dry_run { "would remove" } else { "removed" },
                    rep.stale.len(),
                    rep.bytes as f64 / 1e6,
                    rep.kept
                );
            }
            Ok(())
        }
    }
}
