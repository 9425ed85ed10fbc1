//! From a [`Manifest`] to a [`Scene`], doing only what the manifest leaves open:
//! frames extracted from a video when the walk is a video, the camera response
//! recovered when it is not given, probes merged when only brackets are given,
//! the frames' gain calibrated when it is `auto`. Each product is cached under
//! `<output>/cache/` with a key made of its inputs (file sizes and times) and
//! settings, so a rerun recomputes only what changed; [`Plan`] says, stage by
//! stage, what was given, taken from the cache or computed (with `dry_run`: would
//! be computed).

use crate::capture::calibrate::{calibrate_gain, CalibrateOptions};
use crate::capture::cli::load_exposures;
use crate::capture::exif::{read_exposure, ExifExposure};
use crate::capture::localize::{localize, LocalizeOptions, Panorama, PoseSource};
use crate::capture::merge::{absolute_scale, AbsoluteScale};
use crate::capture::{merge, recover, MergeOptions, RecoverOptions, ResponseCurve};
use crate::error::{Error, Result};
use crate::image::io;
use crate::scene::manifest::{FrameLayout, FrameSource, GainChoice, Manifest, ResponseChoice};
use crate::scene::{Frame, Pose, Probe, Scene};
use std::path::{Path, PathBuf};

/// What happened to one stage.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StageState {
    /// The manifest gave the result; nothing to do.
    Given,
    /// Taken from the cache: its inputs have not changed.
    Cached,
    /// Computed now (or, in a dry run, would be).
    Computed,
}

/// One stage of the plan.
#[derive(Clone, Debug, PartialEq)]
pub struct Stage {
    /// Stage name, e.g. `merge probe_00`.
    pub name: String,
    /// What it did or would do.
    pub state: StageState,
    /// Details for the user (where from, figures).
    pub detail: String,
}

/// The stages of preparing a manifest's scene.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Plan {
    /// In order.
    pub stages: Vec<Stage>,
    /// Every entry of `<output>/cache/` the plan reads or writes (whether it
    /// exists yet or not): what `lumiprobe cache gc` keeps.
    pub live: Vec<PathBuf>,
}

impl Plan {
    fn push(&mut self, name: impl Into<String>, state: StageState, detail: impl Into<String>) {
        self.stages.push(Stage {
            name: name.into(),
            state,
            detail: detail.into(),
        });
    }

    /// One line per stage.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        for st in &self.stages {
            let what = match st.state {
                StageState::Given => "given",
                StageState::Cached => "cached",
                StageState::Computed => "compute",
            };
            s += &format!("{:<8} {:<28} {}\n", what, st.name, st.detail);
        }
        s
    }
}

/// The file stem of a frame image: its id.
fn stem(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Frames of a video, extracted with ffmpeg into `dir` (complete when `dir/.done`
/// exists, so an interrupted extraction is redone).
fn extract_video(file: &Path, fps: f64, dir: &Path) -> Result<Vec<PathBuf>> {
    if !dir.join(".done").exists() {
        if !crate::fsutil::have_program("ffmpeg") {
            return Err(Error::External {
                tool: "ffmpeg",
                msg: format!(
                    "not found; {} is a video, and extracting its frames needs it (apt-get install ffmpeg)",
                    file.display()
                ),
            });
        }
        if dir.exists() {
            std::fs::remove_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        }
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        // `showinfo` prints each frame it passes, with its time in the video,
        // on stderr (at the "info" level, which `-v error` would hide, so the
        // level stays and errors are told apart by the exit status).
        let run = std::process::Command::new("ffmpeg")
            .args(["-hide_banner", "-nostats", "-nostdin", "-i"])
            .arg(file)
            .args(["-vf", &format!("fps={fps},showinfo"), "-q:v", "2"])
            .arg(dir.join("frame_%05d.jpg"))
            .output()
            .map_err(|e| Error::io(file, e))?;
        let log = String::from_utf8_lossy(&run.stderr);
        if !run.status.success() {
            let last = log
                .lines()
                .rev()
                .find(|l| !l.trim().is_empty())
                .unwrap_or("");
            return Err(Error::format(
                file,
                format!("ffmpeg could not read it ({}): {last}", run.status),
            ));
        }
        let times: Vec<(String, f64)> = log
            .lines()
            .filter(|l| l.contains("Parsed_showinfo") && l.contains(" n:"))
            .filter_map(|l| {
                let n: usize = l
                    .split(" n:")
                    .nth(1)?
                    .split_whitespace()
                    .next()?
                    .parse()
                    .ok()?;
                let t: f64 = l
                    .split("pts_time:")
                    .nth(1)?
                    .split_whitespace()
                    .next()?
                    .parse()
                    .ok()?;
                Some((format!("frame_{:05}", n + 1), t))
            })
            .collect();
        let json =
            serde_json::to_string_pretty(&times).map_err(|e| Error::Invalid(e.to_string()))?;
        crate::fsutil::write_atomic(&dir.join(TIMES_FILE), json.as_bytes())?;
        crate::fsutil::write_atomic(&dir.join(".done"), b"")?;
    }
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "jpg"))
        .collect();
    v.sort();
    Ok(v)
}

