//! Lights as lights: a probe's dominant emitters taken out as directional
//! lights (glTF `KHR_lights_punctual`), and the residual environment with their
//! light removed, so that a renderer gets sharp shadows and no fireflies from a
//! sun in its environment map, and the total light is kept.
//!
//! A light is a connected region of pixels brighter than `contrast` times the
//! probe's median radiance (over solid angle: what most directions see, which
//! a sun does not move), no larger than `max_solid_angle_sr`, holding at least
//! `min_share` of the probe's power. Its pixels are scaled down, colour kept,
//! to the threshold's luminance; what was taken, integrated over their solid
//! angles channel by channel, is the light (for a compact source, its
//! illuminance at normal incidence: lux when the probe is in cd/m²). So per
//! channel, the lights plus the residual's integral over the sphere equal the
//! probe's integral, exactly up to rounding.

use crate::image::{luminance, HdrImage};
use crate::sphere::mask::components;
use crate::sphere::{pixel_to_dir, row_solid_angles};
use glam::Vec3;
use serde::{Deserialize, Serialize};

/// What counts as a light ([`split_lights`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LightOptions {
    /// Radiance (luminance) over the probe's median radiance (over solid angle)
    /// above which a pixel may belong to a light.
    pub contrast: f32,
    /// Largest solid angle of a light (steradians): larger bright regions (a
    /// window, an overcast sky) stay in the environment.
    pub max_solid_angle_sr: f64,
    /// Smallest share of the probe's luminance power a light must hold.
    pub min_share: f64,
    /// Most lights taken, the strongest first.
    pub max_lights: usize,
}

impl Default for LightOptions {
    fn default() -> Self {
        LightOptions {
            contrast: 50.0,
            // A cap of about 9 degrees across: a sun, a lamp, a small window.
            max_solid_angle_sr: 0.02,
            min_share: 0.02,
            max_lights: 4,
        }
    }
}

/// One light taken out of a probe.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProbeLight {
    /// Direction towards the light (unit, the probe's axes), weighted by the
    /// light taken out of each pixel.
    pub dir: [f32; 3],
    /// Light taken out, per channel: radiance times solid angle summed over its
    /// pixels (the illuminance it gives a surface facing it).
    pub rgb: [f64; 3],
    /// Solid angle of its pixels (steradians).
    pub solid_angle_sr: f64,
}

impl ProbeLight {
    /// Luminance of [`ProbeLight::rgb`].
    pub fn luminance(&self) -> f64 {
        luminance(self.rgb.map(|v| v as f32)) as f64
    }
}

/// Per channel, the integral of an equirect panorama over the sphere.
pub fn integral(img: &HdrImage) -> [f64; 3] {
    let (w, sa) = (img.width(), row_solid_angles(img.width(), img.height()));
    let mut s = [0.0f64; 3];
    for (i, p) in img.pixels().enumerate() {
        for k in 0..3 {
            if p[k].is_finite() {
                s[k] += p[k] as f64 * sa[i / w] as f64;
            }
        }
    }
    s
}

