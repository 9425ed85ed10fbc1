//! A CPU rasterizer that renders glTF 2.0 models lit by an HDR light probe, to
//! show what a predicted probe does to a real object (image-based lighting).
//!
//! Lighting is the split-sum approximation of Karis 2013 ("Real Shading in Unreal
//! Engine 4"): an [`Environment`] supplies diffuse irradiance, prefiltered
//! specular radiance and the environment-BRDF scale/bias; the material model is
//! the glTF 2.0 metallic-roughness BRDF (specification Appendix B). Because a
//! single bright direction is not representable exactly by a prefiltered probe,
//! analytic directional lights ([`DirLight`]) are shaded with the full BRDF
//! instead, which gives an exact reference for tests.
//!
//! Shading at a surface point with normal `n` (normal-mapped), view `v`,
//! reflection `r = reflect(-v, n)`, `(A, B) = env.brdf(n.v, roughness)`:
//!
//! ```text
//! E_d      = s (0.04 A + B)                       dielectric specular albedo
//! diffuse  = (1 - metallic) baseColor / pi * irradiance(n) * (1 - E_d)
//! specular = specular(r, roughness) * ((1 - metallic) E_d + metallic (baseColor A + B))
//! L_o      = ao (diffuse + specular) + emissive + sum over lights f(v, l) E0 max(0, n.l)
//! ```
//!
//! The `(1 - E_d)` weight is the split-sum form of Appendix B's
//! `fresnel_mix(base, layer) = base (1 - F) + layer F`: a white dielectric in a
//! uniform environment reflects exactly the environment radiance at every
//! roughness. `s` is the KHR_materials_specular factor (1 by default). Metals
//! lose the single-scattering energy of GGX at high roughness (no multiple-
//! scattering compensation).
//!
//! Pieces: [`model`] (glTF loading, procedural spheres), [`camera`], [`brdf`]
//! (BRDF terms and the split-sum table) and the rasterizer behind [`render`].

pub mod brdf;
pub mod camera;
pub mod model;
mod probe_env;
mod raster;

pub use brdf::{SplitSumLut, SurfaceParams};
pub use camera::Camera;
pub use model::{Aabb, LoadLimits, Material, Mesh, Model, Texture, TextureRef, WrapMode};

use crate::error::{Error, Result};
use crate::image::{HdrImage, SdrImage};
use glam::Vec3;
use std::path::{Path, PathBuf};

/// Incident lighting as the split-sum shading model consumes it. Directions are
/// unit world-space vectors in the project's convention (x right, y up, -z
/// forward; see [`crate::sphere`]) pointing away from the surface.
pub trait Environment: Sync {
    /// Irradiance `E(n) = ∫ L(l) max(0, n.l) dl` on a surface with normal `n`,
    /// so a Lambertian surface of albedo `c` reflects `c / pi * E`.
    fn irradiance(&self, n: Vec3) -> [f32; 3];
    /// Radiance around the reflection direction `r`, prefiltered with the GGX
    /// lobe of the given perceptual roughness (first split-sum factor).
    fn specular(&self, r: Vec3, roughness: f32) -> [f32; 3];
    /// Environment BRDF `(A, B)` with `∫ f n.l = f0 A + B` (second split-sum
    /// factor, Karis 2013).
    fn brdf(&self, n_dot_v: f32, roughness: f32) -> [f32; 2];
    /// Radiance seen directly along `d` (for the background).
    fn background(&self, d: Vec3) -> [f32; 3];
}

/// A uniform environment of radiance `radiance` in every direction: irradiance
/// `pi L`, prefiltered radiance `L` at every roughness, the shared split-sum
/// table ([`SplitSumLut::shared`]). The white furnace of shading tests.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConstantEnv {
    /// Linear RGB radiance.
    pub radiance: [f32; 3],
}

impl Environment for ConstantEnv {
    fn irradiance(&self, _n: Vec3) -> [f32; 3] {
        self.radiance.map(|l| std::f32::consts::PI * l)
    }
    fn specular(&self, _r: Vec3, _roughness: f32) -> [f32; 3] {
        self.radiance
    }
    fn brdf(&self, n_dot_v: f32, roughness: f32) -> [f32; 2] {
        SplitSumLut::shared().lookup(n_dot_v, roughness)
    }
    fn background(&self, _d: Vec3) -> [f32; 3] {
        self.radiance
    }
}

