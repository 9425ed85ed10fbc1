//! A set of light probes placed in the world, queried by position: what a renderer
//! needs to light an object standing somewhere along the walk. The set is either a
//! run's per-frame outputs (one probe at every frame's pose) or the scene's own
//! HDR probes.
//!
//! Probes come back in **world orientation**: the equirect of a camera whose
//! axes are world x (right), world z (up) and world -y (back), i.e. with
//! `world_from_camera` = [`WORLD_FROM_PROBE_AXES`]. The panorama's centre looks
//! along world +y and its top row looks up (+z), so probes taken with different
//! headings can be blended texel by texel and a renderer needs only this one
//! fixed rotation.

use crate::error::{Error, Result};
use crate::image::{io, HdrImage};
use crate::scene::{Pose, Scene};
use crate::sphere::rotate;
use glam::{Mat3, Vec3};
use std::path::{Path, PathBuf};

/// Camera axes of the probes a [`ProbeSet`] returns, as a world-from-camera
/// rotation: camera x = world x, camera y (up) = world z, camera -z (forward) =
/// world +y.
pub const WORLD_FROM_PROBE_AXES: Mat3 = Mat3::from_cols(
    Vec3::new(1.0, 0.0, 0.0),
    Vec3::new(0.0, 0.0, 1.0),
    Vec3::new(0.0, -1.0, 0.0),
);

/// One probe of a set: where it was taken and where its panorama lives.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbeEntry {
    /// Frame or probe id.
    pub id: String,
    /// Pose of the panorama's camera.
    pub pose: Pose,
    /// The HDR panorama (equirect, in the camera's own axes).
    pub path: PathBuf,
}

/// How [`ProbeSet::query`] combines probes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Blend {
    /// The nearest probe alone.
    Nearest,
    /// The two nearest probes, weighted by inverse distance (a probe within 1 mm
    /// of the query is returned alone).
    InverseDistance2,
}

/// What a query used: probe ids and their weights (summing to 1).
#[derive(Clone, Debug, PartialEq)]
pub struct QueryReport {
    /// `(id, weight)` of each probe blended.
    pub used: Vec<(String, f32)>,
}

/// Probes placed in the world (see the module docs).
#[derive(Clone, Debug)]
pub struct ProbeSet {
    /// The probes, in the order of the scene file.
    pub entries: Vec<ProbeEntry>,
}

impl ProbeSet {
    /// Opens the per-frame probes written by `lumiprobe run` into `run_dir` for the
    /// scene in `scene_dir` (frames without an output are left out), or, when
    /// `run_dir` is `None`, the scene's own HDR probes. An empty set is an error
    /// naming the folder.
    pub fn open(scene_dir: &Path, run_dir: Option<&Path>) -> Result<ProbeSet> {
        let scene = Scene::load(scene_dir)?;
        let entries: Vec<ProbeEntry> = match run_dir {
            Some(dir) => {
                if !dir.is_dir() {
                    return Err(Error::Invalid(format!(
                        "{}: not a folder of run outputs",
                        dir.display()
                    )));
                }
                scene
                    .frames
                    .iter()
                    .map(|f| ProbeEntry {
                        id: f.id.clone(),
                        pose: f.pose,
                        path: super::prediction_path(dir, f),
                    })
                    .filter(|e| e.path.is_file())
                    .collect()
            }
            None => scene
                .probes
                .iter()
                .filter_map(|p| {
                    p.hdr.as_ref().map(|h| ProbeEntry {
                        id: p.id.clone(),
                        pose: p.pose,
                        path: h.clone(),
                    })
                })
                .collect(),
        };
        if entries.is_empty() {
            let what = run_dir.unwrap_or(scene_dir);
            return Err(Error::Invalid(format!(
                "{}: no probe found (no frame output, or no HDR probe in the scene)",
                what.display()
            )));
        }
        Ok(ProbeSet { entries })
    }

    /// Entry indices sorted by distance to `p` (ties keep file order).
    fn by_distance(&self, p: Vec3) -> Vec<(usize, f32)> {
        let mut v: Vec<(usize, f32)> = self
            .entries
            .iter()
            .enumerate()
            .map(|(i, e)| (i, crate::scene::distance_m(e.pose.position, p)))
            .collect();
        v.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        v
    }