/// The lights of probe `img` (strongest first) and the residual environment
/// (see the module docs). A probe with no light, or with no finite positive
/// power, gives no lights and itself.
pub fn split_lights(img: &HdrImage, opts: &LightOptions) -> (Vec<ProbeLight>, HdrImage) {
    let (w, h) = (img.width(), img.height());
    let mut residual = img.clone();
    if w == 0 || h == 0 {
        return (Vec::new(), residual);
    }
    let sa = row_solid_angles(w, h);
    let lum: Vec<f32> = img
        .pixels()
        .map(|p| {
            let l = luminance(p);
            if l.is_finite() {
                l
            } else {
                0.0
            }
        })
        .collect();
    let power: f64 = lum
        .iter()
        .enumerate()
        .map(|(i, &l)| l.max(0.0) as f64 * sa[i / w] as f64)
        .sum();
    // The median radiance over solid angle.
    let mut order: Vec<usize> = (0..lum.len()).collect();
    order.sort_by(|&a, &b| lum[a].total_cmp(&lum[b]));
    let half = 0.5 * sa.iter().map(|&s| s as f64).sum::<f64>() * w as f64;
    let mut acc = 0.0f64;
    let mut median = 0.0f32;
    for &i in &order {
        acc += sa[i / w] as f64;
        if acc >= half {
            median = lum[i];
            break;
        }
    }
    let threshold = opts.contrast * median;
    if !(power.is_finite() && power > 0.0 && threshold.is_finite() && threshold > 0.0) {
        return (Vec::new(), residual);
    }
    let bright: Vec<bool> = lum.iter().map(|&l| l > threshold).collect();
    let (lab, n) = components(&bright, w, h);
    // Per region: light taken out per channel, direction, solid angle.
    let mut acc = vec![([0.0f64; 3], Vec3::ZERO, 0.0f64); n];
    for (i, &l) in lab.iter().enumerate() {
        if l == u32::MAX {
            continue;
        }
        let (x, y) = (i % w, i / w);
        let p = img.get(x, y);
        let keep = threshold / lum[i];
        let a = &mut acc[l as usize];
        let mut taken = 0.0f64;
        for k in 0..3 {
            let t = (p[k] - p[k] * keep).max(0.0) as f64 * sa[y] as f64;
            a.0[k] += t;
            taken += t;
        }
        a.1 += pixel_to_dir(x, y, w, h) * taken as f32;
        a.2 += sa[y] as f64;
    }
    let mut lights: Vec<(usize, ProbeLight)> = acc
        .iter()
        .enumerate()
        .filter_map(|(r, (rgb, d, solid))| {
            let light = ProbeLight {
                dir: d.normalize_or_zero().to_array(),
                rgb: *rgb,
                solid_angle_sr: *solid,
            };
            let share = light.luminance() / power;
            (d.length() > 0.0
                && *solid <= opts.max_solid_angle_sr
                && share.is_finite()
                && share >= opts.min_share)
                .then_some((r, light))
        })
        .collect();
    lights.sort_by(|a, b| b.1.luminance().total_cmp(&a.1.luminance()));
    lights.truncate(opts.max_lights);
    let mut taken = vec![false; n];
    for (r, _) in &lights {
        taken[*r] = true;
    }
    for (i, &l) in lab.iter().enumerate() {
        if l != u32::MAX && taken[l as usize] {
            let (x, y) = (i % w, i / w);
            let keep = threshold / lum[i];
            let p = img.get(x, y);
            residual.set(x, y, p.map(|v| v * keep));
        }
    }
    (lights.into_iter().map(|(_, l)| l).collect(), residual)
}

/// Where a light is, for a renderer.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "type")]
pub enum Placement {
    /// At infinity (a sun), or at an unknown distance: a directional light.
    Directional,
    /// At a known position (glTF axes, the scene's unit), `distance` from the
    /// probe: a point light whose intensity gives the probe the light's
    /// illuminance (intensity = illuminance x distance^2, candela when the
    /// probe is in cd/m² and the unit is the metre).
    Point { position: [f32; 3], distance: f32 },
    /// A point light on a flat emitter (a ceiling panel, a wall lamp): a spot
    /// light shining into the half-space `facing` points into (glTF axes,
    /// unit), outer cone 90 degrees, inner cone 0. glTF's spot falloff is the
    /// square of the cosine off its axis; `falloff` is that factor in the
    /// probe's direction (at least [`MIN_SPOT_FALLOFF`]), so the intensity
    /// on the axis is illuminance x distance^2 / falloff and the probe gets
    /// the light it measured.
    Spot {
        position: [f32; 3],
        distance: f32,
        facing: [f32; 3],
        falloff: f32,
    },
}

/// Smallest spot falloff a light is given (the square of cos 75 degrees): a
/// probe that sees a flat emitter at grazing incidence measures too little of
/// it to set its intensity on the axis.
pub const MIN_SPOT_FALLOFF: f32 = 0.067;

/// glTF's spot falloff (inner cone 0, outer cone 90 degrees) at a receiver in
/// direction `to_receiver` (unit) from a light facing `facing` (unit): the
/// square of the cosine between them, at least [`MIN_SPOT_FALLOFF`].
pub fn spot_falloff(facing: Vec3, to_receiver: Vec3) -> f32 {
    let c = facing.dot(to_receiver).max(0.0);
    if c.is_finite() {
        (c * c).max(MIN_SPOT_FALLOFF)
    } else {
        MIN_SPOT_FALLOFF
    }
}

