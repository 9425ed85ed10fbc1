//! `lumiprobe export`: a run's probes as engines load them.

use clap::{Args, ValueEnum};
use lumiprobe::ibl::ktx2::KtxFormat;
use lumiprobe::pipeline::export::{export, ExportFormat, ExportOptions, Orientation};
use lumiprobe::{Error, Result};
use std::path::PathBuf;

/// Arguments of `lumiprobe export`.
#[derive(Args)]
pub struct ExportArgs {
    /// Scene folder, poses.json or manifest (for the frames' poses).
    scene: PathBuf,
    /// A `lumiprobe run` output folder (frame_XXX.exr).
    #[arg(long)]
    probes: PathBuf,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    /// Frames to export, by index in walk order: `3`, `0-9`, `0,4,8-12`
    /// (default: every frame with a prediction).
    #[arg(long, value_parser = parse_frames)]
    frames: Option<FrameList>,
    /// Axes: `y` (world, +Y up: glTF, three.js), `z` (world, +Z up: Blender, the
    /// poses' axes) or `camera` (each frame's own).
    #[arg(long, value_enum, default_value_t = Up::Y)]
    up: Up,
    /// What to write, comma-separated.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [Format::Hdr, Format::Exr, Format::Ktx2, Format::Sh])]
    formats: Vec<Format>,
    #[command(flatten)]
    cube: super::CubeArgs,
    /// KTX2 texel format (default: half floats unless a texel exceeds 65504,
    /// then 32-bit floats).
    #[arg(long, value_enum)]
    ktx_format: Option<Ktx>,
}

#[derive(Clone, Copy, ValueEnum)]
enum Up {
    Y,
    Z,
    Camera,
}

#[derive(Clone, Copy, PartialEq, ValueEnum)]
enum Format {
    /// Equirect Radiance RGBE.
    Hdr,
    /// Equirect OpenEXR (32-bit float).
    Exr,
    /// Specular (GGX mips) and irradiance cubes in KTX 2.0.
    Ktx2,
    /// SH9 for three.js's LightProbe (JSON).
    Sh,
    /// The dominant lights as glTF KHR_lights_punctual directional lights,
    /// and the residual environment without them (.hdr and .exr).
    Lights,
}

#[derive(Clone, Copy, ValueEnum)]
enum Ktx {
    Rgba16f,
    Rgba32f,
}

/// Frame indices from `--frames` (one value to clap, not a list of values).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct FrameList(pub Vec<usize>);

/// `3`, `0-9` or `0,4,8-12` as indices (at most a million).
pub(crate) fn parse_frames(s: &str) -> std::result::Result<FrameList, String> {
    let mut out = Vec::new();
    for part in s.split(',') {
        let part = part.trim();
        let num = |t: &str| {
            t.trim()
                .parse::<usize>()
                .map_err(|_| format!("{t:?} is not a frame index (a whole number from 0)"))
        };
        let (a, b) = match part.split_once('-') {
            Some((a, b)) => (num(a)?, num(b)?),
            None => (num(part)?, num(part)?),
        };
        if b < a {
            return Err(format!("{part:?}: the range ends before it starts"));
        }
        if out.len() + (b - a + 1) > 1_000_000 {
            return Err(format!("{s:?} lists more than a million frames"));
        }
        out.extend(a..=b);
    }
    Ok(FrameList(out))
}

/// Runs the command; prints what was written unless `quiet`.
pub fn run(a: ExportArgs, quiet: bool) -> Result<()> {
    let scene = lumiprobe::pipeline::plan::load_scene(&a.scene, !quiet)?;
    let mut opts = ExportOptions {
        orientation: match a.up {
            Up::Y => Orientation::Y,
            Up::Z => Orientation::Z,
            Up::Camera => Orientation::Camera,
        },
        formats: a
            .formats
            .iter()
            .map(|f| match f {
                Format::Hdr => ExportFormat::Hdr,
                Format::Exr => ExportFormat::Exr,
                Format::Ktx2 => ExportFormat::Ktx2,
                Format::Sh => ExportFormat::Sh,
                Format::Lights => ExportFormat::Lights,
            })
            .collect(),
        frames: a.frames.map(|f| f.0),
        ktx_format: a.ktx_format.map(|k| match k {
            Ktx::Rgba16f => KtxFormat::Rgba16f,
            Ktx::Rgba32f => KtxFormat::Rgba32f,
        }),
        ..ExportOptions::default()
    };
    opts.specular.face_size = a.cube.face_size;
    opts.specular.mip_count = a.cube.mips;
    opts.specular.samples = a.cube.samples;
    if a.cube.samples == 0 || a.cube.samples > 1 << 16 {
        return Err(Error::Invalid(format!(
            "--samples {} must be 1 to 65536",
            a.cube.samples
        )));
    }
    let rep = export(&scene, &a.probes, &a.out, &opts)?;
    for w in &rep.warnings {
        eprintln!("{w}");
    }
    if !quiet {
        let files: usize = rep.frames.iter().map(|f| f.files.len()).sum();
        eprintln!(
            "{} frames, {files} files in {}{}",
            rep.frames.len(),
            a.out.display(),
            if rep.missing.is_empty() {
                String::new()
            } else {
                format!(" ({} frames have no prediction yet)", rep.missing.len())
            }
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::parse_frames;

    #[test]
    fn frame_lists_parse_and_bad_ones_say_why() {
        assert_eq!(parse_frames("3").unwrap().0, vec![3]);
        assert_eq!(parse_frames("0-2,7").unwrap().0, vec![0, 1, 2, 7]);
        assert!(parse_frames("5-2").unwrap_err().contains("ends before"));
        assert!(parse_frames("x").unwrap_err().contains("not a frame index"));
        assert!(parse_frames("0-99999999").unwrap_err().contains("million"));
    }
}
