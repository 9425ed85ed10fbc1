//! The `lumiprobe merge` command: exposure brackets (JPEG/PNG) to one HDR file.
//!
//! Exposure times come from each file's Exif `ExposureTime` unless `--times`
//! gives them. The response is recovered from the brackets themselves
//! (Debevec & Malik 1997) unless `--response documented` (the evaluation data's
//! published curve) or a curve saved earlier with `--save-response` is given.

use super::debevec::{recover, RecoverOptions, ResponseCurve, DEFAULT_LAMBDA, DEFAULT_SAMPLES};
use super::exif;
use super::merge::{merge, Exposure, MergeOptions, MergeReport};
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// Arguments of `lumiprobe merge`.
#[derive(clap::Args, Clone, Debug)]
pub struct MergeArgs {
    /// Bracket images (8-bit JPEG or PNG of the same static scene), in any order.
    #[arg(required = true, num_args = 1..)]
    pub brackets: Vec<PathBuf>,
    /// Output HDR file (.exr, .hdr or .pfm).
    #[arg(long)]
    pub out: PathBuf,
    /// Exposure times in seconds, one per bracket in the same order, comma
    /// separated (`1/60` or `0.0167`); overrides Exif.
    #[arg(long, value_delimiter = ',', value_parser = parse_time, allow_hyphen_values = true)]
    pub times: Option<Vec<f64>>,
    /// Camera response: `recover` (from the brackets), `documented` (the
    /// evaluation data's curve) or a JSON file saved with --save-response.
    #[arg(long, default_value = "recover")]
    pub response: String,
    /// Save the response used (e.g. the recovered one) as JSON.
    #[arg(long)]
    pub save_response: Option<PathBuf>,
    /// Smoothness weight of the response recovery.
    #[arg(long, default_value_t = DEFAULT_LAMBDA)]
    pub lambda: f64,
    /// Pixel locations sampled per channel by the response recovery.
    #[arg(long, default_value_t = DEFAULT_SAMPLES)]
    pub samples: usize,
}

/// Parses an exposure time: a decimal number or a fraction `a/b`.
pub fn parse_time(s: &str) -> std::result::Result<f64, String> {
    let t = s.trim();
    let v = match t.split_once('/') {
        Some((a, b)) => {
            let a: f64 = a.trim().parse().map_err(|e| format!("{s:?}: {e}"))?;
            let b: f64 = b.trim().parse().map_err(|e| format!("{s:?}: {e}"))?;
            a / b
        }
        None => t.parse().map_err(|e| format!("{s:?}: {e}"))?,
    };
    Ok(v)
}

/// Reads the brackets and their exposure times (from `times` or Exif).
pub fn load_exposures(paths: &[PathBuf], times: Option<&[f64]>) -> Result<Vec<Exposure>> {
    if let Some(t) = times {
        if t.len() != paths.len() {
            return Err(Error::Invalid(format!(
                "{} exposure times given for {} brackets (`--times` of merge, `times` of a manifest probe)",
                t.len(),
                paths.len()
            )));
        }
    }
    paths
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let bytes = crate::fsutil::read(p)?;
            let image =
                crate::image::io::decode_sdr(&bytes, p, &crate::image::io::Limits::default())?;
            let time_s = match times {
                Some(t) => t[k],
                None => exif::parse(&bytes, p)
                    .ok()
                    .and_then(|e| e.exposure_time_s)
                    .ok_or_else(|| {
                        Error::format(
                            p,
                            "no readable Exif ExposureTime: give the exposure times \
                             (`--times` of merge, `times` of a manifest probe)",
                        )
                    })?,
            };
            Ok(Exposure {
                name: p.clone(),
                image,
                time_s,
            })
        })
        .collect::<Result<Vec<_>>>()
        .and_then(|e| {
            if times.is_some() {
                check_time_order(&e)?;
            }
            Ok(e)
        })
}

/// Mean 8-bit code of an image.
fn mean_code(img: &crate::image::SdrImage) -> f64 {
    let d = img.data();
    d.iter().map(|&v| v as f64).sum::<f64>() / d.len().max(1) as f64
}