/// The lights as a glTF 2.0 document with `KHR_lights_punctual`, colour
/// normalised to each light's largest channel: a directional light on a node
/// turned so that its `-z` axis points the way the light travels, intensity
/// the largest channel's illuminance; or a point light on a node at its
/// position. `dirs_to_gltf` takes a direction of the probe's axes to glTF's
/// (`+y` up).
pub fn lights_gltf(
    lights: &[(ProbeLight, Placement)],
    dirs_to_gltf: glam::Mat3,
) -> serde_json::Value {
    let mut defs = Vec::new();
    let mut nodes = Vec::new();
    for (k, (l, place)) in lights.iter().enumerate() {
        let max = l.rgb.iter().copied().fold(0.0f64, f64::max);
        let colour = if max > 0.0 {
            l.rgb.map(|v| v / max)
        } else {
            [1.0; 3]
        };
        let name = format!("light_{k}");
        let ext = serde_json::json!({ "KHR_lights_punctual": { "light": k } });
        match place {
            Placement::Directional => {
                let travel = -(dirs_to_gltf * Vec3::from_array(l.dir)).normalize_or_zero();
                let q = glam::Quat::from_rotation_arc(Vec3::NEG_Z, travel);
                defs.push(serde_json::json!({
                    "name": name, "type": "directional", "color": colour, "intensity": max,
                }));
                nodes.push(serde_json::json!({
                    "name": name, "rotation": [q.x, q.y, q.z, q.w], "extensions": ext,
                }));
            }
            Placement::Point { position, distance } => {
                let d = *distance as f64;
                defs.push(serde_json::json!({
                    "name": name, "type": "point", "color": colour, "intensity": max * d * d,
                }));
                nodes.push(serde_json::json!({
                    "name": name, "translation": position, "extensions": ext,
                }));
            }
            Placement::Spot {
                position,
                distance,
                facing,
                falloff,
            } => {
                let d = *distance as f64;
                let f = (*falloff).max(MIN_SPOT_FALLOFF) as f64;
                let q = glam::Quat::from_rotation_arc(
                    Vec3::NEG_Z,
                    Vec3::from_array(*facing).normalize_or_zero(),
                );
                defs.push(serde_json::json!({
                    "name": name, "type": "spot", "color": colour, "intensity": max * d * d / f,
                    "spot": { "innerConeAngle": 0.0, "outerConeAngle": std::f32::consts::FRAC_PI_2 },
                }));
                nodes.push(serde_json::json!({
                    "name": name, "translation": position, "rotation": [q.x, q.y, q.z, q.w],
                    "extensions": ext,
                }));
            }
        }
    }
    let indices: Vec<usize> = (0..nodes.len()).collect();
    serde_json::json!({
        "asset": { "version": "2.0", "generator": "lumiprobe" },
        "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": { "KHR_lights_punctual": { "lights": defs } },
        "nodes": nodes,
        "scenes": [{ "nodes": indices }],
        "scene": 0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sphere::dir_to_uv;

    /// A dim sky with a sun of `sun` radiance filling a few pixels around
    /// direction `d`.
    fn sky_with_sun(w: usize, h: usize, d: Vec3, sun: f32) -> HdrImage {
        let d = d.normalize();
        HdrImage::from_fn(w, h, |x, y| {
            let p = pixel_to_dir(x, y, w, h);
            if p.dot(d) > 2f32.to_radians().cos() {
                [sun, 0.9 * sun, 0.7 * sun]
            } else {
                [0.5, 0.6, 0.9]
            }
        })
    }

    #[test]
    fn a_sun_becomes_a_light_and_the_light_is_kept_channel_by_channel() {
        let d = Vec3::new(0.3, 0.6, -0.5).normalize();
        let img = sky_with_sun(256, 128, d, 1e5);
        let (lights, residual) = split_lights(&img, &LightOptions::default());
        assert_eq!(lights.len(), 1, "{lights:?}");
        let l = lights[0];
        assert!(
            Vec3::from_array(l.dir).dot(d) > 1f32.to_radians().cos(),
            "{l:?}"
        );
        // The sun's colour survives in the light.
        assert!((l.rgb[1] / l.rgb[0] - 0.9).abs() < 1e-3, "{l:?}");
        let (before, after) = (integral(&img), integral(&residual));
        for k in 0..3 {
            let sum = after[k] + l.rgb[k];
            assert!(
                (sum - before[k]).abs() <= 1e-4 * before[k],
                "channel {k}: {sum} vs {before:?}"
            );
        }
        // No residual pixel is brighter than the threshold (50 x the sky's
        // luminance, the median) any more.
        let sky = luminance([0.5, 0.6, 0.9]);
        let top = residual.pixels().map(luminance).fold(0.0f32, f32::max);
        assert!(top <= 50.0 * sky * 1.0001, "{top} vs {}", 50.0 * sky);
        // Away from the sun the residual is the probe.
        let (u, v) = dir_to_uv(-d);
        let (x, y) = ((u * 256.0) as usize, (v * 128.0) as usize);
        assert_eq!(residual.get(x, y), img.get(x, y));
    }

    #[test]
    fn a_uniform_sky_or_a_large_window_is_no_light() {
        let flat = HdrImage::from_fn(64, 32, |_, _| [1.0, 1.0, 1.0]);
        let (lights, residual) = split_lights(&flat, &LightOptions::default());
        assert!(lights.is_empty());
        assert_eq!(residual.data(), flat.data());
        // A bright region of 0.5 sr is a window, not a light.
        let d = Vec3::new(0.0, 0.2, -1.0).normalize();
        let window = HdrImage::from_fn(128, 64, |x, y| {
            if pixel_to_dir(x, y, 128, 64).dot(d) > 0.92 {
                [500.0; 3]
            } else {
                [0.1; 3]
            }
        });
        let (lights, _) = split_lights(&window, &LightOptions::default());
        assert!(lights.is_empty(), "{lights:?}");
        // Non-finite or empty probes give no lights and no panic.
        let nan = HdrImage::from_fn(16, 8, |_, _| [f32::NAN; 3]);
        assert!(split_lights(&nan, &LightOptions::default()).0.is_empty());
        assert!(split_lights(&HdrImage::new(0, 0), &LightOptions::default())
            .0
            .is_empty());
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(32))]
        /// Whatever the sun's direction, radiance and size, and the contrast
        /// asked for: per channel, the lights plus the residual hold the
        /// probe's light, no residual pixel of a light is left above the
        /// threshold, and no light is larger than allowed.
        #[test]
        fn lights_and_residual_keep_the_probes_light(
            az in -3.1f32..3.1,
            el in -1.4f32..1.4,
            sun in 10.0f32..1e6,
            cap_deg in 0.5f32..6.0,
            contrast in 5.0f32..500.0,
        ) {
            let d = Vec3::new(el.cos() * az.sin(), el.sin(), -el.cos() * az.cos());
            let (w, h) = (128, 64);
            let img = HdrImage::from_fn(w, h, |x, y| {
                if pixel_to_dir(x, y, w, h).dot(d) > cap_deg.to_radians().cos() {
                    [sun, 0.8 * sun, 0.6 * sun]
                } else {
                    [0.5, 0.6, 0.9]
                }
            });
            let opts = LightOptions { contrast, ..LightOptions::default() };
            let (lights, residual) = split_lights(&img, &opts);
            let (before, after) = (integral(&img), integral(&residual));
            for k in 0..3 {
                let sum = after[k] + lights.iter().map(|l| l.rgb[k]).sum::<f64>();
                proptest::prop_assert!(
                    (sum - before[k]).abs() <= 1e-4 * before[k],
                    "channel {}: {} vs {}", k, sum, before[k]
                );
            }
            for l in &lights {
                proptest::prop_assert!(l.solid_angle_sr <= opts.max_solid_angle_sr);
                proptest::prop_assert!(Vec3::from_array(l.dir).dot(d) > 0.99);
            }
            if !lights.is_empty() {
                let top = residual.pixels().map(luminance).fold(0.0f32, f32::max);
                let sky = luminance([0.5, 0.6, 0.9]);
                proptest::prop_assert!(top <= contrast * sky * 1.0001, "{} > {}", top, contrast * sky);
            }
        }
    }

    /// The rotation of node `k` of a glTF document.
    fn node_rotation(g: &serde_json::Value, k: usize) -> glam::Quat {
        let r: Vec<f32> = (0..4)
            .map(|i| g["nodes"][k]["rotation"][i].as_f64().unwrap() as f32)
            .collect();
        glam::Quat::from_xyzw(r[0], r[1], r[2], r[3])
    }

    #[test]
    fn the_gltf_light_points_from_the_sun() {
        let l = ProbeLight {
            dir: [0.0, 1.0, 0.0],
            rgb: [2.0, 4.0, 1.0],
            solid_angle_sr: 1e-4,
        };
        let g = lights_gltf(
            &[
                (l, Placement::Directional),
                (
                    l,
                    Placement::Point {
                        position: [1.0, 2.0, 3.0],
                        distance: 2.0,
                    },
                ),
            ],
            glam::Mat3::IDENTITY,
        );
        // A point light 2 units away gives the probe the same illuminance.
        let point = &g["extensions"]["KHR_lights_punctual"]["lights"][1];
        assert_eq!(point["type"], "point");
        assert_eq!(point["intensity"].as_f64(), Some(16.0));
        assert_eq!(g["nodes"][1]["translation"][2].as_f64(), Some(3.0));
        let def = &g["extensions"]["KHR_lights_punctual"]["lights"][0];
        assert_eq!(def["type"], "directional");
        assert_eq!(def["intensity"].as_f64(), Some(4.0));
        assert_eq!(def["color"][0].as_f64(), Some(0.5));
        let q = node_rotation(&g, 0);
        // A sun overhead shines straight down.
        assert!((q * Vec3::NEG_Z).dot(Vec3::NEG_Y) > 0.9999);
    }

    #[test]
    fn a_flat_emitters_spot_gives_the_probe_off_its_axis_the_light_it_measured() {
        let l = ProbeLight {
            dir: [0.6, 0.8, 0.0],
            rgb: [2.0, 4.0, 1.0],
            solid_angle_sr: 1e-4,
        };
        // A panel 2 units away, facing down; the probe is 36.87 degrees off its
        // axis (cos 0.8), the falloff 0.64.
        let facing = Vec3::NEG_Y;
        let to_probe = -Vec3::from_array(l.dir);
        let falloff = spot_falloff(facing, to_probe);
        assert!((falloff - 0.64).abs() < 1e-6, "{falloff}");
        let g = lights_gltf(
            &[(
                l,
                Placement::Spot {
                    position: [1.2, 1.6, 0.0],
                    distance: 2.0,
                    facing: facing.to_array(),
                    falloff,
                },
            )],
            glam::Mat3::IDENTITY,
        );
        let def = &g["extensions"]["KHR_lights_punctual"]["lights"][0];
        assert_eq!(def["type"], "spot");
        assert_eq!(def["spot"]["innerConeAngle"].as_f64(), Some(0.0));
        let outer = def["spot"]["outerConeAngle"].as_f64().unwrap();
        assert!((outer - std::f64::consts::FRAC_PI_2).abs() < 1e-6);
        // On the axis: illuminance 4 x 2^2 / 0.64.
        let i = def["intensity"].as_f64().unwrap();
        assert!((i - 25.0).abs() < 1e-4, "{i}");
        let q = node_rotation(&g, 0);
        assert!((q * Vec3::NEG_Z).dot(facing) > 0.9999);
        // A probe at grazing incidence or behind the panel sets no runaway
        // intensity.
        assert_eq!(spot_falloff(facing, Vec3::X), MIN_SPOT_FALLOFF);
        assert_eq!(spot_falloff(facing, Vec3::Y), MIN_SPOT_FALLOFF);
        assert_eq!(spot_falloff(facing, Vec3::NAN), MIN_SPOT_FALLOFF);
    }
}
