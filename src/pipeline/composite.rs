//! The thesis's viewer as files: a glTF model placed at a fixed point of the
//! world, lit at every frame by that frame's probe, seen from that frame's camera
//! and composited over the SDR frame, with a soft contact shadow.
//!
//! The view is a perspective camera at the frame's position looking at the model
//! (cut from the panorama, so the model stays in view along the walk). The
//! background is the linearised SDR frame along each pixel's ray; the composite
//! is re-encoded with the frame camera's own response and exposure, so the
//! background keeps the frame's look and the model looks as that camera would
//! have recorded it.

use super::{linearize, load_frame, prediction_path};
use crate::error::{Error, Result};
use crate::ibl::export::{PrefilterOptions, Prefiltered};
use crate::image::io::{self, ldr::linear_to_sdr};
use crate::image::HdrImage;
use crate::render::{render, Background, Camera, Model, RenderOptions};
use crate::scene::Scene;
use glam::{Mat3, Vec3};
use std::path::{Path, PathBuf};

/// Settings of a composite.
#[derive(Clone, Debug)]
pub struct CompositeOptions {
    /// Where the model stands: world position (metres, z up) of the centre of its
    /// base.
    pub at: Vec3,
    /// Radius of the model's bounding sphere in metres after scaling.
    pub radius: f32,
    /// Yaw of the model about the world's up axis, degrees.
    pub yaw_deg: f32,
    /// Output image size.
    pub width: usize,
    /// Output image height.
    pub height: usize,
    /// Vertical field of view of the view, degrees.
    pub vfov_deg: f32,
    /// Darkening at the centre of the contact shadow, `[0, 1]`.
    pub shadow: f32,
    /// Prefiltering of each frame's probe.
    pub prefilter: PrefilterOptions,
}

impl Default for CompositeOptions {
    /// 640x360, 60° field of view, a 25 cm model, a shadow of 0.6.
    fn default() -> Self {
        let mut prefilter = PrefilterOptions::default();
        prefilter.specular.face_size = 64;
        prefilter.specular.samples = 128;
        CompositeOptions {
            at: Vec3::ZERO,
            radius: 0.25,
            yaw_deg: 0.0,
            width: 640,
            height: 360,
            vfov_deg: 60.0,
            shadow: 0.6,
            prefilter,
        }
    }
}

/// What [`composite`] wrote.
#[derive(Clone, Debug)]
pub struct CompositeReport {
    /// One PNG per frame.
    pub frames: Vec<PathBuf>,
    /// The MP4, when ffmpeg was available.
    pub video: Option<PathBuf>,
    /// Frames skipped because the model was behind the camera or too close.
    pub skipped: Vec<String>,
    /// Probes whose NaN, infinite or negative samples were repaired.
    pub warnings: Vec<String>,
}

/// glTF's y-up, +z-front axes to the world's z-up axes: `(x, y, z) -> (x, -z, y)`.
fn gltf_to_world() -> Mat3 {
    Mat3::from_cols(Vec3::X, Vec3::Z, -Vec3::Y)
}

/// Moves `model` rigidly by `m` (a rotation times a uniform scale) and `t`.
fn transform(model: &mut Model, m: Mat3, t: Vec3) {
    let rot = m * (1.0 / m.x_axis.length().max(1e-12));
    for mesh in &mut model.meshes {
        for p in &mut mesh.positions {
            *p = m * *p + t;
        }
        for n in &mut mesh.normals {
            *n = (rot * *n).normalize_or_zero();
        }
        for tg in &mut mesh.tangents {
            let v = (rot * tg.truncate()).normalize_or_zero();
            *tg = v.extend(tg.w);
        }
    }
}

