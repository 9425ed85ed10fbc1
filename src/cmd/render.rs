//! `lumiprobe render`: glTF models rendered under a probe.

use super::args::*;
use lumiprobe::Result;
use std::path::PathBuf;

/// Arguments of `lumiprobe render`.
#[derive(clap::Args)]
pub struct RenderArgs {
    /// glTF 2.0 model (.glb or .gltf).
    pub model: PathBuf,
    /// HDR probe lighting it (equirect).
    #[arg(long)]
    pub probe: PathBuf,
    /// Output path; `<out>.exr` (linear) and `<out>.png` (tone-mapped) are written.
    #[arg(long)]
    pub out: PathBuf,
    /// Image size in pixels (square).
    #[arg(long, default_value_t = 512)]
    pub size: usize,
    /// Direction the camera looks along, x,y,z in the probe's axes (x right, y up,
    /// -z forward); the model is framed automatically.
    #[arg(long, value_parser = parse_vec3, default_value = "0,-0.35,-1", allow_hyphen_values = true)]
    pub view: [f32; 3],
    /// Vertical field of view in degrees.
    #[arg(long, value_parser = parse_finite, default_value_t = 35.0)]
    pub fov: f32,
    /// Transparent background instead of the probe.
    #[arg(long)]
    pub transparent: bool,
    /// Exposure of the PNG in EV (default: the probe's log-average luminance
    /// to middle grey, printed).
    #[arg(long, value_parser = parse_finite, allow_hyphen_values = true)]
    pub exposure: Option<f32>,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: RenderArgs, quiet: bool) -> Result<()> {
    let RenderArgs {
        model,
        probe,
        out,
        size,
        view,
        fov,
        transparent,
        exposure,
    } = a;
    use lumiprobe::render::{render, write_render, Background, Camera, Model, RenderOptions};
    let m = Model::load(&model)?;
    let env_img = read_input(&probe)?;
    let env = lumiprobe::ibl::export::Prefiltered::from_env(
        &env_img,
        &lumiprobe::ibl::export::PrefilterOptions::default(),
    )?;
    let cam = Camera::framing(&m.bounds(), glam::Vec3::from(view), fov, size, size);
    let opts = RenderOptions {
        background: if transparent {
            Background::Transparent
        } else {
            Background::Environment
        },
        ..Default::default()
    };
    let exposure = match exposure {
        Some(ev) => ev,
        None => {
            let ev = lumiprobe::tonemap::auto_exposure_ev(&env_img);
            if !quiet {
                eprintln!(
                    "exposure {ev:+.2} EV (auto: the probe's log-average luminance to 0.18; --exposure fixes it)"
                );
            }
            ev
        }
    };
    let r = render(&m, &env, &cam, &opts)?;
    let (a, b) = write_render(&out, &r, exposure)?;
    if !quiet {
        eprintln!("wrote {} and {}", a.display(), b.display());
    }
    Ok(())
}
