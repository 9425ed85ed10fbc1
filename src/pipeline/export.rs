//! `lumiprobe export`: a run's probes in the files engines load.
//!
//! For each chosen frame of a `lumiprobe run` output, in world axes (gravity
//! up) or in the frame's camera axes:
//!
//! | file | content |
//! |------|---------|
//! | `<id>.hdr`, `<id>.exr` | the equirect probe (Radiance RGBE; OpenEXR float) |
//! | `<id>_specular.ktx2` | GGX-prefiltered cube, one mip per roughness `level / (levels - 1)` |
//! | `<id>_irradiance.ktx2` | irradiance cube `E` (a Lambertian surface's radiance is `albedo E / pi`) |
//! | `<id>_sh.json` | nine RGB SH coefficients of the radiance as three.js's `LightProbe.fromJSON` reads them |
//! | `<id>_lights.gltf` | the dominant lights ([`crate::ibl::lights`]) as glTF `KHR_lights_punctual` directional lights (glTF's `+y`-up axes whatever `--up`) |
//! | `<id>_residual.hdr`, `<id>_residual.exr` | the probe with those lights' light taken out: lights plus residual hold the probe's light, channel by channel |
//! | `export.json` | what was written, in which axes and conventions; written last |
//!
//! Axes: with `y` up (glTF, three.js, Unity, Unreal after its own swap) the
//! target is right-handed with `+y` against gravity and `-z` along the poses'
//! `+y` (world `x` stays `x`); with `z` up (Blender, the poses' own axes) the
//! target is the world of `poses.json`. Equirect files always have the up axis at
//! their top row, and the same pixels either way: column `u`, row `v` look along
//! `(sin(phi) cos(lat), sin(lat), -cos(phi) cos(lat))` in the `y`-up target,
//! `phi = 2 pi (u - 1/2)`, `lat = pi (1/2 - v)`. Cube faces follow KTX 2.0's
//! OpenGL/Vulkan convention ([`crate::ibl::ktx2::gl_face_dir`]) in the target's
//! axes.

use crate::error::{Error, Result};
use crate::ibl::ktx2::{encode_cube, gl_cube, peak, KtxFormat, HALF_MAX};
use crate::ibl::lights::{
    integral, lights_gltf, split_lights, spot_falloff, LightOptions, Placement, ProbeLight,
};
use crate::ibl::prefilter::{cube_texel_solid_angle, mip_roughness, prefilter_specular};
use crate::ibl::{Sh9, SpecularOptions};
use crate::image::io::{read_hdr_repaired, ExrWriteOptions};
use crate::image::{luminance, HdrImage};
use crate::scene::{Pose, Scene};
use crate::sphere::{rotate, row_solid_angles};
use glam::{Mat3, Vec3};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Axes the exported probes are written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Orientation {
    /// World axes, `+y` up (glTF, three.js).
    Y,
    /// World axes of `poses.json`, `+z` up (Blender).
    Z,
    /// Each frame's own camera axes (x right, y up, -z forward).
    Camera,
}

/// One kind of exported file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ExportFormat {
    /// Equirect Radiance RGBE (`.hdr`).
    Hdr,
    /// Equirect OpenEXR, 32-bit float (`.exr`).
    Exr,
    /// Prefiltered specular and irradiance cubes in KTX 2.0.
    Ktx2,
    /// SH9 of the radiance for three.js's `LightProbe`.
    Sh,
    /// The dominant lights as glTF `KHR_lights_punctual`, and the residual
    /// environment without them.
    Lights,
}

/// Everything that controls [`export`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExportOptions {
    /// Axes of the outputs.
    pub orientation: Orientation,
    /// What to write.
    pub formats: Vec<ExportFormat>,
    /// Indices into the scene's frames (walk order); `None`: every frame with a
    /// prediction.
    pub frames: Option<Vec<usize>>,
    /// Specular cube: face size of mip 0, mip count, GGX samples per texel.
    pub specular: SpecularOptions,
    /// Face size of the irradiance cube.
    pub irradiance_face_size: usize,
    /// Texel format of the KTX 2.0 files; `None`: half floats unless a texel
    /// exceeds what they hold (a sun), then single floats.
    pub ktx_format: Option<KtxFormat>,
    /// What counts as a light for [`ExportFormat::Lights`].
    #[serde(default)]
    pub lights: LightOptions,
    /// Largest width of the exported equirects: wider predictions are box
    /// filtered down, their power kept ([`crate::sphere::downsample_box`]);
    /// `None`: their own size.
    #[serde(default)]
    pub max_width: Option<usize>,
}