/// The file, in a video's extraction folder, that lists each extracted frame's
/// time in the video.
pub const TIMES_FILE: &str = "times.json";

/// The first and last frame times (seconds) of an extraction folder, when it
/// has its [`TIMES_FILE`].
fn video_times(dir: &Path) -> Result<Option<(f64, f64)>> {
    let f = dir.join(TIMES_FILE);
    if !f.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&f).map_err(|e| Error::io(&f, e))?;
    let v: Vec<(String, f64)> =
        serde_json::from_str(&text).map_err(|e| Error::format(&f, e.to_string()))?;
    Ok(v.first().zip(v.last()).map(|(a, b)| (a.1, b.1)))
}

/// Dual-fisheye frames stitched to equirect PNGs (lossless, same stems) in `dir`
/// (complete when `dir/.done` exists, so an interrupted run redoes it), at the
/// input's width and half of it in height.
fn stitch_frames(files: &[PathBuf], fov_deg: f32, dir: &Path) -> Result<Vec<PathBuf>> {
    use crate::capture::fisheye::{dual_fisheye_to_equirect, DualFisheye};
    use rayon::prelude::*;
    let out: Vec<PathBuf> = files
        .iter()
        .map(|f| dir.join(format!("{}.png", stem(f))))
        .collect();
    if dir.join(".done").exists() {
        return Ok(out);
    }
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let cfg = DualFisheye::new(fov_deg);
    files
        .par_iter()
        .zip(&out)
        .try_for_each(|(src, dst)| -> Result<()> {
            let img = crate::image::io::read_sdr(src)?;
            let w = img.width();
            let layout = |m: String| {
                Error::Invalid(format!(
                    "{}: as a dual-fisheye frame (frames.layout): {m}",
                    src.display()
                ))
            };
            // A frame that fills the corners outside both lens circles is not
            // two fisheye circles (most often an equirect frame): stitching it
            // would make a panorama of nonsense.
            let filled = crate::capture::fisheye::content_outside_circles(&img, &cfg).map_err(
                |e| match e {
                    Error::Invalid(m) => layout(m),
                    other => other,
                },
            )?;
            if let Some(share) = filled.filter(|&s| s > 0.5) {
                return Err(layout(format!(
                    "{:.0}% of the pixels outside both lens circles hold image content, \
                     where a two-lens camera leaves them black; if the frames are already \
                     equirectangular, set frames.layout = \"equirect\" (circles wider than \
                     the image is high are not supported)",
                    100.0 * share
                )));
            }
            let eq =
                dual_fisheye_to_equirect(&img, &cfg, w, (w / 2).max(1)).map_err(|e| match e {
                    Error::Invalid(m) => layout(m),
                    other => other,
                })?;
            let tmp = dst.with_extension("tmp.png");
            crate::image::io::write_sdr(&tmp, &eq)?;
            std::fs::rename(&tmp, dst).map_err(|e| Error::io(dst, e))
        })?;
    crate::fsutil::write_atomic(&dir.join(".done"), b"")?;
    Ok(out)
}

/// The 8-bit image of a probe that localization cuts views from: its bracket
/// whose mean code is nearest mid-grey, else its HDR tone-mapped.
fn probe_view_image(
    p: &crate::scene::manifest::ProbeSource,
    hdr: Option<&Path>,
) -> Result<crate::image::SdrImage> {
    let files: Vec<&Path> = p.brackets.iter().map(|b| b.as_path()).collect();
    if let Some(img) = crate::capture::localize::mid_grey_bracket(&files)? {
        return Ok(img);
    }
    let path = hdr.ok_or_else(|| Error::Invalid(format!("probe {} has no image", p.id)))?;
    let img = io::read_hdr(path)?;
    let disp = crate::tonemap::reinhard_global(&img, 0.18, None, None);
    crate::image::SdrImage::from_vec(img.width(), img.height(), crate::tonemap::quantize(&disp))
}