    /// The probes `blend` uses for `position` and their weights.
    pub fn weights(&self, position: Vec3, blend: Blend) -> Result<Vec<(usize, f32)>> {
        if !position.is_finite() {
            return Err(Error::Invalid(format!(
                "query position {position} is not finite"
            )));
        }
        let near = self.by_distance(position);
        let k = match blend {
            Blend::Nearest => 1,
            Blend::InverseDistance2 => 2,
        };
        let near = &near[..k.min(near.len())];
        if near[0].1 < 1e-3 || near.len() == 1 {
            return Ok(vec![(near[0].0, 1.0)]);
        }
        let inv: Vec<f32> = near.iter().map(|&(_, d)| 1.0 / d).collect();
        let s: f32 = inv.iter().sum();
        Ok(near
            .iter()
            .zip(&inv)
            .map(|(&(i, _), &w)| (i, w / s))
            .collect())
    }

    /// The probe for a world `position`, in world orientation (see the module
    /// docs), `width x height` texels (0 x 0 = the first probe's size). Blended
    /// probes are resampled to the common orientation, then mixed in linear
    /// radiance: weights are non-negative, so nothing is clamped or lost.
    pub fn query(
        &self,
        position: Vec3,
        blend: Blend,
        size: Option<(usize, usize)>,
    ) -> Result<(HdrImage, QueryReport)> {
        let w = self.weights(position, blend)?;
        let mut out: Option<HdrImage> = None;
        let mut used = Vec::new();
        for &(i, wt) in &w {
            let e = &self.entries[i];
            let img = io::read_hdr(&e.path)?;
            let (ow, oh) = size.unwrap_or((img.width(), img.height()));
            if ow == 0 || oh == 0 {
                return Err(Error::Invalid(format!(
                    "{}: requested probe size {ow}x{oh} is empty",
                    e.path.display()
                )));
            }
            // Output direction d (probe axes) shows the panorama at
            // camera_from_world * world_from_probe_axes * d.
            let r = e.pose.world_from_camera.transpose() * WORLD_FROM_PROBE_AXES;
            let turned = rotate(&img, r, ow, oh);
            match out.as_mut() {
                None => {
                    let mut t = turned;
                    t.data_mut().iter_mut().for_each(|v| *v *= wt);
                    out = Some(t);
                }
                Some(acc) => {
                    if acc.width() != ow || acc.height() != oh {
                        return Err(Error::Invalid(format!(
                            "{}: {}x{} differs from the other probes' size",
                            e.path.display(),
                            ow,
                            oh
                        )));
                    }
                    for (a, b) in acc.data_mut().iter_mut().zip(turned.data()) {
                        *a += wt * b;
                    }
                }
            }
            used.push((e.id.clone(), wt));
        }
        let img = out.ok_or_else(|| Error::Invalid("empty probe set".into()))?;
        Ok((img, QueryReport { used }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sphere::{dir_to_uv, pixel_to_dir};

    #[test]
    fn probe_axes_are_a_rotation_with_z_up() {
        let m = WORLD_FROM_PROBE_AXES;
        assert!((m.determinant() - 1.0).abs() < 1e-6);
        assert!((m.transpose() * m - Mat3::IDENTITY).abs_diff_eq(Mat3::ZERO, 1e-6));
        // Camera up is world up; camera forward (-z) is world +y.
        assert!(m.mul_vec3(Vec3::Y).abs_diff_eq(Vec3::Z, 1e-6));
        assert!(m.mul_vec3(Vec3::NEG_Z).abs_diff_eq(Vec3::Y, 1e-6));
    }

    fn marker_scene(dir: &Path) {
        // Two probes with different headings; each panorama is dark with one bright
        // texel looking along world +x (east).
        let (w, h) = (64, 32);
        std::fs::create_dir_all(dir.join("probes")).unwrap();
        let mut probes = Vec::new();
        for (k, yaw) in [(0, 0.0f32), (1, 70.0)].iter() {
            let r = Mat3::from_rotation_z(yaw.to_radians());
            // Camera looks along world +y turned by yaw; camera axes in world:
            // x = r*x_w, up = z, forward = r*y_w.
            let wfc = Mat3::from_cols(r * Vec3::X, Vec3::Z, -(r * Vec3::Y));
            let east_cam = wfc.transpose() * Vec3::X;
            let (u, v) = dir_to_uv(east_cam);
            let mut img = HdrImage::new(w, h);
            img.data_mut().iter_mut().for_each(|x| *x = 0.01);
            let (cx, cy) = (
                ((u * w as f32) as usize).min(w - 1),
                ((v * h as f32) as usize).min(h - 1),
            );
            img.set(cx, cy, [100.0 * (*k as f32 + 1.0); 3]);
            let file = dir.join(format!("probes/p{k}.exr"));
            io::write_hdr(&file, &img).unwrap();
            let c = wfc.to_cols_array_2d();
            let rows: Vec<[f32; 3]> = (0..3).map(|i| [c[0][i], c[1][i], c[2][i]]).collect();
            probes.push(serde_json::json!({
                "id": format!("p{k}"), "position": [*k as f32 * 2.0, 0.0, 1.5],
                "yaw_pitch_roll_deg": [yaw, 0.0, 0.0], "world_from_camera": rows,
                "hdr": format!("probes/p{k}.exr"), "brackets": []
            }));
        }
        let poses = serde_json::json!({
            "scene": "markers", "resolution": [w, h], "probes": probes, "frames": [],
            "camera": {"path_gain": 1.0, "bracket_gain_at_0ev": 1.0,
                        "bracket_base_exposure_time_s": 0.0166}
        });
        std::fs::write(dir.join("poses.json"), poses.to_string()).unwrap();
    }

    #[test]
    fn probes_come_back_in_world_orientation_and_blend_by_inverse_distance() {
        let dir = tempfile::tempdir().unwrap();
        marker_scene(dir.path());
        let set = match ProbeSet::open(dir.path(), None) {
            Ok(s) => s,
            Err(e) => panic!("{e}"),
        };
        assert_eq!(set.entries.len(), 2);
        // Nearest: the brightest texel looks east in world orientation.
        let (img, rep) = set
            .query(Vec3::new(0.2, 0.0, 1.5), Blend::Nearest, None)
            .unwrap();
        assert_eq!(rep.used, vec![("p0".to_string(), 1.0)]);
        let east = WORLD_FROM_PROBE_AXES.transpose() * Vec3::X;
        let (mut best, mut bd) = (0.0f32, Vec3::ZERO);
        for row in 0..img.height() {
            for col in 0..img.width() {
                let v = img.get(col, row)[0];
                if v > best {
                    best = v;
                    bd = pixel_to_dir(col, row, img.width(), img.height());
                }
            }
        }
        assert!(bd.angle_between(east).to_degrees() < 12.0, "{bd}");
        // Blend at 1/4 of the way: weights 3/4 and 1/4, and the turned marker of
        // the second probe lands in the same direction.
        let (_, rep) = set
            .query(Vec3::new(0.5, 0.0, 1.5), Blend::InverseDistance2, None)
            .unwrap();
        assert_eq!(rep.used.len(), 2);
        assert!((rep.used[0].1 - 0.75).abs() < 1e-4, "{:?}", rep.used);
        assert!((rep.used[1].1 - 0.25).abs() < 1e-4);
        // Exactly at a probe: that probe alone.
        let w = set
            .weights(Vec3::new(2.0, 0.0, 1.5), Blend::InverseDistance2)
            .unwrap();
        assert_eq!(w, vec![(1, 1.0)]);
        assert!(set
            .weights(Vec3::new(f32::NAN, 0.0, 0.0), Blend::Nearest)
            .is_err());
    }

    #[test]
    fn an_empty_run_folder_is_an_error_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        marker_scene(dir.path());
        let run = dir.path().join("run");
        std::fs::create_dir_all(&run).unwrap();
        let e = ProbeSet::open(dir.path(), Some(&run)).unwrap_err();
        assert!(e.to_string().contains("run"), "{e}");
    }
}
