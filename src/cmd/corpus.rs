//! `lumiprobe corpus`: methods run and scored on every scene of one or more corpora.

use super::args::*;
use lumiprobe::pipeline::Method;
use lumiprobe::{Error, Result};
use std::path::PathBuf;

/// Arguments of `lumiprobe corpus`.
#[derive(clap::Args)]
pub struct CorpusArgs {
    /// Corpus folders (holding corpus.json) or folders of scene folders (each
    /// holding a poses.json; split "shared").
    #[arg(required = true)]
    pub roots: Vec<PathBuf>,
    /// Output folder: OUT/<scene>/<method> per run, corpus.txt, corpus.csv,
    /// corpus.json and corpus_worst_irradiance.png.
    #[arg(long)]
    pub out: PathBuf,
    /// Methods, comma-separated.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [Method::Warp, Method::Flow, Method::Hybrid, Method::Fusion])]
    pub methods: Vec<Method>,
    /// Working size WxH (default: the frames' size).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(usize, usize)>,
    /// Compression of the per-frame EXR files (as for `run`).
    #[arg(long, value_enum, default_value_t = lumiprobe::pipeline::RunParams::default().exr_compression)]
    pub exr_compression: lumiprobe::image::io::ExrCompression,
    /// Only the scenes of these splits, comma-separated (default: all).
    #[arg(long, value_enum, value_delimiter = ',')]
    pub split: Vec<lumiprobe::pipeline::corpus::Split>,
    /// A setting as KEY=VALUE, KEY a path into the run's settings
    /// (`fusion.max_angle_deg=5`); repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    #[command(flatten)]
    pub warp: WarpOpts,
    #[command(flatten)]
    pub flow: FlowOpts,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: CorpusArgs, quiet: bool) -> Result<()> {
    let CorpusArgs {
        roots,
        out,
        methods,
        size,
        exr_compression,
        split,
        set,
        warp,
        flow,
    } = a;
    use lumiprobe::pipeline::corpus;
    // The same settings as `run` with these options, per method.
    let mut params = run_params(Method::Fusion, size, &warp, &flow);
    params.exr_compression = exr_compression;
    let params = params.with_settings(&set)?;
    let report = corpus::run_corpus(
        &roots,
        &out,
        &corpus::CorpusOptions {
            methods,
            params,
            splits: split,
        },
        &|line| {
            if !quiet {
                eprintln!("{line}");
            }
        },
        &progress_printer(quiet, "frames"),
    )?;
    print!("{}", corpus::to_text(&report));
    let failed = report.failed().len();
    if failed > 0 {
        return Err(Error::Invalid(format!(
            "{failed} of {} scene and method rows failed (see {})",
            report.rows.len(),
            out.join("corpus.txt").display()
        )));
    }
    Ok(())
}