/// Poses saved by the localization stage.
fn read_localized(file: &Path) -> Result<(Vec<(String, Pose)>, Vec<(String, Pose)>)> {
    let text = std::fs::read_to_string(file).map_err(|e| Error::io(file, e))?;
    let list: Vec<serde_json::Value> =
        serde_json::from_str(&text).map_err(|e| Error::format(file, e.to_string()))?;
    let (mut probes, mut frames) = (Vec::new(), Vec::new());
    for v in list {
        let id = v["id"].as_str().unwrap_or_default().to_string();
        let nums = |k: &str| -> Vec<f32> {
            v[k].as_array()
                .map(|a| {
                    a.iter()
                        .filter_map(|x| x.as_f64())
                        .map(|x| x as f32)
                        .collect()
                })
                .unwrap_or_default()
        };
        let (p, m) = (nums("position"), nums("world_from_camera"));
        if p.len() != 3 || m.len() != 9 {
            return Err(Error::format(file, format!("bad pose for {id}")));
        }
        let pose = Pose {
            position: glam::Vec3::new(p[0], p[1], p[2]),
            world_from_camera: glam::Mat3::from_cols_slice(&m),
        };
        if v["probe"].as_bool().unwrap_or(false) {
            probes.push((id, pose));
        } else {
            frames.push((id, pose));
        }
    }
    Ok((probes, frames))
}

/// A calibrated gain as the cache keeps it.
#[derive(serde::Serialize, serde::Deserialize)]
struct CachedGain {
    gain: f32,
    frames_used: usize,
    log_iqr: f32,
}

/// What a gain calibration of `scene` reads, for its cache key: the probes'
/// files and poses, the frames' files and poses.
fn gain_inputs(scene: &Scene) -> Vec<String> {
    let mut parts: Vec<String> = Vec::new();
    for p in &scene.probes {
        parts.extend(p.hdr.iter().map(|h| super::file_stamp(h)));
        parts.push(format!("{:?}", p.pose));
    }
    for f in &scene.frames {
        parts.push(super::file_stamp(&f.sdr));
        parts.push(format!("{:?}", f.pose));
    }
    parts
}

/// Merged probes are in the response's own relative unit; a given gain defines
/// the frames' (radiance = response⁻¹(code / 255) / `gain`). The probes merged
/// from brackets are scaled into the frames' unit: by the gain calibration
/// against them would find, over the given one (cached, like the gain). Their
/// scaled copies replace them in `scene`.
fn tie_probes_to_frames(
    scene: &mut Scene,
    m: &Manifest,
    gain: f32,
    curve_id: &str,
    cache: &Path,
    plan: &mut Plan,
) -> Result<()> {
    let merged: Vec<usize> = scene
        .probes
        .iter()
        .enumerate()
        .filter(|(_, p)| {
            m.probes
                .iter()
                .any(|q| q.id == p.id && q.hdr.is_none() && !q.brackets.is_empty())
        })
        .map(|(k, _)| k)
        .collect();
    let mut parts = gain_inputs(scene);
    let opts = CalibrateOptions::default();
    parts.push(format!("{curve_id} {opts:?} tie {gain}"));
    let key = super::fingerprint(&parts);
    let file = cache.join(format!("tie-{key}.json"));
    plan.live.push(file.clone());
    let relative = match read_gain(&file) {
        Some(g) => g.gain,
        None => {
            let mut rel = scene.clone();
            rel.path_gain = 1.0;
            let est = calibrate_gain(&rel, &opts)?;
            let g = CachedGain {
                gain: est.gain,
                frames_used: est.frames_used,
                log_iqr: est.log_iqr,
            };
            let text = crate::error::to_json(&g)?.into_bytes();
            std::fs::create_dir_all(cache).map_err(|e| Error::io(cache, e))?;
            crate::fsutil::write_atomic(&file, &text)?;
            est.gain
        }
    };
    let factor = relative / gain;
    for k in merged {
        let Some(src) = scene.probes[k].hdr.clone() else {
            continue;
        };
        let stem = src
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let out = cache.join("probes").join(format!("{stem}-tied-{key}.exr"));
        plan.live.push(out.clone());
        if !out.exists() {
            let mut img = io::read_hdr(&src)?;
            img.data_mut().iter_mut().for_each(|v| *v *= factor);
            io::write_hdr(&out, &img)?;
        }
        scene.probes[k].hdr = Some(out);
    }
    plan.push(
        "probes in the frames' unit",
        StageState::Computed,
        format!(
            "merged radiance x {factor:.5} (calibrated gain {relative:.5} over the given {gain})"
        ),
    );
    Ok(())
}