/// Places a model (in glTF axes) at `opts.at` in world axes, then expresses it in
/// the camera axes of a frame at `cam_pos` with `world_from_camera`.
fn placed_in_frame(
    model: &Model,
    opts: &CompositeOptions,
    cam_pos: Vec3,
    world_from_camera: Mat3,
) -> Model {
    let b = model.bounds();
    let (c, r) = if b.is_empty() {
        (Vec3::ZERO, 1.0)
    } else {
        (b.center(), b.radius().max(1e-6))
    };
    let s = opts.radius / r;
    let base = Vec3::new(c.x, b.min.y, c.z); // glTF: bottom centre
    let yaw = Mat3::from_rotation_z(opts.yaw_deg.to_radians());
    let to_world = yaw * gltf_to_world() * s;
    let cam_from_world = world_from_camera.transpose();
    let m = cam_from_world * to_world;
    let t = cam_from_world * (opts.at - to_world * base - cam_pos);
    let mut out = model.clone();
    transform(&mut out, m, t);
    out
}

/// Renders the composite of one frame given its probe (camera axes).
pub fn composite_frame(
    model: &Model,
    probe: &HdrImage,
    background: &HdrImage,
    world_from_camera: Mat3,
    cam_pos: Vec3,
    opts: &CompositeOptions,
) -> Result<Option<HdrImage>> {
    let m = placed_in_frame(model, opts, cam_pos, world_from_camera);
    let target = world_from_camera.transpose() * (opts.at - cam_pos)
        + world_from_camera.transpose() * Vec3::Z * opts.radius;
    if target.length() < 2.0 * opts.radius {
        return Ok(None);
    }
    let up = world_from_camera.transpose() * Vec3::Z;
    let cam = Camera {
        eye: Vec3::ZERO,
        target,
        up,
        vfov_deg: opts.vfov_deg,
        width: opts.width,
        height: opts.height,
    };
    let mut probe = probe.clone();
    probe.repair_invalid();
    let env = Prefiltered::from_env(&probe, &opts.prefilter)?;
    let r = render(
        &m,
        &env,
        &cam,
        &RenderOptions {
            background: Background::Transparent,
            supersample: 2,
            lights: Vec::new(),
        },
    )?;
    // Contact shadow: rays that hit the ground plane under the model near its
    // footprint are darkened by a Gaussian of the footprint's radius.
    let ground_z = opts.at.z;
    let world_from_cam = world_from_camera;
    let mut out = HdrImage::new(opts.width, opts.height);
    for y in 0..opts.height {
        for x in 0..opts.width {
            let d = cam.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
            let mut bg = crate::sphere::sample_dir(background, d);
            let dw = world_from_cam * d;
            if dw.z < -1e-4 {
                let t = (ground_z - cam_pos.z) / dw.z;
                let hit = cam_pos + dw * t;
                let rr = (hit - opts.at).truncate().length() / (0.8 * opts.radius);
                let f = 1.0 - opts.shadow * (-rr * rr).exp();
                bg = bg.map(|v| v * f);
            }
            let i = y * opts.width + x;
            let a = r.alpha[i];
            let c = r.color.get(x, y);
            out.set(
                x,
                y,
                [
                    c[0] + (1.0 - a) * bg[0],
                    c[1] + (1.0 - a) * bg[1],
                    c[2] + (1.0 - a) * bg[2],
                ],
            );
        }
    }
    Ok(Some(out))
}

