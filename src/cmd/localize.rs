//! `lumiprobe localize`: frame poses from COLMAP.

use super::args::*;
use lumiprobe::image::io;
use lumiprobe::{Error, Result};
use std::path::{Path, PathBuf};

/// Arguments of `lumiprobe localize`.
#[derive(clap::Args)]
pub struct LocalizeArgs {
    /// Scene folder (with poses.json) or the poses.json itself.
    pub scene: PathBuf,
    /// Working folder (views, COLMAP database, model, logs).
    #[arg(long)]
    pub work: PathBuf,
    /// Write the recovered poses here (dataset layout, COLMAP's frame of reference).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Pinhole views per panorama.
    #[arg(long, default_value_t = lumiprobe::capture::localize::LocalizeOptions::default().views)]
    pub views: usize,
    /// View size in pixels.
    #[arg(long, default_value_t = lumiprobe::capture::localize::LocalizeOptions::default().view_size)]
    pub view_size: usize,
    /// Field of view of each view, degrees.
    #[arg(long, value_parser = parse_finite, default_value_t = lumiprobe::capture::localize::LocalizeOptions::default().fov_deg)]
    pub fov: f32,
    /// Read the COLMAP model already in WORK instead of running COLMAP.
    #[arg(long)]
    pub reuse: bool,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: LocalizeArgs, quiet: bool) -> Result<()> {
    let LocalizeArgs {
        scene,
        work,
        out,
        views,
        view_size,
        fov,
        reuse,
    } = a;
    use lumiprobe::capture::localize::{localize, pose_errors, LocalizeOptions, Panorama};
    let scene = lumiprobe::pipeline::plan::load_scene(&scene, !quiet)?;
    let opts = LocalizeOptions {
        views,
        view_size,
        fov_deg: fov,
        reuse_model: reuse,
        ..Default::default()
    };
    let t0 = std::time::Instant::now();
    let mut panos = Vec::new();
    for p in &scene.probes {
        // The bracket nearest mid-grey, else the HDR through the frames' camera.
        let files: Vec<&Path> = p.brackets.iter().map(|b| b.file.as_path()).collect();
        let image = match lumiprobe::capture::localize::mid_grey_bracket(&files)? {
            Some(img) => img,
            None => {
                let (hdr, _) = lumiprobe::pipeline::load_probe(
                    &scene,
                    scene.probes.iter().position(|q| q.id == p.id).unwrap_or(0),
                    None,
                )?;
                io::linear_to_sdr(&hdr, &scene.response, scene.path_gain)
            }
        };
        panos.push(Panorama {
            id: p.id.clone(),
            is_probe: true,
            image,
        });
    }
    for f in &scene.frames {
        panos.push(Panorama {
            id: f.id.clone(),
            is_probe: false,
            image: io::read_sdr(&f.sdr)?,
        });
    }
    let loc = localize(&panos, &work, &opts)?;
    let secs = t0.elapsed().as_secs_f64();
    let reference: Vec<(String, lumiprobe::scene::Pose)> = scene
        .probes
        .iter()
        .map(|p| (p.id.clone(), p.pose))
        .chain(scene.frames.iter().map(|f| (f.id.clone(), f.pose)))
        .collect();
    for l in &loc {
        if l.source != lumiprobe::capture::localize::PoseSource::Registered {
            println!(
                "{}: {:?} ({} views registered)",
                l.id, l.source, l.views_registered
            );
        }
    }
    match pose_errors(&loc, &reference) {
        Some((e, _)) => println!(
            "{}: {} panoramas, {} registered, {} interpolated, {} missing; after a similarity alignment: position error median {:.3} m, max {:.3} m; after aligning orientations: rotation error median {:.2} deg, max {:.2} deg; relative rotation error between panoramas median {:.2} deg; {:.0} s",
            scene.name, loc.len(), e.registered, e.interpolated, e.missing,
            e.median_pos_m, e.max_pos_m, e.median_rot_deg, e.max_rot_deg, e.median_rel_rot_deg, secs
        ),
        None => println!("{}: too few registered panoramas to align ({:.0} s)", scene.name, secs),
    }
    if let Some(path) = out {
        let entry = |id: &str, pose: &lumiprobe::scene::Pose, extra: serde_json::Value| {
            let m = pose.world_from_camera;
            let rows: Vec<[f32; 3]> = (0..3)
                .map(|i| [m.x_axis[i], m.y_axis[i], m.z_axis[i]])
                .collect();
            let mut v = serde_json::json!({"id": id, "position": pose.position.to_array(), "world_from_camera": rows});
            if let (Some(o), Some(e)) = (v.as_object_mut(), extra.as_object()) {
                for (k, x) in e {
                    o.insert(k.clone(), x.clone());
                }
            }
            v
        };
        let mut probes = Vec::new();
        let mut frames = Vec::new();
        for l in &loc {
            let Some(pose) = &l.pose else { continue };
            if l.is_probe {
                let p = scene.probes.iter().find(|p| p.id == l.id).ok_or_else(|| {
                    Error::Invalid(format!(
                        "localization names {}, which the scene does not hold",
                        l.id
                    ))
                })?;
                probes.push(entry(
                    &l.id,
                    pose,
                    serde_json::json!({"hdr": p.hdr, "pose_source": l.source}),
                ));
            } else {
                let f = scene.frames.iter().find(|f| f.id == l.id).ok_or_else(|| {
                    Error::Invalid(format!(
                        "localization names {}, which the scene does not hold",
                        l.id
                    ))
                })?;
                frames.push(entry(
                    &l.id,
                    pose,
                    serde_json::json!({"sdr": f.sdr, "pose_source": l.source}),
                ));
            }
        }
        let js = serde_json::json!({"scene": scene.name, "probes": probes, "frames": frames,
            "camera": {"response": format!("{:?}", scene.response), "path_gain": scene.path_gain}});
        lumiprobe::fsutil::write_atomic(&path, lumiprobe::error::to_json(&js)?.as_bytes())?;
    }
    Ok(())
}