impl Default for ExportOptions {
    fn default() -> Self {
        ExportOptions {
            orientation: Orientation::Y,
            formats: vec![
                ExportFormat::Hdr,
                ExportFormat::Exr,
                ExportFormat::Ktx2,
                ExportFormat::Sh,
            ],
            frames: None,
            specular: SpecularOptions::default(),
            irradiance_face_size: 32,
            ktx_format: None,
            lights: LightOptions::default(),
            max_width: None,
        }
    }
}

/// What was exported of one frame.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FrameExport {
    /// Frame id.
    pub id: String,
    /// Files written (names inside the output folder).
    pub files: Vec<String>,
    /// Texel format of its KTX 2.0 files, when written.
    pub ktx_format: Option<KtxFormat>,
    /// Luminance power (integral over the sphere) of the probe and of the
    /// specular cube's mip 0: the check that the cube holds the probe's light.
    pub power: Option<[f64; 2]>,
    /// The lights taken out, when written.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lights: Option<LightsExport>,
}

/// One exported light.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ExportedLight {
    /// What was taken out of the probe.
    #[serde(flatten)]
    pub light: ProbeLight,
    /// Where it is.
    pub placement: Placement,
}

/// The lights of one frame and the check that they keep its light.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LightsExport {
    /// Each light: direction (the equirect files' axes), light per channel,
    /// solid angle, and where it is (a point light where the run's report
    /// places a light at a distance in its direction).
    pub lights: Vec<ExportedLight>,
    /// Per channel, the probe's integral over the sphere.
    pub probe: [f64; 3],
    /// Per channel, the lights' sum plus the residual's integral: equal to
    /// `probe` up to rounding.
    pub kept: [f64; 3],
}

/// What [`export`] did; also written as `export.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ExportReport {
    /// Axes of every file.
    pub orientation: Orientation,
    /// Roughness of each specular mip (GGX `alpha = roughness^2`).
    pub roughness: Vec<f32>,
    /// One entry per exported frame, in walk order.
    pub frames: Vec<FrameExport>,
    /// Frames with no prediction in the run's folder (only when exporting all).
    pub missing: Vec<String>,
    /// Predictions whose NaN, infinite or negative samples were repaired.
    #[serde(default)]
    pub warnings: Vec<String>,
}

/// Name of the report written last into the output folder.
pub const EXPORT_FILE: &str = "export.json";

/// World (z up) from the `y`-up target: target `x` is world `x`, target `y` is
/// world `z`, target `z` is world `-y`.
fn world_from_y_up() -> Mat3 {
    Mat3::from_cols(Vec3::X, Vec3::Z, -Vec3::Y)
}

/// Rotation taking directions of the equirect files' axes to the frame's camera
/// axes (what [`rotate`] takes to resample the prediction).
pub fn camera_from_image(pose: &Pose, o: Orientation) -> Mat3 {
    match o {
        Orientation::Camera => Mat3::IDENTITY,
        Orientation::Y | Orientation::Z => pose.world_from_camera.transpose() * world_from_y_up(),
    }
}

/// Rotation taking directions of the target axes (cubes, SH) to the equirect
/// files' axes.
pub fn image_from_target(o: Orientation) -> Mat3 {
    match o {
        Orientation::Camera | Orientation::Y => Mat3::IDENTITY,
        Orientation::Z => world_from_y_up().transpose(),
    }
}

/// Luminance power of an equirect panorama.
fn equirect_power(img: &HdrImage) -> f64 {
    let (w, sa) = (img.width(), row_solid_angles(img.width(), img.height()));
    img.data()
        .chunks_exact(3)
        .enumerate()
        .map(|(i, c)| luminance([c[0], c[1], c[2]]) as f64 * sa[i / w] as f64)
        .sum()
}

/// Luminance power of a cube's faces.
fn cube_power(faces: &[HdrImage; 6]) -> f64 {
    let n = faces[0].width();
    let mut s = 0.0;
    for f in faces {
        for y in 0..n {
            for x in 0..n {
                s += luminance(f.get(x, y)) as f64 * cube_texel_solid_angle(x, y, n);
            }
        }
    }
    s
}

