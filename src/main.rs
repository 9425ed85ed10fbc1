//! `lumiprobe` command line: one subcommand per workflow step.

use clap::{Parser, Subcommand};
use lumiprobe::image::io;
use lumiprobe::{Error, HdrImage, Result};
use std::path::PathBuf;

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
    /// The manifest's cache: `cache gc MANIFEST` removes what no run of it would
    /// read again.
    Cache(cmd::cache::CacheArgs),
    /// Composite a glTF model, lit by each frame's probe, over the SDR frames (the
    /// thesis's viewer as PNGs and, with ffmpeg, an MP4).
    Composite(cmd::composite::CompositeArgs),
    /// Draft a manifest (lumiprobe.toml) for a capture folder: probes (HDR files or
    /// bracket folders), frames (a folder or a video), poses.json when present.
    Init {
        /// The capture folder.
        folder: PathBuf,
        /// Where to write the manifest (default: FOLDER/lumiprobe.toml).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Replace an existing manifest.
        #[arg(long)]
        force: bool,
    },
    /// Find every frame's and probe's pose with COLMAP (pinhole views cut from the
    /// panoramas); with reference poses in the scene, report the errors after a
    /// similarity alignment.
    Localize(cmd::localize::LocalizeArgs),
    /// Recover the SDR frames' exposure gain against the probes (radiance =
    /// response⁻¹(code) / gain) and compare it with the scene's documented gain.
    Calibrate {
        /// Scene folder (with poses.json) or the poses.json itself.
        scene: PathBuf,
    },
    /// Convert a side-by-side dual-fisheye image (two-lens 360° cameras such as
    /// the Gear 360) to an equirect panorama: 8-bit in, 8-bit out; HDR in, HDR out.
    Fisheye {
        /// Input image (.jpg/.png, or .exr/.hdr/.pfm).
        input: PathBuf,
        /// Output image, same kind as the input.
        output: PathBuf,
        /// Lens field of view in degrees (at least 180).
        #[arg(long, value_parser = parse_finite, default_value_t = 195.0)]
        fov: f32,
        /// Width in degrees of the cross-fade where both lenses see.
        #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::capture::fisheye::DEFAULT_BLEND_DEG)]
        blend: f32,
        /// Output size WxH (default: the input's size).
        #[arg(long, value_parser = parse_size)]
        size: Option<(usize, usize)>,
    },
    /// Merge exposure brackets into one HDR panorama (Debevec-Malik response
    /// recovery, hat-weighted merge); reports what clipped even in the darkest frame.
    Merge(lumiprobe::capture::MergeArgs),
    /// Scores for two HDR panoramas (the second is the reference).
    Compare {
        /// Prediction.
        a: PathBuf,
        /// Reference.
        b: PathBuf,
    },
    /// Convert between HDR formats (.exr, .hdr, .pfm) by extension; NaN, infinite
    /// and negative samples are repaired (zero; +inf the brightest finite sample)
    /// with a warning that counts them.
    Convert {
        /// Input file.
        input: PathBuf,
        /// Output file.
        output: PathBuf,
        /// Compression when the output is EXR.
        #[arg(long, value_enum, default_value_t = lumiprobe::image::io::ExrCompression::Zip)]
        exr_compression: lumiprobe::image::io::ExrCompression,
    },
    /// Tone-map an HDR image to an 8-bit PNG/JPEG.
    Tonemap {
        /// Input HDR file.
        input: PathBuf,
        /// Output 8-bit file.
        output: PathBuf,
        /// Operator.
        #[arg(long, value_enum, default_value_t = Operator::Reinhard05)]
        operator: Operator,
        /// Exposure in EV for `exposure`.
        #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
        ev: f32,
    },
    /// Cut a panorama into six cube faces (`<stem>_<face>.<ext>`).
    Cube {
        /// Input HDR panorama.
        input: PathBuf,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Face size in pixels (default: width / 4).
        #[arg(long)]
        size: Option<usize>,
    },
    /// Rotate a panorama by yaw/pitch/roll in degrees.
    Rotate {
        /// Input HDR panorama.
        input: PathBuf,
        /// Output HDR panorama.
        output: PathBuf,
        /// Yaw (right positive).
        #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
        yaw: f32,
        /// Pitch (up positive).
        #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
        pitch: f32,
        /// Roll (clockwise positive).
        #[arg(long, value_parser = parse_finite, default_value_t = 0.0, allow_hyphen_values = true)]
        roll: f32,
    },
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum Operator {
    Reinhard05,
    Reinhard,
    Exposure,
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
        Cmd::Init { folder, out, force } => {
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
            if !cli.quiet {
                eprintln!("wrote {}", path.display());
            }
        }
        Cmd::Localize(args) => cmd::localize::run(args, cli.quiet)?,
        Cmd::Calibrate { scene } => {
            let scene = lumiprobe::pipeline::plan::load_scene(&scene, !cli.quiet)?;
            let est = lumiprobe::capture::calibrate::calibrate_gain(
                &scene,
                &lumiprobe::capture::calibrate::CalibrateOptions::default(),
            )?;
            println!(
                "{}: recovered gain {:.5} from {} frames (spread: log IQR {:.3}); scene file says {:.5} ({:+.2}%)",
                scene.name,
                est.gain,
                est.frames_used,
                est.log_iqr,
                scene.path_gain,
                100.0 * (est.gain / scene.path_gain - 1.0)
            );
        }
        Cmd::Fisheye {
            input,
            output,
            fov,
            blend,
            size,
        } => {
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
            if !cli.quiet {
                eprintln!("wrote {}", output.display());
            }
        }
        Cmd::Export(args) => cmd::export::run(args, cli.quiet)?,
        Cmd::Cache(args) => cmd::cache::run(args, cli.quiet)?,
        Cmd::Merge(args) => {
            lumiprobe::capture::run_merge(&args, cli.quiet)?;
        }
        Cmd::Compare { a, b } => {
            let pa = read_input(&a)?;
            let pb = read_input(&b)?;
            let m = lumiprobe::eval::compare_resized(&pa, &pb)?;
            println!(
                "{}",
                serde_json::to_string_pretty(&m).map_err(|e| Error::Invalid(e.to_string()))?
            );
        }
        Cmd::Convert {
            input,
            output,
            exr_compression,
        } => {
            let img = read_input(&input)?;
            let exr = io::ExrWriteOptions {
                compression: exr_compression,
                ..Default::default()
            };
            io::write_hdr_with(&output, &img, &exr)?;
        }
        Cmd::Tonemap {
            input,
            output,
            operator,
            ev,
        } => {
            let img = read_input(&input)?;
            let (w, h) = (img.width(), img.height());
            let codes = match operator {
                // Straight to 8 bits: no float copy of a large panorama.
                Operator::Reinhard05 => {
                    lumiprobe::tonemap::Reinhard05::default().apply_quantized(&img)
                }
                Operator::Reinhard => lumiprobe::tonemap::quantize(
                    &lumiprobe::tonemap::reinhard_global(&img, 0.18, None, None),
                ),
                Operator::Exposure => {
                    lumiprobe::tonemap::quantize(&lumiprobe::tonemap::exposure_srgb(&img, ev))
                }
            };
            drop(img);
            io::write_sdr(&output, &lumiprobe::SdrImage::from_vec(w, h, codes)?)?;
        }
        Cmd::Cube { input, out, size } => {
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
        }
        Cmd::Rotate {
            input,
            output,
            yaw,
            pitch,
            roll,
        } => {
            let img = read_input(&input)?;
            let r = lumiprobe::sphere::ypr_to_mat(yaw, pitch, roll);
            let out: HdrImage = lumiprobe::sphere::rotate(&img, r, img.width(), img.height());
            io::write_hdr(&output, &out)?;
        }
    }
    Ok(())
}
