//! `lumiprobe tonemap`: an HDR image tone-mapped to 8 bits.

use super::args::*;
use lumiprobe::image::io;
use lumiprobe::Result;
use std::path::PathBuf;

/// The tone-mapping operator.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum Operator {
    Reinhard05,
    Reinhard,
    Exposure,
}

/// Arguments of `lumiprobe tonemap`.
#[derive(clap::Args)]
pub struct TonemapArgs {
    /// Input HDR file.
    pub input: PathBuf,
    /// Output 8-bit file.
    pub output: PathBuf,
    /// Operator.
    #[arg(long, value_enum, default_value_t = Operator::Reinhard05)]
    pub operator: Operator,
    /// Exposure in EV for `exposure` (default: the image's log-average
    /// luminance to middle grey, printed).
    #[arg(long, value_parser = parse_finite, allow_hyphen_values = true)]
    pub ev: Option<f32>,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: TonemapArgs, quiet: bool) -> Result<()> {
    let TonemapArgs {
        input,
        output,
        operator,
        ev,
    } = a;
    let img = read_input(&input)?;
    let (w, h) = (img.width(), img.height());
    let codes = match operator {
        // Straight to 8 bits: no float copy of a large panorama.
        Operator::Reinhard05 => lumiprobe::tonemap::Reinhard05::default().apply_quantized(&img),
        Operator::Reinhard => lumiprobe::tonemap::quantize(&lumiprobe::tonemap::reinhard_global(
            &img, 0.18, None, None,
        )),
        Operator::Exposure => {
            let ev = ev.unwrap_or_else(|| {
                let ev = lumiprobe::tonemap::auto_exposure_ev(&img);
                if !quiet {
                    eprintln!("exposure {ev:+.2} EV (auto: the log-average luminance to 0.18; --ev fixes it)");
                }
                ev
            });
            lumiprobe::tonemap::quantize(&lumiprobe::tonemap::exposure_srgb(&img, ev))
        }
    };
    drop(img);
    io::write_sdr(&output, &lumiprobe::SdrImage::from_vec(w, h, codes)?)?;
    Ok(())
}