/// A light a fusion run placed at a distance, as its frame sees it (camera
/// axes).
#[derive(Clone, Copy, Debug)]
struct PlacedAt {
    /// Direction from the frame (unit).
    dir: Vec3,
    /// Distance from the frame, in the poses' unit.
    distance: f32,
    /// The normal of the plane it lies on, on the frame's side (a flat
    /// emitter), when the probes agreed on one.
    facing: Option<Vec3>,
}

/// The lights a fusion run placed at a distance for the frame whose prediction
/// is `pred` (`w` x `h`): direction in the frame's camera axes and distance,
/// from the run's report beside it (`<id>.json`, `fusion.lights`). None when
/// there is no report or the method placed none.
fn placed_lights(pred: &Path, w: usize, h: usize) -> Result<Vec<PlacedAt>> {
    let report = pred.with_extension("json");
    if !report.is_file() {
        return Ok(Vec::new());
    }
    let text = crate::fsutil::read(&report)?;
    let v: serde_json::Value = serde_json::from_slice(&text)
        .map_err(|e| Error::format(&report, format!("not a run's frame report: {e}")))?;
    let mut out = Vec::new();
    for l in v["fusion"]["lights"].as_array().into_iter().flatten() {
        let (Some(x), Some(y), Some(d)) = (
            l["at_px"][0].as_f64(),
            l["at_px"][1].as_f64(),
            l["distance"].as_f64(),
        ) else {
            continue;
        };
        if l["region"].is_null() || !(d.is_finite() && d > 0.0) || w == 0 || h == 0 {
            continue;
        }
        let dir = crate::sphere::uv_to_dir(x as f32 / w as f32, y as f32 / h as f32);
        let facing = l["facing"].as_array().and_then(|v| {
            let c: Vec<f32> = v
                .iter()
                .filter_map(|c| c.as_f64())
                .map(|c| c as f32)
                .collect();
            let n = (c.len() == 3).then(|| Vec3::new(c[0], c[1], c[2]).normalize_or_zero())?;
            (n != Vec3::ZERO && n.is_finite()).then_some(n)
        });
        out.push(PlacedAt {
            dir,
            distance: d as f32,
            facing,
        });
    }
    Ok(out)
}

/// Each light with where it is: a point light where a light the run placed at
/// a distance (`placed`, camera axes) looks the same way from the frame
/// (within the light's angular radius plus 3 degrees), else directional.
/// Positions are in glTF's axes: the world's, `+y` up (the frame's camera
/// axes for `Orientation::Camera`), in the poses' unit.
fn place(
    lights: Vec<ProbeLight>,
    placed: &[PlacedAt],
    pose: &Pose,
    o: Orientation,
) -> Vec<(ProbeLight, Placement)> {
    // The equirect files' axes are +y up for every orientation: glTF's own.
    let cam_from_img = camera_from_image(pose, o);
    let origin = match o {
        Orientation::Camera => Vec3::ZERO,
        Orientation::Y | Orientation::Z => {
            let p = pose.position;
            Vec3::new(p.x, p.z, -p.y)
        }
    };
    lights
        .into_iter()
        .map(|l| {
            let d = Vec3::from_array(l.dir);
            let reach = (crate::sphere::disc_radius(l.solid_angle_sr) as f32) + 3f32.to_radians();
            let img_from_cam = cam_from_img.transpose();
            let near = placed
                .iter()
                .map(|p| (img_from_cam * p.dir, p))
                .filter(|(c, _)| c.angle_between(d) <= reach)
                .min_by(|a, b| a.0.angle_between(d).total_cmp(&b.0.angle_between(d)));
            let place = match near {
                Some((c, p)) => {
                    let (c, dist) = (c.normalize(), p.distance);
                    let position = (origin + c * dist).to_array();
                    match p.facing.map(|n| (img_from_cam * n).normalize_or_zero()) {
                        Some(facing) if facing != Vec3::ZERO => Placement::Spot {
                            position,
                            distance: dist,
                            facing: facing.to_array(),
                            falloff: spot_falloff(facing, -c),
                        },
                        _ => Placement::Point {
                            position,
                            distance: dist,
                        },
                    }
                }
                None => Placement::Directional,
            };
            (l, place)
        })
        .collect()
}