/// Given times must follow the files (sorted by name, as brackets are listed):
/// of two photos neither black nor white, the one given the longer time must
/// be the brighter. Refuses times that contradict the photos, naming the files
/// in order with their brightness.
fn check_time_order(exps: &[Exposure]) -> Result<()> {
    // Codes a well-exposed mean lies between, and the least brightness step and
    // time ratio that count as a contradiction (JPEG noise and a shift of the
    // view between brackets move the mean by less).
    const LOW: f64 = 8.0;
    const HIGH: f64 = 247.0;
    const MIN_STEP: f64 = 4.0;
    const MIN_RATIO: f64 = 1.5;
    let means: Vec<f64> = exps.iter().map(|e| mean_code(&e.image)).collect();
    for i in 0..exps.len() {
        for j in 0..exps.len() {
            let (a, b) = (&exps[i], &exps[j]);
            let usable = |m: f64| m > LOW && m < HIGH;
            if usable(means[i])
                && usable(means[j])
                && b.time_s > MIN_RATIO * a.time_s
                && means[i] > means[j] + MIN_STEP
            {
                let list: Vec<String> = exps
                    .iter()
                    .zip(&means)
                    .map(|(e, m)| {
                        format!(
                            "{} ({} s, mean code {m:.0})",
                            e.name.file_name().unwrap_or_default().to_string_lossy(),
                            e.time_s
                        )
                    })
                    .collect();
                return Err(Error::format(
                    &b.name,
                    format!(
                        "is given a longer exposure time than {} but is darker: the times \
                         must follow the files sorted by name: {}",
                        a.name.file_name().unwrap_or_default().to_string_lossy(),
                        list.join(", ")
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Runs `lumiprobe merge`: loads the brackets, obtains the response, merges,
/// writes the HDR file (and the curve when asked) and prints a short summary
/// unless `quiet` (warnings go to standard error either way).
pub fn run_merge(a: &MergeArgs, quiet: bool) -> Result<MergeReport> {
    let t0 = std::time::Instant::now();
    let exps = load_exposures(&a.brackets, a.times.as_deref())?;
    super::merge::check_exposures(&exps)?;
    let (curve, what) = match a.response.as_str() {
        "documented" => (
            ResponseCurve::documented(),
            "documented response".to_string(),
        ),
        "recover" => {
            let images: Vec<&crate::image::SdrImage> = exps.iter().map(|e| &e.image).collect();
            let times: Vec<f64> = exps.iter().map(|e| e.time_s).collect();
            let opts = RecoverOptions {
                lambda: a.lambda,
                samples: a.samples,
                ..Default::default()
            };
            let rec = recover(&images, &times, &opts)?;
            for w in &rec.warnings {
                eprintln!("warning: {w}");
            }
            let what = format!(
                "recovered response (lambda {}, {} samples/channel, RMS residual {:.3} ln)",
                a.lambda,
                rec.samples_used.iter().min().copied().unwrap_or(0),
                rec.rms_residual.iter().fold(0.0f64, |m, v| m.max(*v))
            );
            (rec.curve, what)
        }
        file => (
            ResponseCurve::load(Path::new(file))?,
            format!("response from {file}"),
        ),
    };
    if let Some(p) = &a.save_response {
        curve.save(p)?;
    }
    let merged = merge(&exps, &curve, &MergeOptions::default())?;
    crate::image::io::write_hdr(&a.out, &merged.image)?;
    if quiet {
        for w in &merged.report.warnings {
            eprintln!("warning: {w}");
        }
    } else {
        println!("{what}");
        print!("{}", merged.report.summary());
        println!(
            "wrote {} in {:.0} ms",
            a.out.display(),
            t0.elapsed().as_secs_f64() * 1e3
        );
    }
    Ok(merged.report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn times_parse_as_fractions_or_decimals() {
        assert_eq!(parse_time("1/60").unwrap(), 1.0 / 60.0);
        assert_eq!(parse_time(" 0.5 ").unwrap(), 0.5);
        assert!(parse_time("fast").is_err());
        assert!(parse_time("1/x").is_err());
    }

    #[test]
    fn args_parse() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            m: MergeArgs,
        }
        let c = Cli::try_parse_from([
            "x",
            "a.jpg",
            "b.jpg",
            "--out",
            "o.exr",
            "--times",
            "1/60,1/30",
            "--lambda",
            "5",
        ])
        .unwrap();
        assert_eq!(c.m.brackets.len(), 2);
        assert_eq!(c.m.times.unwrap(), vec![1.0 / 60.0, 1.0 / 30.0]);
        assert_eq!(c.m.response, "recover");
        assert_eq!(c.m.lambda, 5.0);
    }
}