/// The cached gain in `file`, if it is there and sound (a damaged entry is
/// computed again).
fn read_gain(file: &Path) -> Option<CachedGain> {
    let text = crate::fsutil::read_to_string_limited(file, 1 << 16).ok()?;
    let g: CachedGain = serde_json::from_str(&text).ok()?;
    (g.gain.is_finite() && g.gain > 0.0).then_some(g)
}

/// What [`cache_gc`] found in a manifest's cache.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GcReport {
    /// Entries no longer used (removed unless it was a dry run).
    pub stale: Vec<PathBuf>,
    /// Their size in bytes.
    pub bytes: u64,
    /// Entries still used.
    pub kept: usize,
}

/// Bytes of a file, or of everything under a folder.
fn size_of(p: &Path) -> u64 {
    match std::fs::symlink_metadata(p) {
        Ok(m) if m.is_dir() => std::fs::read_dir(p)
            .map(|rd| rd.flatten().map(|e| size_of(&e.path())).sum())
            .unwrap_or(0),
        Ok(m) => m.len(),
        Err(_) => 0,
    }
}

/// Removes (unless `dry_run`) every entry of the manifest's cache
/// (`<output>/cache/` and its `probes/`) that the manifest's plan no longer
/// uses: products of inputs or settings that have changed since, and temporary
/// files of interrupted writes.
pub fn cache_gc(m: &Manifest, dry_run: bool) -> Result<GcReport> {
    let (_, plan) = prepare(m, true)?;
    let cache = m.output.folder.join("cache");
    let mut rep = GcReport::default();
    if !cache.is_dir() {
        return Ok(rep);
    }
    let live: std::collections::HashSet<&Path> = plan.live.iter().map(|p| p.as_path()).collect();
    let list = |dir: &Path| -> Result<Vec<PathBuf>> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(|e| Error::io(dir, e))?
            .flatten()
            .map(|e| e.path())
            .collect();
        v.sort();
        Ok(v)
    };
    let probes = cache.join("probes");
    let mut entries = list(&cache)?;
    if probes.is_dir() {
        entries.retain(|p| *p != probes);
        entries.extend(list(&probes)?);
    }
    for e in entries {
        if live.contains(e.as_path()) {
            rep.kept += 1;
            continue;
        }
        rep.bytes += size_of(&e);
        if !dry_run {
            let r = if e.is_dir() {
                std::fs::remove_dir_all(&e)
            } else {
                std::fs::remove_file(&e)
            };
            r.map_err(|err| Error::io(&e, err))?;
        }
        rep.stale.push(e);
    }
    Ok(rep)
}

/// The scene a command names: a manifest (`.toml`, prepared as `run` prepares
/// it: merges, response, poses and gain from its cache, computed when missing),
/// a scene folder or a poses file. With `plan`, the manifest's plan is written
/// to standard error.
pub fn load_scene(path: &Path, plan: bool) -> Result<Scene> {
    if path.extension().is_some_and(|e| e == "toml") {
        let m = Manifest::load(path)?;
        let (scene, p) = prepare(&m, false)?;
        if plan {
            eprint!("{}", p.to_text());
        }
        scene.ok_or_else(|| Error::format(path, "the scene could not be prepared"))
    } else {
        Scene::load(path)
    }
}

