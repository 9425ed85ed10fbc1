//! `lumiprobe` command line: one subcommand per workflow step.

use clap::{Parser, Subcommand};
use lumiprobe::Result;

mod cmd;

use cmd::args::*;

#[derive(Parser)]
#[command(
    name = "lumiprobe",
    version,
    about = "HDR light probes at every frame of a 360° SDR walk"
)]
struct Cli {
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// No progress output.
    #[arg(long, short, global = true)]
    quiet: bool,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Predict an HDR probe for every frame of a scene.
    Run(cmd::run::RunArgs),
    /// Synthesize a small scene, run every method on it and print the scores.
    Demo(cmd::demo::DemoArgs),
    /// Time the method per frame (probe features cached) with a stage breakdown.
    Bench(cmd::bench::BenchArgs),
    /// Run methods on every scene of one or more corpora and score them with the
    /// worst case: one row per scene and method, totals per split, a plot.
    Corpus(cmd::corpus::CorpusArgs),
    /// Score predictions against the scene's ground truth, with both baselines.
    Eval(cmd::eval::EvalArgs),
    /// Prefilter a probe for image-based lighting: SH irradiance, irradiance cube,
    /// GGX specular mips and the split-sum BRDF table, as EXR/JSON files.
    Prefilter(cmd::prefilter::PrefilterArgs),
    /// Render a glTF model lit by a probe (CPU rasterizer, split-sum IBL).
    Render(cmd::render::RenderArgs),
    /// Write a run's probes as engines load them: equirect .hdr/.exr, KTX2
    /// prefiltered cubes, SH for three.js; world-aligned (+Y or +Z up) or per camera.
    Export(cmd::export::ExportArgs),
    /// Write a web page (three.js) to look through a run: scrub the walk, the SDR
    /// frame, the probe with an exposure slider, a model lit by the probe and its
    /// lights, the eval plots; `--serve` serves it on 127.0.0.1.
    View(cmd::view::ViewArgs),
    /// The manifest's cache: `cache gc MANIFEST` removes what no run of it would
    /// read again.
    Cache(cmd::cache::CacheArgs),
    /// Composite a glTF model, lit by each frame's probe, over the SDR frames (the
    /// thesis's viewer as PNGs and, with ffmpeg, an MP4).
    Composite(cmd::composite::CompositeArgs),
    /// Draft a manifest (lumiprobe.toml) for a capture folder: probes (HDR files or
    /// bracket folders), frames (a folder or a video), poses.json when present.
    Init(cmd::init::InitArgs),
    /// Find every frame's and probe's pose with COLMAP (pinhole views cut from the
    /// panoramas); with reference poses in the scene, report the errors after a
    /// similarity alignment.
    Localize(cmd::localize::LocalizeArgs),
    /// Recover the SDR frames' exposure gain against the probes (radiance =
    /// response⁻¹(code) / gain) and compare it with the scene's documented gain.
    Calibrate(cmd::calibrate::CalibrateArgs),
    /// Convert a side-by-side dual-fisheye image (two-lens 360° cameras such as
    /// the Gear 360) to an equirect panorama: 8-bit in, 8-bit out; HDR in, HDR out.
    Fisheye(cmd::fisheye::FisheyeArgs),
    /// Merge exposure brackets into one HDR panorama (Debevec-Malik response
    /// recovery, hat-weighted merge); reports what clipped even in the darkest frame.
    Merge(lumiprobe::capture::MergeArgs),
    /// Scores for two HDR panoramas (the second is the reference).
    Compare(cmd::compare::CompareArgs),
    /// Convert between HDR formats (.exr, .hdr, .pfm) by extension; NaN, infinite
    /// and negative samples are repaired (zero; +inf the brightest finite sample)
    /// with a warning that counts them.
    Convert(cmd::convert::ConvertArgs),
    /// Tone-map an HDR image to an 8-bit PNG/JPEG.
    Tonemap(cmd::tonemap::TonemapArgs),
    /// Cut a panorama into six cube faces (`<stem>_<face>.<ext>`).
    Cube(cmd::cube::CubeArgs),
    /// Rotate a panorama by yaw/pitch/roll in degrees.
    Rotate(cmd::rotate::RotateArgs),
}