/// Composites `model` over every frame of `scene` lit by the probes in `pred_dir`
/// (a `lumiprobe run` output), writing `out_dir/<frame id>.png` and, when ffmpeg
/// is on the PATH, `out_dir/composite.mp4` (at `fps`). Existing PNGs are kept
/// (a rerun resumes).
pub fn composite(
    scene: &Scene,
    pred_dir: &Path,
    model_path: &Path,
    out_dir: &Path,
    opts: &CompositeOptions,
    fps: u32,
) -> Result<CompositeReport> {
    let model = Model::load(model_path)?;
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    let mut report = CompositeReport {
        frames: Vec::new(),
        video: None,
        skipped: Vec::new(),
        warnings: Vec::new(),
    };
    for frame in &scene.frames {
        let png = out_dir.join(format!("{}.png", frame.id));
        if png.exists() {
            report.frames.push(png);
            continue;
        }
        let probe_path = prediction_path(pred_dir, frame);
        if !probe_path.exists() {
            return Err(Error::Invalid(format!(
                "{}: no probe for frame {} (run `lumiprobe run` first)",
                probe_path.display(),
                frame.id
            )));
        }
        let (probe, warning) = io::read_hdr_repaired(&probe_path)?;
        report.warnings.extend(warning);
        let sdr = load_frame(frame, None)?;
        let lin = linearize(&sdr, scene, frame);
        match composite_frame(
            &model,
            &probe,
            &lin,
            frame.pose.world_from_camera,
            frame.pose.position,
            opts,
        )? {
            Some(img) => {
                let enc = linear_to_sdr(&img, &scene.response, scene.frame_luminance_gain(frame));
                io::write_sdr(&png, &enc)?;
                report.frames.push(png);
            }
            None => report.skipped.push(frame.id.clone()),
        }
    }
    if !report.frames.is_empty() && crate::fsutil::have_program("ffmpeg") {
        let list = out_dir.join("frames.txt");
        let mut text = String::new();
        // ffmpeg's concat list resolves names against the list's own folder,
        // where the pictures are: their bare names, quoted.
        for f in &report.frames {
            let name = f
                .file_name()
                .map(|n| n.to_string_lossy().replace('\'', "'\\''"))
                .unwrap_or_default();
            text += &format!("file '{name}'\nduration {}\n", 1.0 / fps.max(1) as f64);
        }
        crate::fsutil::write_atomic(&list, text.as_bytes())?;
        let mp4 = out_dir.join("composite.mp4");
        let tmp = out_dir.join("composite.tmp.mp4");
        let st = std::process::Command::new("ffmpeg")
            .args([
                "-y",
                "-loglevel",
                "error",
                "-f",
                "concat",
                "-safe",
                "0",
                "-i",
            ])
            .arg(&list)
            .args([
                "-pix_fmt",
                "yuv420p",
                "-vf",
                "pad=ceil(iw/2)*2:ceil(ih/2)*2",
            ])
            .arg(&tmp)
            .status()
            .map_err(|e| Error::io(&tmp, e))?;
        let _ = std::fs::remove_file(&list);
        if st.success() {
            std::fs::rename(&tmp, &mp4).map_err(|e| Error::io(&mp4, e))?;
            report.video = Some(mp4);
        } else {
            let _ = std::fs::remove_file(&tmp);
            return Err(Error::External {
                tool: "ffmpeg",
                msg: format!("failed to encode {} ({st})", mp4.display()),
            });
        }
    }
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::Material;

    #[test]
    fn gltf_up_becomes_world_up_and_the_frame_is_right_handed() {
        let m = gltf_to_world();
        assert!((m * Vec3::Y - Vec3::Z).length() < 1e-6);
        assert!((m.determinant() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn a_lit_sphere_appears_where_it_stands_with_a_shadow_under_it() {
        let model = Model::uv_sphere(1.0, 24, Material::basic([0.8, 0.8, 0.8], 0.0, 1.0));
        let (w, h) = (64, 32);
        let probe = HdrImage::from_fn(w, h, |_, _| [1.0, 1.0, 1.0]);
        let bg = HdrImage::from_fn(w, h, |_, _| [0.5, 0.5, 0.5]);
        let opts = CompositeOptions {
            at: Vec3::new(2.0, 0.0, 0.0),
            width: 96,
            height: 64,
            ..Default::default()
        };
        // Camera 1.5 m above the ground, axes: camera -z (forward) = world +x.
        let wfc = Mat3::from_cols(-Vec3::Y, Vec3::Z, -Vec3::X);
        let img = composite_frame(&model, &probe, &bg, wfc, Vec3::new(0.0, 0.0, 1.5), &opts)
            .unwrap()
            .unwrap();
        // Centre: the sphere, lit by a white environment: albedo 0.8 -> about 0.8.
        let c = img.get(48, 32);
        assert!((c[0] - 0.8).abs() < 0.1, "{c:?}");
        // Far corner: untouched background.
        assert!((img.get(1, 1)[0] - 0.5).abs() < 1e-4);
        // Just below the sphere on the ground: in its shadow.
        let below = (40..64)
            .map(|y| img.get(48, y)[0])
            .fold(f32::INFINITY, f32::min);
        assert!(below < 0.45, "no shadow: {below}");
    }
}