/// A distant light from a single direction, shaded with the full glTF BRDF:
/// adds `f(v, l) * irradiance * max(0, n.l)`. No shadows are cast.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DirLight {
    /// Direction from the surface towards the light (normalised on use).
    pub dir: Vec3,
    /// Irradiance at normal incidence `E0` (radiance times solid angle), RGB.
    pub irradiance: [f32; 3],
}

/// What uncovered pixels (and partially covered edges) show.
#[derive(Clone, Debug, PartialEq, Default)]
pub enum Background {
    /// Nothing: colour 0, so the output is premultiplied by its alpha.
    Transparent,
    /// The environment seen along each pixel's view ray.
    #[default]
    Environment,
    /// A constant linear colour.
    Color([f32; 3]),
    /// A linear image stretched over the frame (bilinear).
    Image(HdrImage),
}

impl Background {
    /// An 8-bit sRGB photograph as a linear background image.
    pub fn from_sdr(img: &SdrImage) -> Background {
        let data = img
            .data()
            .iter()
            .map(|&c| crate::tonemap::srgb_eotf(c as f32 / 255.0))
            .collect();
        // Sizes match by construction.
        match HdrImage::from_vec(img.width(), img.height(), data) {
            Ok(h) => Background::Image(h),
            Err(_) => Background::Transparent,
        }
    }
}

/// How to render.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    /// What shows behind the model.
    pub background: Background,
    /// Samples per pixel side (1 = none, 2 = 2x2, at most 8).
    pub supersample: usize,
    /// Analytic directional lights added to the environment lighting.
    pub lights: Vec<DirLight>,
}

impl Default for RenderOptions {
    /// Environment background, 2x2 supersampling, no extra lights.
    fn default() -> Self {
        RenderOptions {
            background: Background::Environment,
            supersample: 2,
            lights: Vec::new(),
        }
    }
}

/// A rendered frame.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOutput {
    /// Linear radiance (finite, non-negative).
    pub color: HdrImage,
    /// Fraction of each pixel's samples covered by the model, row-major.
    pub alpha: Vec<f32>,
    /// `color` is premultiplied by `alpha` (the background was transparent).
    pub premultiplied: bool,
}

impl RenderOutput {
    /// Fraction of the image covered by the model (mean alpha).
    pub fn coverage(&self) -> f32 {
        if self.alpha.is_empty() {
            0.0
        } else {
            self.alpha.iter().sum::<f32>() / self.alpha.len() as f32
        }
    }
}

/// Renders `model` from `camera` under `env` (plus `options.lights`): z-buffered
/// perspective rasterization in parallel tiles with deterministic output,
/// perspective-correct attributes, back-face culling unless the material is
/// double-sided. Fails on an invalid camera or an inconsistent model.
pub fn render<E: Environment + ?Sized>(
    model: &Model,
    env: &E,
    camera: &Camera,
    options: &RenderOptions,
) -> Result<RenderOutput> {
    raster::render_impl(model, env, camera, options)
}