/// The command line with the tuning options hidden from `--help` (they still
/// parse), and a line saying where they are.
fn compact_help(cmd: clap::Command) -> clap::Command {
    let tuning = |a: &clap::Arg| matches!(a.get_help_heading(), Some(h) if h == TUNING_WARP || h == TUNING_FLOW);
    cmd.mut_subcommands(|sub| {
        let hidden = sub.get_arguments().any(tuning);
        let sub = sub.mut_args(|a| if tuning(&a) { a.hide(true) } else { a });
        if hidden {
            sub.after_help("The warp and flow methods' tuning options: --help-all.")
        } else {
            sub
        }
    })
}

fn main() {
    use clap::{CommandFactory, FromArgMatches};
    // `--help-all` is `--help` with every option shown.
    let mut args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    let all = args.iter().any(|a| a == "--help-all");
    for a in args.iter_mut().filter(|a| *a == "--help-all") {
        *a = "--help".into();
    }
    let cmd = if all {
        Cli::command()
    } else {
        compact_help(Cli::command())
    };
    let cli = Cli::from_arg_matches(&cmd.get_matches_from(args)).unwrap_or_else(|e| e.exit());
    // Frames allocate and free buffers of a few MB each: keep them in the heap
    // (blocks up to 32 MiB, glibc's most; 64 MiB kept) instead of mapping fresh zeroed pages
    // every time. Measured (`bench kitchen --method fusion`, one thread, four
    // alternating runs): 129 -> 107 ms per frame (medians), peak RSS +1 MiB.
    lumiprobe::cv::keep_freed_memory(32 << 20);
    if let Some(n) = cli.threads {
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build_global();
    }
    if let Err(e) = real_main(cli) {
        eprintln!("lumiprobe: {e}");
        std::process::exit(1);
    }
}

fn real_main(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::Run(args) => cmd::run::run(args, cli.quiet)?,
        Cmd::Demo(args) => cmd::demo::run(args, cli.quiet)?,
        Cmd::Bench(args) => cmd::bench::run(args, cli.quiet)?,
        Cmd::Corpus(args) => cmd::corpus::run(args, cli.quiet)?,
        Cmd::Eval(args) => cmd::eval::run(args, cli.quiet)?,
        Cmd::Composite(args) => cmd::composite::run(args, cli.quiet)?,
        Cmd::Prefilter(args) => cmd::prefilter::run(args, cli.quiet)?,
        Cmd::Render(args) => cmd::render::run(args, cli.quiet)?,
        Cmd::Init(args) => cmd::init::run(args, cli.quiet)?,
        Cmd::Localize(args) => cmd::localize::run(args, cli.quiet)?,
        Cmd::Calibrate(args) => cmd::calibrate::run(args, cli.quiet)?,
        Cmd::Fisheye(args) => cmd::fisheye::run(args, cli.quiet)?,
        Cmd::Export(args) => cmd::export::run(args, cli.quiet)?,
        Cmd::View(args) => cmd::view::run(args, cli.quiet)?,
        Cmd::Cache(args) => cmd::cache::run(args, cli.quiet)?,
        Cmd::Merge(args) => {
            lumiprobe::capture::run_merge(&args, cli.quiet)?;
        }
        Cmd::Compare(args) => cmd::compare::run(args, cli.quiet)?,
        Cmd::Convert(args) => cmd::convert::run(args, cli.quiet)?,
        Cmd::Tonemap(args) => cmd::tonemap::run(args, cli.quiet)?,
        Cmd::Cube(args) => cmd::cube::run(args, cli.quiet)?,
        Cmd::Rotate(args) => cmd::rotate::run(args, cli.quiet)?,
    }
    Ok(())
}