/// The frames to export (index and prediction path) and the ids of frames with
/// no prediction yet.
type Chosen = (Vec<(usize, PathBuf)>, Vec<String>);

/// The frames to export (see [`Chosen`]).
fn chosen(scene: &Scene, pred_dir: &Path, opts: &ExportOptions) -> Result<Chosen> {
    let path = |i: usize| pred_dir.join(format!("{}.exr", scene.frames[i].id));
    match &opts.frames {
        Some(list) => {
            let mut out = Vec::new();
            for &i in list {
                if i >= scene.frames.len() {
                    return Err(Error::Invalid(format!(
                        "frame {i} is not in the scene, which has {} frames (0 to {})",
                        scene.frames.len(),
                        scene.frames.len().saturating_sub(1)
                    )));
                }
                let p = path(i);
                if !p.is_file() {
                    return Err(Error::Invalid(format!(
                        "{}: no prediction for frame {} (run `lumiprobe run` first)",
                        p.display(),
                        scene.frames[i].id
                    )));
                }
                out.push((i, p));
            }
            Ok((out, Vec::new()))
        }
        None => {
            let (mut out, mut missing) = (Vec::new(), Vec::new());
            for i in 0..scene.frames.len() {
                let p = path(i);
                if p.is_file() {
                    out.push((i, p));
                } else {
                    missing.push(scene.frames[i].id.clone());
                }
            }
            if out.is_empty() {
                return Err(Error::Invalid(format!(
                    "{}: no predictions of this scene's frames (frame_XXX.exr from `lumiprobe run`)",
                    pred_dir.display()
                )));
            }
            Ok((out, missing))
        }
    }
}