/// Writes a render as `<out>.exr` (linear float; RGBA with premultiplied alpha
/// when the background was transparent, else RGB) and `<out>.png` (exposure by
/// `2^exposure_ev`, clipped, sRGB-encoded; RGBA when transparent). `out`'s own
/// extension is replaced. Returns the two paths written.
pub fn write_render(
    out: &Path,
    output: &RenderOutput,
    exposure_ev: f32,
) -> Result<(PathBuf, PathBuf)> {
    let exr_path = out.with_extension("exr");
    let png_path = out.with_extension("png");
    let img = &output.color;
    let (w, h) = (img.width(), img.height());
    if output.alpha.len() != w * h {
        return Err(Error::Invalid(format!(
            "{}: render has {} alpha values for {w}x{h} pixels",
            out.display(),
            output.alpha.len()
        )));
    }
    if output.premultiplied {
        write_rgba_exr(&exr_path, output)?;
    } else {
        crate::image::io::write_hdr(&exr_path, img)?;
    }
    let scale = 2f32.powf(exposure_ev);
    let enc = |v: f32| {
        let v = if v.is_finite() { v * scale } else { 0.0 };
        (crate::tonemap::srgb_oetf(v.clamp(0.0, 1.0)) * 255.0 + 0.5) as u8
    };
    if output.premultiplied {
        let mut rgba = Vec::with_capacity(w * h * 4);
        for (p, &a) in img.pixels().zip(&output.alpha) {
            let inv = if a > 0.0 { 1.0 / a } else { 0.0 };
            rgba.extend(p.map(|c| enc(c * inv)));
            rgba.push((a.clamp(0.0, 1.0) * 255.0 + 0.5) as u8);
        }
        let mut bytes = Vec::new();
        {
            use image::ImageEncoder;
            image::codecs::png::PngEncoder::new(&mut bytes)
                .write_image(&rgba, w as u32, h as u32, image::ExtendedColorType::Rgba8)
                .map_err(|e| {
                    Error::Invalid(format!("{}: cannot encode PNG: {e}", png_path.display()))
                })?;
        }
        crate::fsutil::write_atomic(&png_path, &bytes)?;
    } else {
        let rgb = img.data().iter().map(|&c| enc(c)).collect();
        crate::image::io::write_sdr(&png_path, &SdrImage::from_vec(w, h, rgb)?)?;
    }
    Ok((exr_path, png_path))
}