/// Prepares the manifest's scene (see the module docs). With `dry_run` nothing is
/// computed or written and no scene is returned, only the plan.
pub fn prepare(m: &Manifest, dry_run: bool) -> Result<(Option<Scene>, Plan)> {
    let mut plan = Plan::default();
    // A dataset-layout poses file also lists each bracket's exposure time, used
    // when the manifest gives none and a file carries no Exif.
    let poses_scene = match &m.poses {
        Some(f) => Some(Scene::load(f)?),
        None => None,
    };
    let times_for = |p: &crate::scene::manifest::ProbeSource| -> Option<Vec<f64>> {
        if p.times.is_some() {
            return p.times.clone();
        }
        let known = poses_scene.as_ref()?.probes.iter().find(|q| q.id == p.id)?;
        let same = |a: &Path, b: &Path| match (a.canonicalize(), b.canonicalize()) {
            (Ok(x), Ok(y)) => x == y,
            _ => a == b,
        };
        p.brackets
            .iter()
            .map(|b| {
                known
                    .brackets
                    .iter()
                    .chain(&known.brackets_wide)
                    .find(|k| same(&k.file, b))
                    .and_then(|k| k.exposure_time_s.map(f64::from))
            })
            .collect()
    };
    let exposures = |p: &crate::scene::manifest::ProbeSource| {
        let exif = load_exposures(&p.brackets, p.times.as_deref());
        match (exif, times_for(p)) {
            (Ok(e), _) => Ok(e),
            (Err(_), Some(t)) if p.times.is_none() => load_exposures(&p.brackets, Some(&t)),
            (Err(e), _) => Err(e),
        }
    };
    let cache = m.output.folder.join("cache");
    // Frames.
    let frame_files: Vec<PathBuf> = match &m.frames {
        FrameSource::Images(v) => {
            plan.push("frames", StageState::Given, format!("{} images", v.len()));
            v.clone()
        }
        FrameSource::Video { file, fps } => {
            let dir = cache.join(format!(
                "frames-{}",
                super::fingerprint(&[super::file_stamp(file), fps.to_string()])
            ));
            plan.live.push(dir.clone());
            let cached = dir.join(".done").exists();
            let state = if cached {
                StageState::Cached
            } else {
                StageState::Computed
            };
            plan.push(
                "extract frames",
                state,
                format!("{} at {fps} fps (ffmpeg)", file.display()),
            );
            if dry_run && !cached {
                Vec::new()
            } else {
                let v = extract_video(file, *fps, &dir)?;
                if let Some((first, last)) = video_times(&dir)? {
                    plan.push(
                        "frame times",
                        StageState::Given,
                        format!(
                            "{} frames from {first:.3} s to {last:.3} s of the video ({})",
                            v.len(),
                            dir.join(TIMES_FILE).display()
                        ),
                    );
                }
                v
            }
        }
    };
    let frame_files = match m.frame_layout {
        FrameLayout::Equirect => frame_files,
        FrameLayout::DualFisheye { fov_deg } => {
            let mut parts: Vec<String> = frame_files.iter().map(|f| super::file_stamp(f)).collect();
            parts.push(format!("dual-fisheye {fov_deg}"));
            let dir = cache.join(format!("frames-equirect-{}", super::fingerprint(&parts)));
            plan.live.push(dir.clone());
            let cached = dir.join(".done").exists();
            plan.push(
                "stitch frames",
                if cached {
                    StageState::Cached
                } else {
                    StageState::Computed
                },
                format!(
                    "{} dual-fisheye frames to equirect, lenses of {fov_deg} degrees",
                    frame_files.len()
                ),
            );
            if dry_run && !cached {
                Vec::new()
            } else {
                stitch_frames(&frame_files, fov_deg, &dir)?
            }
        }
    };
    // Response.
    let bracketed: Vec<&crate::scene::manifest::ProbeSource> =
        m.probes.iter().filter(|p| !p.brackets.is_empty()).collect();
    // What identifies the response in the probes' cache keys (not the curve's
    // values, which a save/load round trip may perturb in the last digit).
    let curve_id: String;
    let curve: Option<ResponseCurve> = match &m.response {
        ResponseChoice::Known(r) => {
            curve_id = format!("{r:?}");
            plan.push("response", StageState::Given, format!("{r:?}"));
            Some(ResponseCurve::from_response(r))
        }
        ResponseChoice::File(f) => {
            curve_id = super::file_stamp(f);
            plan.push("response", StageState::Given, f.display().to_string());
            Some(ResponseCurve::load(f)?)
        }
        ResponseChoice::Recover => {
            // The probe with the most brackets carries the most information.
            let src = bracketed
                .iter()
                .max_by_key(|p| p.brackets.len())
                .ok_or_else(|| {
                    Error::format(
                        &m.file,
                        "camera.response is \"recover\" but no probe has brackets: give the response",
                    )
                })?;
            let opts = RecoverOptions::default();
            let mut parts: Vec<String> =
                src.brackets.iter().map(|b| super::file_stamp(b)).collect();
            parts.push(format!(
                "{:?} {:?} {}",
                src.times, opts.lambda, opts.samples
            ));
            curve_id = super::fingerprint(&parts);
            let file = cache.join(format!("response-{curve_id}.json"));
            plan.live.push(file.clone());
            if file.exists() {
                plan.push(
                    "recover response",
                    StageState::Cached,
                    file.display().to_string(),
                );
                Some(ResponseCurve::load(&file)?)
            } else if dry_run {
                plan.push(
                    "recover response",
                    StageState::Computed,
                    format!("from {}'s {} brackets", src.id, src.brackets.len()),
                );
                None
            } else {
                let exps = exposures(src)?;
                let images: Vec<&crate::image::SdrImage> = exps.iter().map(|e| &e.image).collect();
                let times: Vec<f64> = exps.iter().map(|e| e.time_s).collect();
                let rec = recover(&images, &times, &opts)?;
                std::fs::create_dir_all(&cache).map_err(|e| Error::io(&cache, e))?;
                rec.curve.save(&file)?;
                plan.push(
                    "recover response",
                    StageState::Computed,
                    format!(
                        "from {}'s {} brackets, RMS residual {:.3} ln",
                        src.id,
                        src.brackets.len(),
                        rec.rms_residual.iter().fold(0.0f64, |a, v| a.max(*v))
                    ),
                );
                Some(rec.curve)
            }
        }
    };
    // The probes' unit: luminance in cd/m² from the brackets' Exif (f-number,
    // ISO, time) when every probe is merged from brackets that carry them and
    // the gain is left to calibration; a given gain defines the frames' unit,
    // which the merged probes then take (below).
    let absolute = match m.gain {
        GainChoice::Auto if m.probes.iter().all(|p| p.hdr.is_none()) => {
            let scales: Vec<Option<AbsoluteScale>> = m
                .probes
                .iter()
                .map(|p| {
                    let exif: Option<Vec<ExifExposure>> =
                        p.brackets.iter().map(|b| read_exposure(b).ok()).collect();
                    absolute_scale(&exif?, curve.as_ref())
                })
                .collect();
            match scales.first() {
                Some(Some(a)) if scales.iter().all(|s| *s == Some(*a)) => Some(*a),
                _ => None,
            }
        }
        _ => None,
    };
    let probe_unit = match (absolute, m.gain) {
        (Some(a), _) => format!(
            "cd/m² from the brackets' Exif (f/{}, ISO {}; ISO 12232 saturation speed, lens factor 0.65)",
            a.f_number, a.iso
        ),
        (None, GainChoice::Value(g)) if !bracketed.is_empty() => {
            format!("the frames' unit (radiance = response⁻¹(code / 255) / {g})")
        }
        (None, _) if bracketed.is_empty() => "as given (HDR files)".to_string(),
        (None, _) => {
            "relative (brackets without Exif FNumber and ISO, or HDR files among the probes)"
                .to_string()
        }
    };
    plan.push("probe unit", StageState::Given, probe_unit.clone());
    // Probes.
    let mut probe_files: Vec<(String, Option<PathBuf>)> = Vec::new();
    for p in &m.probes {
        if let Some(h) = &p.hdr {
            plan.push(
                format!("probe {}", p.id),
                StageState::Given,
                h.display().to_string(),
            );
            probe_files.push((p.id.clone(), Some(h.clone())));
            continue;
        }
        let mut parts: Vec<String> = p.brackets.iter().map(|b| super::file_stamp(b)).collect();
        parts.push(format!("{:?} {curve_id}", p.times));
        if let Some(f) = absolute.and_then(|a| a.factor) {
            parts.push(format!("absolute {f}"));
        }
        let file =
            cache
                .join("probes")
                .join(format!("{}-{}.exr", p.id, super::fingerprint(&parts)));
        plan.live.push(file.clone());
        if file.exists() {
            plan.push(
                format!("merge {}", p.id),
                StageState::Cached,
                file.display().to_string(),
            );
            probe_files.push((p.id.clone(), Some(file)));
        } else if dry_run || curve.is_none() {
            plan.push(
                format!("merge {}", p.id),
                StageState::Computed,
                format!("{} brackets", p.brackets.len()),
            );
            probe_files.push((p.id.clone(), None));
        } else {
            let exps = exposures(p)?;
            let mut merged = merge(
                &exps,
                curve.as_ref().expect("checked"),
                &MergeOptions::default(),
            )?;
            if let Some(f) = absolute.and_then(|a| a.factor) {
                let f = f as f32;
                merged.image.data_mut().iter_mut().for_each(|v| *v *= f);
            }
            io::write_hdr(&file, &merged.image)?;
            plan.push(
                format!("merge {}", p.id),
                StageState::Computed,
                format!(
                    "{} brackets; clipped in the darkest: {:.3}% of the sphere",
                    p.brackets.len(),
                    100.0 * merged.report.clipped_fraction
                ),
            );
            probe_files.push((p.id.clone(), Some(file)));
        }
    }
    // Poses.
    let (probe_poses, frame_poses): (Vec<(String, Pose)>, Vec<(String, Pose)>) = match (
        &m.poses,
        &poses_scene,
    ) {
        (Some(poses_file), Some(known)) => {
            plan.push("poses", StageState::Given, poses_file.display().to_string());
            (
                known
                    .probes
                    .iter()
                    .map(|p| (p.id.clone(), p.pose))
                    .collect(),
                known
                    .frames
                    .iter()
                    .map(|f| (f.id.clone(), f.pose))
                    .collect(),
            )
        }
        _ => {
            let mut parts: Vec<String> = frame_files.iter().map(|f| super::file_stamp(f)).collect();
            for p in &m.probes {
                parts.extend(p.brackets.iter().map(|b| super::file_stamp(b)));
                parts.extend(p.hdr.iter().map(|h| super::file_stamp(h)));
            }
            let opts = LocalizeOptions::default();
            parts.push(format!(
                "{:?}",
                (
                    opts.views,
                    opts.view_size,
                    opts.fov_deg,
                    opts.max_features,
                    opts.frame_window,
                    opts.probe_stride
                )
            ));
            let work = cache.join(format!("localize-{}", super::fingerprint(&parts)));
            plan.live.push(work.clone());
            let done = work.join("poses.json");
            if done.exists() {
                plan.push("localize", StageState::Cached, done.display().to_string());
            } else if dry_run || frame_files.is_empty() {
                plan.push(
                    "localize",
                    StageState::Computed,
                    "COLMAP on pinhole views of every panorama",
                );
                plan.push(
                    "frames",
                    StageState::Computed,
                    if frame_files.is_empty() {
                        "every frame (once extracted and localized)".to_string()
                    } else {
                        format!("all {} (once localized)", frame_files.len())
                    },
                );
                return Ok((None, plan));
            } else {
                let mut panos = Vec::new();
                for (p, (_, file)) in m.probes.iter().zip(&probe_files) {
                    panos.push(Panorama {
                        id: p.id.clone(),
                        is_probe: true,
                        image: probe_view_image(p, file.as_deref())?,
                    });
                }
                for f in &frame_files {
                    panos.push(Panorama {
                        id: stem(f),
                        is_probe: false,
                        image: io::read_sdr(f)?,
                    });
                }
                let t0 = std::time::Instant::now();
                let loc = localize(&panos, &work, &opts)?;
                let list: Vec<serde_json::Value> = loc
                    .iter()
                    .filter_map(|l| {
                        let p = l.pose?;
                        Some(serde_json::json!({
                            "id": l.id, "probe": l.is_probe, "source": l.source,
                            "position": p.position.to_array(),
                            "world_from_camera": p.world_from_camera.to_cols_array(),
                        }))
                    })
                    .collect();
                let text = crate::error::to_json(&list)?.into_bytes();
                crate::fsutil::write_atomic(&done, &text)?;
                let missing: Vec<&str> = loc
                    .iter()
                    .filter(|l| l.pose.is_none())
                    .map(|l| l.id.as_str())
                    .collect();
                let interp = loc
                    .iter()
                    .filter(|l| l.source == PoseSource::Interpolated)
                    .count();
                plan.push(
                        "localize",
                        StageState::Computed,
                        format!(
                            "COLMAP: {} of {} panoramas registered, {interp} interpolated, missing: [{}]; {:.0} s",
                            loc.len() - missing.len() - interp,
                            loc.len(),
                            missing.join(" "),
                            t0.elapsed().as_secs_f64()
                        ),
                    );
            }
            read_localized(&done)?
        }
    };
    let find = |list: &[(String, Pose)], id: &str| list.iter().find(|(i, _)| i == id).map(|x| x.1);
    let mut missing = Vec::new();
    let mut probes = Vec::new();
    for (id, file) in &probe_files {
        match find(&probe_poses, id) {
            Some(pose) => probes.push(Probe {
                id: id.clone(),
                pose,
                hdr: file.clone(),
                brackets: Vec::new(),
                brackets_wide: Vec::new(),
            }),
            None => missing.push(format!("probe {id}")),
        }
    }
    let mut frames = Vec::new();
    for f in &frame_files {
        let id = stem(f);
        match find(&frame_poses, &id) {
            Some(pose) => frames.push(Frame {
                id,
                pose,
                sdr: f.clone(),
                ground_truth: None,
                gain: None,
            }),
            None => missing.push(format!("frame {id}")),
        }
    }
    if !missing.is_empty() {
        match &m.poses {
            Some(poses_file) => {
                return Err(Error::format(
                    poses_file,
                    format!("no pose for {}", missing.join(", ")),
                ))
            }
            None => plan.push(
                "left out",
                StageState::Computed,
                format!("not localized: {}", missing.join(", ")),
            ),
        }
    }
    if probes.is_empty() {
        return Err(Error::format(&m.file, "no probe could be localized"));
    }
    if dry_run && probes.iter().any(|p| p.hdr.is_none()) {
        if m.gain == GainChoice::Auto {
            plan.push("calibrate gain", StageState::Computed, "against the probes");
        }
        plan.push(
            "frames",
            StageState::Computed,
            format!("all {} (once the probes are merged)", frames.len()),
        );
        return Ok((None, plan));
    }
    let response = curve.as_ref().map(|c| c.to_table(1)).unwrap_or_default();
    let mut scene = Scene {
        root: m.root.clone(),
        name: m.name.clone(),
        probes,
        frames,
        response,
        path_gain: 1.0,
        probe_unit,
        warnings: m
            .probes
            .iter()
            .filter(|p| p.brackets.len() == 1)
            .map(|p| {
                format!(
                    "probe {}: one exposure ({}) cannot extend the range; its clipped \
                     pixels stay at the white point (a lower bound): shoot a bracket",
                    p.id,
                    p.brackets[0].display()
                )
            })
            .collect(),
        vignetting: None,
    };
    match m.gain {
        GainChoice::Value(g) => {
            scene.path_gain = g;
            plan.push("gain", StageState::Given, format!("{g}"));
            if !bracketed.is_empty() {
                if m.response == ResponseChoice::Recover {
                    scene.warnings.push(format!(
                        "{}: camera.gain = {g} with a recovered response: a recovered curve's \
                         scale is its own (exposure 1 at code 128), not the camera's, so the \
                         gain does not give the frames' unit; give the camera's documented \
                         response with its gain, or gain = \"auto\" for luminance from Exif",
                        m.file.display()
                    ));
                }
                tie_probes_to_frames(&mut scene, m, g, &curve_id, &cache, &mut plan)?;
            }
        }
        GainChoice::Auto => {
            // Keyed by what the estimate reads: the frames, the probes, the
            // poses and the response.
            let mut parts = gain_inputs(&scene);
            let opts = CalibrateOptions::default();
            parts.push(format!("{curve_id} {opts:?}"));
            let file = cache.join(format!("gain-{}.json", super::fingerprint(&parts)));
            plan.live.push(file.clone());
            match read_gain(&file) {
                Some(g) => {
                    scene.path_gain = g.gain;
                    plan.push(
                        "calibrate gain",
                        StageState::Cached,
                        format!("{:.5} ({})", g.gain, file.display()),
                    );
                }
                None => {
                    // Cheap and read-only: done in a dry run too (not saved),
                    // so the frames' state (which depends on the gain) can be
                    // reported.
                    let est = calibrate_gain(&scene, &opts)?;
                    scene.path_gain = est.gain;
                    if !dry_run {
                        let g = CachedGain {
                            gain: est.gain,
                            frames_used: est.frames_used,
                            log_iqr: est.log_iqr,
                        };
                        let text = crate::error::to_json(&g)?.into_bytes();
                        crate::fsutil::write_atomic(&file, &text)?;
                    }
                    plan.push(
                        "calibrate gain",
                        StageState::Computed,
                        format!(
                            "{:.5} from {} frames (log IQR {:.3})",
                            est.gain, est.frames_used, est.log_iqr
                        ),
                    );
                }
            }
        }
    }
    Ok((Some(scene), plan))
}