/// Exports the predictions in `pred_dir` (a `lumiprobe run` output) of `scene`'s
/// frames into `out_dir` (see the module docs), each file written atomically and
/// `export.json` last.
pub fn export(
    scene: &Scene,
    pred_dir: &Path,
    out_dir: &Path,
    opts: &ExportOptions,
) -> Result<ExportReport> {
    if opts.formats.is_empty() {
        return Err(Error::Invalid("nothing to export: no format chosen".into()));
    }
    let s = &opts.specular;
    if s.face_size == 0 || s.face_size > 4096 || s.mip_count == 0 || s.mip_count > 16 {
        return Err(Error::Invalid(format!(
            "specular cube of {} texels and {} mips: faces must be 1 to 4096 texels, 1 to 16 mips",
            s.face_size, s.mip_count
        )));
    }
    if s.mip_count > 1 + (usize::BITS - s.face_size.leading_zeros()) as usize {
        return Err(Error::Invalid(format!(
            "{} mips do not fit a {}-texel face (at most {})",
            s.mip_count,
            s.face_size,
            1 + (usize::BITS - s.face_size.leading_zeros())
        )));
    }
    if opts.irradiance_face_size == 0 || opts.irradiance_face_size > 1024 {
        return Err(Error::Invalid(
            "irradiance faces must be 1 to 1024 texels".into(),
        ));
    }
    let (frames, missing) = chosen(scene, pred_dir, opts)?;
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    let mut report = ExportReport {
        orientation: opts.orientation,
        roughness: (0..s.mip_count)
            .map(|i| mip_roughness(i, s.mip_count))
            .collect(),
        frames: Vec::new(),
        missing,
        warnings: Vec::new(),
    };
    let to_image = image_from_target(opts.orientation);
    for (i, path) in frames {
        let frame = &scene.frames[i];
        let (pred, warning) = read_hdr_repaired(&path)?;
        report.warnings.extend(warning);
        let (w, h) = (pred.width(), pred.height());
        let mut img = rotate(
            &pred,
            camera_from_image(&frame.pose, opts.orientation),
            w,
            h,
        );
        if let Some(max_w) = opts.max_width {
            match crate::sphere::downsample_box(&img, max_w) {
                Some(small) => img = small,
                None => report.warnings.push(format!(
                    "{}: {w}x{h} has no block size that brings it to {max_w} wide; exported at its own size",
                    path.display()
                )),
            }
        }
        let mut fe = FrameExport {
            id: frame.id.clone(),
            files: Vec::new(),
            ktx_format: None,
            power: None,
            lights: None,
        };
        for f in &opts.formats {
            match f {
                ExportFormat::Hdr => {
                    let name = format!("{}.hdr", frame.id);
                    crate::image::io::rgbe::write(&out_dir.join(&name), &img)?;
                    fe.files.push(name);
                }
                ExportFormat::Exr => {
                    let name = format!("{}.exr", frame.id);
                    crate::image::io::exr::write(
                        &out_dir.join(&name),
                        &img,
                        &ExrWriteOptions::default(),
                    )?;
                    fe.files.push(name);
                }
                ExportFormat::Sh => {
                    let name = format!("{}_sh.json", frame.id);
                    let sh = Sh9::project(&img).rotate(to_image);
                    let coeffs: Vec<f32> = sh.coeffs.iter().flatten().copied().collect();
                    let json = serde_json::json!({
                        "type": "LightProbe",
                        "intensity": 1.0,
                        "sh": coeffs,
                    });
                    crate::fsutil::write_atomic(&out_dir.join(&name), json.to_string().as_bytes())?;
                    fe.files.push(name);
                }
                ExportFormat::Lights => {
                    let (lights, residual) = split_lights(&img, &opts.lights);
                    let placed = placed_lights(&path, w, h)?;
                    let lights = place(lights, &placed, &frame.pose, opts.orientation);
                    // The equirect files' axes are +y up whatever the target:
                    // glTF's own.
                    let gltf = lights_gltf(&lights, Mat3::IDENTITY);
                    let name = format!("{}_lights.gltf", frame.id);
                    let text = crate::error::to_json(&gltf)?;
                    crate::fsutil::write_atomic(&out_dir.join(&name), text.as_bytes())?;
                    fe.files.push(name);
                    let name = format!("{}_residual.hdr", frame.id);
                    crate::image::io::rgbe::write(&out_dir.join(&name), &residual)?;
                    fe.files.push(name);
                    let name = format!("{}_residual.exr", frame.id);
                    crate::image::io::exr::write(
                        &out_dir.join(&name),
                        &residual,
                        &ExrWriteOptions::default(),
                    )?;
                    fe.files.push(name);
                    let mut kept = integral(&residual);
                    for (l, _) in &lights {
                        for k in 0..3 {
                            kept[k] += l.rgb[k];
                        }
                    }
                    fe.lights = Some(LightsExport {
                        lights: lights
                            .into_iter()
                            .map(|(light, placement)| ExportedLight { light, placement })
                            .collect(),
                        probe: integral(&img),
                        kept,
                    });
                }
                ExportFormat::Ktx2 => {
                    let cube = prefilter_specular(&img, s);
                    let levels: Vec<[HdrImage; 6]> = cube
                        .mips
                        .iter()
                        .map(|m| gl_cube(m.size, |d| m.sample(to_image * d)))
                        .collect();
                    let sh = Sh9::project(&img);
                    let irr = [gl_cube(opts.irradiance_face_size, |d| {
                        sh.irradiance_clamped(to_image * d)
                    })];
                    let format = opts.ktx_format.unwrap_or(if peak(&levels) > HALF_MAX {
                        KtxFormat::Rgba32f
                    } else {
                        KtxFormat::Rgba16f
                    });
                    let rough: Vec<String> =
                        report.roughness.iter().map(|r| r.to_string()).collect();
                    let up = match opts.orientation {
                        Orientation::Y => "+y",
                        Orientation::Z => "+z",
                        Orientation::Camera => "camera",
                    };
                    let spec_kv = [
                        ("lumiprobe.roughness", rough.join(" ")),
                        ("lumiprobe.up", up.to_string()),
                    ];
                    let spec_kv: Vec<(&str, &str)> =
                        spec_kv.iter().map(|(k, v)| (*k, v.as_str())).collect();
                    let name = format!("{}_specular.ktx2", frame.id);
                    let bytes = encode_cube(&levels, format, &spec_kv).map_err(|e| {
                        Error::Invalid(format!("{}: {e}", out_dir.join(&name).display()))
                    })?;
                    crate::fsutil::write_atomic(&out_dir.join(&name), &bytes)?;
                    fe.files.push(name);
                    let name = format!("{}_irradiance.ktx2", frame.id);
                    let irr_format = if peak(&irr) > HALF_MAX {
                        KtxFormat::Rgba32f
                    } else {
                        format
                    };
                    let bytes =
                        encode_cube(&irr, irr_format, &[("lumiprobe.up", up)]).map_err(|e| {
                            Error::Invalid(format!("{}: {e}", out_dir.join(&name).display()))
                        })?;
                    crate::fsutil::write_atomic(&out_dir.join(&name), &bytes)?;
                    fe.files.push(name);
                    fe.ktx_format = Some(format);
                    fe.power = Some([equirect_power(&img), cube_power(&levels[0])]);
                }
            }
        }
        report.frames.push(fe);
    }
    let json = crate::error::to_json(&report)?.into_bytes();
    crate::fsutil::write_atomic(&out_dir.join(EXPORT_FILE), &json)?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ibl::ktx2::gl_face_dir;
    use crate::sphere::pixel_to_dir;

    /// A pose turned `yaw` about world z and tilted a little, as a hand-held
    /// camera is.
    fn pose(yaw: f32) -> Pose {
        let upright = Mat3::from_cols(Vec3::X, Vec3::Z, -Vec3::Y);
        Pose {
            position: Vec3::ZERO,
            world_from_camera: Mat3::from_rotation_z(yaw) * upright * Mat3::from_rotation_x(0.1),
        }
    }

    #[test]
    fn a_light_at_a_world_direction_lands_there_in_every_orientation() {
        // A dim panorama with one bright pixel; its direction in the world.
        let (w, h) = (64, 32);
        let p = pose(0.7);
        let (lx, ly) = (40, 9);
        let mut img = HdrImage::from_fn(w, h, |_, _| [0.1, 0.1, 0.1]);
        img.set(lx, ly, [500.0, 400.0, 300.0]);
        let world = p.world_from_camera * pixel_to_dir(lx, ly, w, h);
        let targets = [
            (Orientation::Y, world_from_y_up().transpose() * world),
            (Orientation::Z, world),
            (Orientation::Camera, pixel_to_dir(lx, ly, w, h)),
        ];
        for (o, want) in targets {
            let out = rotate(&img, camera_from_image(&p, o), w, h);
            // The equirect's brightest pixel looks along the light in y-up
            // image axes.
            let (mut best, mut at) = (0.0, (0, 0));
            for y in 0..h {
                for x in 0..w {
                    if luminance(out.get(x, y)) > best {
                        best = luminance(out.get(x, y));
                        at = (x, y);
                    }
                }
            }
            let got = image_from_target(o).transpose() * pixel_to_dir(at.0, at.1, w, h);
            assert!(
                got.angle_between(want).to_degrees() < 8.0,
                "{o:?}: {got} vs {want}"
            );
            // The brightest texel of a GL cube built like export's looks along
            // it too.
            let n = 16;
            let cube = gl_cube(n, |d| {
                crate::sphere::sample_dir(&out, image_from_target(o) * d)
            });
            let (mut best, mut dir) = (0.0, Vec3::ZERO);
            for (f, face) in cube.iter().enumerate() {
                for y in 0..n {
                    for x in 0..n {
                        if luminance(face.get(x, y)) > best {
                            best = luminance(face.get(x, y));
                            let (s, t) = ((x as f32 + 0.5) / n as f32, (y as f32 + 0.5) / n as f32);
                            dir = gl_face_dir(f, s, t).normalize();
                        }
                    }
                }
            }
            assert!(
                dir.angle_between(want).to_degrees() < 8.0,
                "{o:?} cube: {dir} vs {want}"
            );
        }
    }

    #[test]
    fn sh_in_the_target_axes_puts_the_light_where_the_target_says() {
        let (w, h) = (64, 32);
        let p = pose(-1.2);
        let mut img = HdrImage::from_fn(w, h, |_, _| [0.05, 0.05, 0.05]);
        for (x, y) in [(10, 8), (11, 8), (10, 9), (11, 9)] {
            img.set(x, y, [300.0, 300.0, 300.0]);
        }
        let world = p.world_from_camera * pixel_to_dir(10, 8, w, h);
        for (o, want) in [
            (Orientation::Y, world_from_y_up().transpose() * world),
            (Orientation::Z, world),
        ] {
            let eq = rotate(&img, camera_from_image(&p, o), w, h);
            let sh = Sh9::project(&eq).rotate(image_from_target(o));
            let dom = sh.dominant_direction().unwrap();
            assert!(
                dom.angle_between(want).to_degrees() < 12.0,
                "{o:?}: {dom} vs {want}"
            );
        }
    }
}