/// Float RGBA OpenEXR (ZIP), written atomically.
fn write_rgba_exr(path: &Path, output: &RenderOutput) -> Result<()> {
    let img = &output.color;
    if img.width() == 0 || img.height() == 0 {
        return Err(Error::Invalid(format!(
            "{}: cannot write an empty image",
            path.display()
        )));
    }
    if img
        .data()
        .iter()
        .chain(&output.alpha)
        .any(|v| !v.is_finite())
    {
        return Err(Error::Invalid(format!(
            "{}: render has NaN or infinite samples; refusing to write them",
            path.display()
        )));
    }
    let w = img.width();
    let channels = exr::image::SpecificChannels::rgba(|pos: exr::math::Vec2<usize>| {
        let p = img.get(pos.x(), pos.y());
        (p[0], p[1], p[2], output.alpha[pos.y() * w + pos.x()])
    });
    let encoding = exr::image::Encoding {
        compression: exr::compression::Compression::ZIP16,
        blocks: exr::image::Blocks::ScanLines,
        line_order: exr::meta::attribute::LineOrder::Increasing,
    };
    let layer = exr::image::Layer::new(
        (img.width(), img.height()),
        exr::meta::header::LayerAttributes::default(),
        encoding,
        channels,
    );
    let mut buf = std::io::Cursor::new(Vec::new());
    {
        use exr::prelude::WritableImage;
        exr::image::Image::from_layer(layer)
            .write()
            .to_buffered(&mut buf)
            .map_err(|e| {
                Error::Invalid(format!("{}: cannot encode OpenEXR: {e}", path.display()))
            })?;
    }
    crate::fsutil::write_atomic(path, &buf.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(w: usize, h: usize) -> Camera {
        Camera {
            eye: Vec3::new(0.0, 0.0, 3.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 45.0,
            width: w,
            height: h,
        }
    }

    #[test]
    fn output_is_deterministic_and_sized() {
        let m = Model::uv_sphere(1.0, 24, Material::basic([0.8, 0.4, 0.2], 0.0, 0.5));
        let env = ConstantEnv { radiance: [1.0; 3] };
        let opts = RenderOptions::default();
        let a = render(&m, &env, &cam(70, 45), &opts).unwrap();
        let b = render(&m, &env, &cam(70, 45), &opts).unwrap();
        assert_eq!(a, b);
        assert_eq!(a.color.width(), 70);
        assert_eq!(a.alpha.len(), 70 * 45);
        assert!(a.coverage() > 0.1 && a.coverage() < 0.9);
        assert_eq!(a.color.count_invalid(), 0);
        // Single-threaded gives the same image.
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let c = pool.install(|| render(&m, &env, &cam(70, 45), &opts).unwrap());
        assert_eq!(a, c);
    }

    #[test]
    fn closed_mesh_has_no_cracks() {
        // A fine sphere seen head-on: every sample inside its silhouette is covered.
        let m = Model::uv_sphere(1.0, 64, Material::basic([1.0; 3], 0.0, 1.0));
        let env = ConstantEnv { radiance: [1.0; 3] };
        let opts = RenderOptions {
            background: Background::Transparent,
            supersample: 1,
            lights: Vec::new(),
        };
        let c = cam(101, 101);
        let out = render(&m, &env, &c, &opts).unwrap();
        let centre = Vec3::ZERO;
        for y in 0..101 {
            for x in 0..101 {
                let d = c.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
                // Distance of the ray from the centre; well inside the polygon.
                let t = (centre - c.eye).dot(d);
                let miss = (c.eye + d * t - centre).length();
                if miss < 0.95 {
                    assert_eq!(out.alpha[y * 101 + x], 1.0, "hole at {x},{y}");
                }
                if miss > 1.01 {
                    assert_eq!(out.alpha[y * 101 + x], 0.0, "spill at {x},{y}");
                }
            }
        }
    }

    #[test]
    fn back_faces_are_culled_unless_double_sided() {
        // A single triangle facing away from the camera (clockwise seen from +z).
        let mk = |double_sided: bool| Model {
            meshes: vec![Mesh {
                positions: vec![
                    Vec3::new(-1.0, -1.0, 0.0),
                    Vec3::new(0.0, 1.0, 0.0),
                    Vec3::new(1.0, -1.0, 0.0),
                ],
                indices: vec![[0, 1, 2]],
                ..Default::default()
            }],
            materials: vec![Material {
                double_sided,
                ..Material::basic([1.0; 3], 0.0, 1.0)
            }],
            textures: vec![],
        };
        let env = ConstantEnv { radiance: [1.0; 3] };
        let opts = RenderOptions {
            background: Background::Transparent,
            ..Default::default()
        };
        let single = render(&mk(false), &env, &cam(32, 32), &opts).unwrap();
        assert_eq!(single.coverage(), 0.0);
        let double = render(&mk(true), &env, &cam(32, 32), &opts).unwrap();
        assert!(double.coverage() > 0.1);
        // Lit from the viewer's side: the flipped normal faces the camera.
        let lit = RenderOptions {
            lights: vec![DirLight {
                dir: Vec3::Z,
                irradiance: [1.0; 3],
            }],
            ..opts
        };
        let black = ConstantEnv { radiance: [0.0; 3] };
        let o = render(&mk(true), &black, &cam(32, 32), &lit).unwrap();
        assert!(o.color.get(16, 18)[0] > 0.2, "{:?}", o.color.get(16, 18));
    }

    #[test]
    fn camera_inside_geometry_is_clipped_without_panic() {
        let m = Model::uv_sphere(1.0, 16, Material::basic([0.5; 3], 0.0, 1.0));
        let mut c = cam(40, 30);
        c.eye = Vec3::new(0.0, 0.0, 0.5);
        let mut mat = m.clone();
        mat.materials[0].double_sided = true;
        let out = render(
            &mat,
            &ConstantEnv { radiance: [1.0; 3] },
            &c,
            &RenderOptions::default(),
        )
        .unwrap();
        assert_eq!(out.coverage(), 1.0);
        assert_eq!(out.color.count_invalid(), 0);
        let bad = Camera { width: 0, ..c };
        assert!(render(
            &m,
            &ConstantEnv { radiance: [1.0; 3] },
            &bad,
            &RenderOptions::default()
        )
        .is_err());
    }

    /// A unit quad in the z = 0 plane facing +z (u along +x, v along -y) with a
    /// constant normal map; `tangents` selects given or per-triangle tangents.
    fn normal_mapped_quad(texel: [u8; 3], tangents: bool, mat: Material) -> Model {
        use glam::{Vec2, Vec4};
        let mesh = Mesh {
            positions: vec![
                Vec3::new(-1.0, -1.0, 0.0),
                Vec3::new(1.0, -1.0, 0.0),
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(-1.0, 1.0, 0.0),
            ],
            normals: vec![Vec3::Z; 4],
            tangents: if tangents {
                vec![Vec4::new(1.0, 0.0, 0.0, 1.0); 4]
            } else {
                vec![]
            },
            uv0: vec![
                Vec2::new(0.0, 1.0),
                Vec2::new(1.0, 1.0),
                Vec2::new(1.0, 0.0),
                Vec2::new(0.0, 0.0),
            ],
            indices: vec![[0, 1, 2], [0, 2, 3]],
            ..Default::default()
        };
        Model {
            meshes: vec![mesh],
            materials: vec![Material {
                normal_texture: Some(TextureRef::new(0)),
                ..mat
            }],
            textures: vec![Texture::from_rgb8(2, 2, texel.repeat(4)).unwrap()],
        }
    }

    #[test]
    fn normal_maps_tilt_towards_tangent_and_bitangent() {
        let black = ConstantEnv { radiance: [0.0; 3] };
        let lambert = Material {
            specular: 0.0,
            ..Material::basic([1.0; 3], 0.0, 1.0)
        };
        let dec = |c: u8| c as f32 / 255.0 * 2.0 - 1.0;
        // (+0.6, 0, 0.8) tilts towards +x (tangent), (0, +0.6, 0.8) towards +y
        // (bitangent = "up" in the image).
        for (texel, axis) in [([204u8, 128, 230], Vec3::X), ([128, 204, 230], Vec3::Y)] {
            let tn = Vec3::new(dec(texel[0]), dec(texel[1]), dec(texel[2])).normalize();
            // The quad's frame is the world frame: T = +x, B = +y, N = +z.
            let n = tn;
            for tangents in [true, false] {
                let m = normal_mapped_quad(texel, tangents, lambert.clone());
                for l in [axis * 0.8 + Vec3::Z * 0.6, -axis * 0.8 + Vec3::Z * 0.6] {
                    let opts = RenderOptions {
                        background: Background::Transparent,
                        supersample: 1,
                        lights: vec![DirLight {
                            dir: l,
                            irradiance: [1.0; 3],
                        }],
                    };
                    let out = render(&m, &black, &cam(33, 33), &opts).unwrap();
                    let got = out.color.get(16, 16)[0];
                    let want = n.dot(l.normalize()).max(0.0) / std::f32::consts::PI;
                    assert!(
                        (got - want).abs() < 0.01,
                        "axis {axis} tangents {tangents} light {l}: {got} vs {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn occlusion_and_emission() {
        let env = ConstantEnv { radiance: [1.0; 3] };
        let mut m = normal_mapped_quad([128, 128, 255], true, Material::basic([0.5; 3], 0.0, 1.0));
        m.materials[0].specular = 0.0;
        m.materials[0].occlusion_texture = Some(TextureRef::new(1));
        m.materials[0].occlusion_strength = 0.5;
        m.materials[0].emissive = [0.0, 0.0, 2.0];
        m.textures
            .push(Texture::from_rgb8(1, 1, vec![0, 255, 255]).unwrap());
        let opts = RenderOptions {
            supersample: 1,
            ..Default::default()
        };
        let out = render(&m, &env, &cam(33, 33), &opts).unwrap();
        let p = out.color.get(16, 16);
        // ao = 1 + 0.5 (0 - 1) = 0.5 on 0.5 L; emission adds 2 to blue.
        assert!(
            (p[0] - 0.25).abs() < 0.01 && (p[2] - 2.25).abs() < 0.01,
            "{p:?}"
        );
    }

    #[test]
    fn write_render_writes_exr_and_png() {
        let tmp = tempfile::tempdir().unwrap();
        let m = Model::uv_sphere(1.0, 12, Material::basic([0.5; 3], 0.0, 1.0));
        for bg in [Background::Transparent, Background::Environment] {
            let opts = RenderOptions {
                background: bg,
                ..Default::default()
            };
            let out = render(&m, &ConstantEnv { radiance: [2.0; 3] }, &cam(16, 8), &opts).unwrap();
            let (e, p) = write_render(&tmp.path().join("r.out"), &out, -1.0).unwrap();
            let back = crate::image::io::read_hdr(&e).unwrap();
            assert_eq!((back.width(), back.height()), (16, 8));
            let sdr = crate::image::io::read_sdr(&p).unwrap();
            assert_eq!((sdr.width(), sdr.height()), (16, 8));
        }
    }
}
