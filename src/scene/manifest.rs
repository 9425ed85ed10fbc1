//! A scene manifest: the TOML file a user writes (or lets `lumiprobe init` draft)
//! to point lumiprobe at what the camera produced — probes as HDR files or as
//! exposure brackets, the walk as a folder of frames or a video, optional poses,
//! the camera's response and gain, and output settings. [`crate::pipeline::plan`]
//! turns it into a [`Scene`](super::Scene), doing only the stages the manifest
//! leaves open.
//!
//! ```toml
//! name = "kitchen"
//!
//! [camera]
//! response = "recover"     # or "documented", "srgb", "gamma 2.2", a formula, or a JSON curve file
//! gain = "auto"            # or a number: radiance = response⁻¹(code / 255) / gain
//!
//! [[probe]]
//! id = "probe_00"
//! brackets = "probes/probe_00/wide"   # a folder of bracket images (Exif times), or a list
//! # hdr = "probes/probe_00.exr"       # an HDR file instead of brackets
//! # times = [0.001, 0.004]            # exposure times, when the files carry no Exif
//!
//! [frames]
//! folder = "path"          # images, sorted by name; each frame's id is its file stem
//! pattern = "frame_*.jpg"  # optional: `*` matches any run of characters
//! # video = "walk.mp4"     # instead of folder: frames extracted with ffmpeg
//! # fps = 2.0
//! # layout = "dual-fisheye" # two lens circles side by side (Theta, Gear 360):
//! # fov = 195               # stitched to equirect (`lumiprobe fisheye`); default "equirect"
//!
//! [poses]
//! file = "poses.json"      # probes and frames by id (the dataset layout)
//!
//! [output]
//! folder = "out"
//! method = "fusion"
//! size = "512x256"
//! ```
//!
//! Relative paths are relative to the manifest's folder. Every error names the
//! manifest and the key at fault.

use crate::error::{Error, Result};
use crate::tonemap::Response;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// How the frames' camera response is known.
#[derive(Clone, Debug, PartialEq)]
pub enum ResponseChoice {
    /// Given as a curve or formula.
    Known(Response),
    /// Recovered from the probes' exposure brackets (Debevec & Malik).
    Recover,
    /// A response curve saved by `lumiprobe merge --save-response`.
    File(PathBuf),
}

/// How the frames' exposure gain is known.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GainChoice {
    /// Given.
    Value(f32),
    /// Recovered against the probes ([`crate::capture::calibrate`]).
    Auto,
}

/// One probe: an HDR file, or brackets to merge.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbeSource {
    /// Identifier, matched against the poses file.
    pub id: String,
    /// The merged HDR panorama, when given.
    pub hdr: Option<PathBuf>,
    /// Bracket images (sorted by name when given as a folder).
    pub brackets: Vec<PathBuf>,
    /// Exposure times overriding Exif, one per bracket.
    pub times: Option<Vec<f64>>,
}

/// Where the walk's frames come from.
#[derive(Clone, Debug, PartialEq)]
pub enum FrameSource {
    /// Image files, in walk order.
    Images(Vec<PathBuf>),
    /// A video, sampled at `fps` frames per second.
    Video {
        /// The video file.
        file: PathBuf,
        /// Frames per second to extract.
        fps: f64,
    },
}

/// How each frame's image maps to directions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FrameLayout {
    /// An equirectangular panorama (the default).
    Equirect,
    /// Two fisheye circles side by side (front lens left), as two-lens cameras
    /// record them; stitched to equirect before anything else reads them.
    DualFisheye {
        /// Each lens's field of view in degrees (at least 180).
        fov_deg: f32,
    },
}

/// Output settings.
#[derive(Clone, Debug, PartialEq)]
pub struct OutputSettings {
    /// Output folder (default `out` beside the manifest).
    pub folder: PathBuf,
    /// Method name (`warp`, `flow`, `hybrid`, `fusion`); default `fusion`.
    pub method: String,
    /// Working size, when given.
    pub size: Option<(usize, usize)>,
}

/// A parsed and checked manifest (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Manifest {
    /// The manifest file.
    pub file: PathBuf,
    /// Its folder: relative paths start here.
    pub root: PathBuf,
    /// Scene name.
    pub name: String,
    /// The frames' response.
    pub response: ResponseChoice,
    /// The frames' exposure gain.
    pub gain: GainChoice,
    /// The probes.
    pub probes: Vec<ProbeSource>,
    /// The frames.
    pub frames: FrameSource,
    /// How the frames' images map to directions.
    pub frame_layout: FrameLayout,
    /// Poses file, when given (otherwise poses must be recovered).
    pub poses: Option<PathBuf>,
    /// Output settings.
    pub output: OutputSettings,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawManifest {
    name: Option<String>,
    camera: Option<RawCamera>,
    #[serde(default)]
    probe: Vec<RawProbe>,
    frames: Option<RawFrames>,
    poses: Option<RawPoses>,
    output: Option<RawOutput>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    response: Option<String>,
    gain: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum RawList {
    Folder(String),
    Files(Vec<String>),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawProbe {
    id: String,
    hdr: Option<String>,
    brackets: Option<RawList>,
    times: Option<Vec<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFrames {
    folder: Option<String>,
    pattern: Option<String>,
    video: Option<String>,
    fps: Option<f64>,
    layout: Option<String>,
    fov: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPoses {
    file: String,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawOutput {
    folder: Option<String>,
    method: Option<String>,
    size: Option<String>,
}

/// Whether `name` matches `pattern`, where `*` matches any run of characters.
fn glob_match(pattern: &str, name: &str) -> bool {
    let parts: Vec<&str> = pattern.split('*').collect();
    if parts.len() == 1 {
        return pattern == name;
    }
    let (first, last) = (parts[0], parts[parts.len() - 1]);
    if !name.starts_with(first) || name.len() < first.len() + last.len() || !name.ends_with(last) {
        return false;
    }
    let mut rest = &name[first.len()..name.len() - last.len()];
    for mid in &parts[1..parts.len() - 1] {
        match rest.find(mid) {
            Some(i) => rest = &rest[i + mid.len()..],
            None => return false,
        }
    }
    true
}

const IMAGE_EXTS: [&str; 4] = ["jpg", "jpeg", "png", "tif"];

/// Image files of a folder (8-bit kinds), sorted by name, optionally filtered.
fn images_in(dir: &Path, pattern: Option<&str>) -> Result<Vec<PathBuf>> {
    let rd = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut v: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| IMAGE_EXTS.contains(&e.to_ascii_lowercase().as_str()))
        })
        .filter(|p| {
            pattern.is_none_or(|pat| {
                p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| glob_match(pat, n))
            })
        })
        .collect();
    v.sort();
    Ok(v)
}

impl Manifest {
    /// Reads and checks a manifest: TOML syntax and types, unknown keys, files and
    /// folders that must exist, and values that must make sense. Errors name the
    /// manifest and the key.
    pub fn load(path: &Path) -> Result<Manifest> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let root = super::parent_dir(path);
        Self::parse(&text, &root, path)
    }

    /// Parses manifest text; `root` resolves relative paths, `file` names the
    /// manifest in errors.
    pub fn parse(text: &str, root: &Path, file: &Path) -> Result<Manifest> {
        let bad = |msg: String| Error::format(file, msg);
        let raw: RawManifest =
            toml::from_str(text).map_err(|e| bad(format!("not a valid manifest: {e}")))?;
        let resolve = |s: &str| super::resolve_path(root, s);
        let must_exist = |key: &str, p: &Path| -> Result<()> {
            if p.exists() {
                Ok(())
            } else {
                Err(bad(format!("{key}: {} does not exist", p.display())))
            }
        };
        // The images of a folder the manifest names; errors name the key.
        let folder_images = |key: &str, dir: &Path, pattern: Option<&str>| {
            must_exist(key, dir)?;
            if !dir.is_dir() {
                return Err(bad(format!("{key}: {} is not a folder", dir.display())));
            }
            images_in(dir, pattern).map_err(|e| bad(format!("{key}: {e}")))
        };
        let camera = raw.camera.unwrap_or(RawCamera {
            response: None,
            gain: None,
        });
        let response = match camera.response.as_deref().map(str::trim) {
            None | Some("recover") => ResponseChoice::Recover,
            Some("documented") => ResponseChoice::Known(Response::RationalGamma {
                scale: 1.08,
                knee: 0.08,
                gamma: 2.2,
            }),
            Some(t) => match Response::parse(t) {
                Some(r) => ResponseChoice::Known(r),
                None => {
                    let p = resolve(t);
                    if p.extension().is_some_and(|e| e == "json") {
                        must_exist("camera.response", &p)?;
                        ResponseChoice::File(p)
                    } else {
                        return Err(bad(format!(
                            "camera.response: {t:?} is not \"recover\", \"documented\", \"srgb\", \"gamma G\", a response formula or a .json curve file"
                        )));
                    }
                }
            },
        };
        let gain = match &camera.gain {
            None => GainChoice::Auto,
            Some(toml::Value::String(s)) if s == "auto" => GainChoice::Auto,
            Some(v) => {
                let g = v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
                match g {
                    Some(g) if g.is_finite() && g > 0.0 => GainChoice::Value(g as f32),
                    _ => {
                        return Err(bad(format!(
                            "camera.gain: expected a positive number or \"auto\", got {v}"
                        )))
                    }
                }
            }
        };
        if raw.probe.is_empty() {
            return Err(bad(
                "probe: at least one [[probe]] with `hdr` or `brackets` is needed".into(),
            ));
        }
        let mut probes = Vec::new();
        let mut ids = std::collections::HashSet::new();
        for (i, p) in raw.probe.iter().enumerate() {
            let key = format!("probe[{i}]");
            if p.id.trim().is_empty() || !ids.insert(p.id.clone()) {
                return Err(bad(format!("{key}.id: {:?} is empty or used twice", p.id)));
            }
            let hdr = match &p.hdr {
                Some(h) => {
                    let path = resolve(h);
                    must_exist(&format!("{key}.hdr"), &path)?;
                    Some(path)
                }
                None => None,
            };
            let brackets = match &p.brackets {
                None => Vec::new(),
                Some(RawList::Folder(d)) => {
                    let dir = resolve(d);
                    let v = folder_images(&format!("{key}.brackets"), &dir, None)?;
                    if v.is_empty() {
                        return Err(bad(format!(
                            "{key}.brackets: {} holds no JPEG or PNG image",
                            dir.display()
                        )));
                    }
                    v
                }
                Some(RawList::Files(files)) => {
                    let mut v = Vec::new();
                    for (j, f) in files.iter().enumerate() {
                        let path = resolve(f);
                        must_exist(&format!("{key}.brackets[{j}]"), &path)?;
                        v.push(path);
                    }
                    v
                }
            };
            if hdr.is_none() && brackets.is_empty() {
                return Err(bad(format!("{key} ({}): give `hdr` or `brackets`", p.id)));
            }
            if let Some(t) = &p.times {
                if t.len() != brackets.len() {
                    return Err(bad(format!(
                        "{key}.times: {} times for {} brackets",
                        t.len(),
                        brackets.len()
                    )));
                }
                if let Some(x) = t.iter().find(|x| !(x.is_finite() && **x > 0.0)) {
                    return Err(bad(format!(
                        "{key}.times: exposure times must be positive seconds, got {x}"
                    )));
                }
            }
            probes.push(ProbeSource {
                id: p.id.clone(),
                hdr,
                brackets,
                times: p.times.clone(),
            });
        }
        let fr = raw
            .frames
            .ok_or_else(|| bad("frames: the [frames] table is missing".into()))?;
        let frames = match (&fr.folder, &fr.video) {
            (Some(_), Some(_)) => {
                return Err(bad("frames: give `folder` or `video`, not both".into()))
            }
            (None, None) => return Err(bad("frames: give `folder` or `video`".into())),
            (Some(d), None) => {
                let dir = resolve(d);
                let v = folder_images("frames.folder", &dir, fr.pattern.as_deref())?;
                if v.is_empty() {
                    return Err(bad(format!(
                        "frames.folder: no image in {} matches {}",
                        dir.display(),
                        fr.pattern.as_deref().unwrap_or("*.jpg|*.png")
                    )));
                }
                FrameSource::Images(v)
            }
            (None, Some(v)) => {
                let file = resolve(v);
                must_exist("frames.video", &file)?;
                let fps = fr.fps.unwrap_or(2.0);
                if !(fps.is_finite() && fps > 0.0 && fps <= 240.0) {
                    return Err(bad(format!(
                        "frames.fps: expected a rate in (0, 240], got {fps}"
                    )));
                }
                FrameSource::Video { file, fps }
            }
        };
        let frame_layout = match (fr.layout.as_deref(), fr.fov) {
            (None | Some("equirect"), None) => FrameLayout::Equirect,
            (None | Some("equirect"), Some(_)) => {
                return Err(bad(
                    "frames.fov: a lens field of view needs layout = \"dual-fisheye\"".into(),
                ))
            }
            (Some("dual-fisheye"), fov) => {
                let fov = fov.unwrap_or(195.0);
                if !(fov.is_finite() && (180.0..=270.0).contains(&fov)) {
                    return Err(bad(format!(
                        "frames.fov: expected a lens field of view in [180, 270] degrees, got {fov}"
                    )));
                }
                FrameLayout::DualFisheye {
                    fov_deg: fov as f32,
                }
            }
            (Some(other), _) => {
                return Err(bad(format!(
                    "frames.layout: expected \"equirect\" or \"dual-fisheye\", got {other:?}"
                )))
            }
        };
        let poses = match raw.poses {
            Some(p) => {
                let path = resolve(&p.file);
                must_exist("poses.file", &path)?;
                Some(path)
            }
            None => None,
        };
        let out = raw.output.unwrap_or(RawOutput {
            folder: None,
            method: None,
            size: None,
        });
        let method = out.method.unwrap_or_else(|| "fusion".into());
        if !["warp", "flow", "hybrid", "fusion"].contains(&method.as_str()) {
            return Err(bad(format!(
                "output.method: {method:?} is not warp, flow, hybrid or fusion"
            )));
        }
        let size = match &out.size {
            None => None,
            Some(s) => {
                let parsed = s
                    .split_once(['x', 'X'])
                    .and_then(|(w, h)| Some((w.trim().parse().ok()?, h.trim().parse().ok()?)))
                    .filter(|&(w, h): &(usize, usize)| {
                        w >= 8 && h >= 4 && w <= super::MAX_PANORAMA.0 && h <= super::MAX_PANORAMA.1
                    });
                Some(parsed.ok_or_else(|| {
                    let (mw, mh) = super::MAX_PANORAMA;
                    bad(format!(
                        "output.size: expected WxH between 8x4 and {mw}x{mh}, got {s:?}"
                    ))
                })?)
            }
        };
        Ok(Manifest {
            file: file.to_path_buf(),
            root: root.to_path_buf(),
            name: raw.name.unwrap_or_else(|| {
                root.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_else(|| "scene".into())
            }),
            response,
            gain,
            probes,
            frames,
            frame_layout,
            poses,
            output: OutputSettings {
                folder: resolve(out.folder.as_deref().unwrap_or("out")),
                method,
                size,
            },
        })
    }

    /// Drafts a manifest for a capture folder: probes from `probes/` (an HDR file
    /// `<id>.exr`, else the brackets in `<id>/wide/` or `<id>/`), frames from
    /// `path/` or `frames/` (ground-truth files `*_gt.*` left out), a video file at
    /// the top if there is no frame folder, and `poses.json` when present. The
    /// result is text for the user to check and edit.
    pub fn draft(folder: &Path) -> Result<String> {
        let mut s = String::new();
        let name = folder
            .canonicalize()
            .ok()
            .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .unwrap_or_else(|| "scene".into());
        s += &format!(
            "# lumiprobe manifest drafted by `lumiprobe init`; check it.\nname = {name:?}\n\n"
        );
        let has_poses = folder.join("poses.json").is_file();
        // A dataset-layout poses.json may document the response.
        let documented = if has_poses {
            super::Scene::load(folder)
                .ok()
                .filter(|sc| !sc.warnings.iter().any(|w| w.contains("camera.response")))
                .map(|sc| sc.response)
        } else {
            None
        };
        // Brackets the manifest will use: a probe folder of images with no HDR
        // file beside it (a probe with one keeps its brackets commented out).
        let pdir = folder.join("probes");
        let any_brackets = pdir.is_dir()
            && std::fs::read_dir(&pdir)
                .map_err(|e| Error::io(&pdir, e))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.is_dir())
                .any(|d| {
                    let id = d.file_name().map(|n| n.to_string_lossy().into_owned());
                    let has_hdr = id.is_some_and(|id| {
                        pdir.join(format!("{id}.exr")).is_file()
                            || pdir.join(format!("{id}.hdr")).is_file()
                    });
                    !has_hdr && walk_has_images(&d)
                });
        s += "[camera]\n";
        match documented {
            Some(r) if !any_brackets => {
                s += &format!("response = {:?}   # from poses.json\n", response_text(&r));
            }
            _ if any_brackets => {
                s += "response = \"recover\"   # from the brackets; or \"documented\", \"srgb\", \"gamma 2.2\", a .json curve\n";
            }
            _ => {
                s += "response = \"srgb\"   # CHECK: the frames' camera response\n";
            }
        }
        s += "gain = \"auto\"          # or the frames' exposure gain\n\n";
        let mut n_probes = 0;
        if pdir.is_dir() {
            let mut ids: Vec<String> = std::fs::read_dir(&pdir)
                .map_err(|e| Error::io(&pdir, e))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter_map(|p| {
                    if p.is_dir() {
                        p.file_name().map(|n| n.to_string_lossy().into_owned())
                    } else if p.extension().is_some_and(|e| e == "exr" || e == "hdr") {
                        p.file_stem().map(|n| n.to_string_lossy().into_owned())
                    } else {
                        None
                    }
                })
                .collect();
            ids.sort();
            ids.dedup();
            for id in ids {
                let exr = pdir.join(format!("{id}.exr"));
                let hdr = pdir.join(format!("{id}.hdr"));
                let wide = pdir.join(&id).join("wide");
                let plain = pdir.join(&id);
                s += &format!("[[probe]]\nid = {id:?}\n");
                if exr.is_file() {
                    s += &format!("hdr = \"probes/{id}.exr\"\n");
                } else if hdr.is_file() {
                    s += &format!("hdr = \"probes/{id}.hdr\"\n");
                }
                let brackets = if wide.is_dir() && !images_in(&wide, None)?.is_empty() {
                    Some(format!("probes/{id}/wide"))
                } else if plain.is_dir() && !images_in(&plain, None)?.is_empty() {
                    Some(format!("probes/{id}"))
                } else {
                    None
                };
                if let Some(b) = brackets {
                    let prefix = if exr.is_file() || hdr.is_file() {
                        "# "
                    } else {
                        ""
                    };
                    s += &format!("{prefix}brackets = {b:?}\n");
                }
                s += "\n";
                n_probes += 1;
            }
        }
        if n_probes == 0 {
            return Err(Error::Invalid(format!(
                "{}: no probes/ folder with HDR files or bracket folders",
                folder.display()
            )));
        }
        s += "[frames]\n";
        let frame_dir = ["path", "frames"]
            .iter()
            .map(|d| folder.join(d))
            .find(|d| d.is_dir());
        match frame_dir {
            Some(d) => {
                let rel = d
                    .file_name()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned();
                let all = images_in(&d, None)?;
                let gt = all
                    .iter()
                    .filter(|p| {
                        p.file_stem()
                            .and_then(|n| n.to_str())
                            .is_some_and(|n| n.ends_with("_gt"))
                    })
                    .count();
                s += &format!("folder = {rel:?}\n");
                let ext = all
                    .iter()
                    .find_map(|p| p.extension().map(|e| e.to_string_lossy().into_owned()))
                    .unwrap_or_else(|| "jpg".into());
                if gt > 0
                    || all
                        .iter()
                        .any(|p| p.extension().is_some_and(|e| e != ext.as_str()))
                {
                    s += &format!("pattern = \"*.{ext}\"\n");
                }
            }
            None => {
                let video = std::fs::read_dir(folder)
                    .map_err(|e| Error::io(folder, e))?
                    .filter_map(|e| e.ok().map(|e| e.path()))
                    .find(|p| {
                        p.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                            ["mp4", "mov", "mkv", "avi"].contains(&e.to_ascii_lowercase().as_str())
                        })
                    });
                match video {
                    Some(v) => {
                        s += &format!(
                            "video = {:?}\nfps = 2.0\n",
                            v.file_name().unwrap_or_default().to_string_lossy()
                        )
                    }
                    None => {
                        return Err(Error::Invalid(format!(
                            "{}: no path/ or frames/ folder and no video file",
                            folder.display()
                        )))
                    }
                }
            }
        }
        s += "\n";
        if has_poses {
            s += "[poses]\nfile = \"poses.json\"\n\n";
        } else {
            s += "# [poses]\n# file = \"poses.json\"   # without it the poses are recovered\n\n";
        }
        s += "[output]\nfolder = \"out\"\nmethod = \"fusion\"\n";
        Ok(s)
    }
}

/// Whether a folder or any folder below it (two levels) holds an 8-bit image.
fn walk_has_images(dir: &Path) -> bool {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return false;
    };
    rd.filter_map(|e| e.ok().map(|e| e.path())).any(|p| {
        if p.is_dir() {
            images_in(&p, None).is_ok_and(|v| !v.is_empty())
                || std::fs::read_dir(&p).is_ok_and(|r| {
                    r.filter_map(|e| e.ok().map(|e| e.path()))
                        .any(|q| q.is_dir() && images_in(&q, None).is_ok_and(|v| !v.is_empty()))
                })
        } else {
            false
        }
    })
}

/// A response as manifest text that [`Response::parse`] reads back.
fn response_text(r: &Response) -> String {
    match r {
        Response::Srgb => "srgb".into(),
        Response::Gamma { gamma } => format!("gamma {gamma}"),
        Response::RationalGamma { scale, knee, gamma } => {
            format!("f(x) = min(1, {scale} * x^(1/{gamma}) / (1 + {knee} * x^(1/{gamma})))")
        }
        Response::Table { .. } => "srgb".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn setup() -> tempfile::TempDir {
        let t = tempfile::tempdir().unwrap();
        let d = t.path();
        std::fs::create_dir_all(d.join("probes/p0/wide")).unwrap();
        std::fs::create_dir_all(d.join("path")).unwrap();
        for f in ["probes/p0/wide/ev-2.jpg", "probes/p0/wide/ev+0.jpg"] {
            std::fs::write(d.join(f), b"x").unwrap();
        }
        std::fs::write(d.join("probes/p1.exr"), b"x").unwrap();
        for f in [
            "path/frame_000.jpg",
            "path/frame_001.jpg",
            "path/frame_000_gt.exr",
        ] {
            std::fs::write(d.join(f), b"x").unwrap();
        }
        std::fs::write(d.join("poses.json"), b"{}").unwrap();
        t
    }

    const GOOD: &str = r#"
name = "t"
[camera]
response = "gamma 2.2"
gain = 0.5
[[probe]]
id = "p0"
brackets = "probes/p0/wide"
times = [0.25, 1.0]
[[probe]]
id = "p1"
hdr = "probes/p1.exr"
[frames]
folder = "path"
pattern = "frame_*.jpg"
[poses]
file = "poses.json"
[output]
method = "flow"
size = "256x128"
"#;

    #[test]
    fn a_good_manifest_parses() {
        let t = setup();
        let f = t.path().join("m.toml");
        let m = Manifest::parse(GOOD, t.path(), &f).unwrap();
        assert_eq!(m.name, "t");
        assert_eq!(
            m.response,
            ResponseChoice::Known(Response::Gamma { gamma: 2.2 })
        );
        assert_eq!(m.gain, GainChoice::Value(0.5));
        assert_eq!(m.probes.len(), 2);
        assert_eq!(m.probes[0].brackets.len(), 2);
        assert!(m.probes[0].brackets[0].ends_with("ev+0.jpg"));
        assert_eq!(m.probes[1].hdr, Some(t.path().join("probes/p1.exr")));
        match &m.frames {
            FrameSource::Images(v) => assert_eq!(v.len(), 2),
            other => panic!("{other:?}"),
        }
        assert_eq!(m.output.size, Some((256, 128)));
        assert_eq!(m.output.method, "flow");
        assert_eq!(m.poses, Some(t.path().join("poses.json")));
        assert_eq!(m.frame_layout, FrameLayout::Equirect);
        let dual = GOOD.replace("[poses]", "layout = \"dual-fisheye\"\n[poses]");
        let m = Manifest::parse(&dual, t.path(), &f).unwrap();
        assert_eq!(m.frame_layout, FrameLayout::DualFisheye { fov_deg: 195.0 });
    }

    #[test]
    fn bad_manifests_name_the_key() {
        let t = setup();
        let f = t.path().join("m.toml");
        let cases = [
            (GOOD.replace("gain = 0.5", "gain = -1"), "camera.gain"),
            (GOOD.replace("gain = 0.5", "gain = \"fast\""), "camera.gain"),
            (GOOD.replace("gamma 2.2", "banana"), "camera.response"),
            (
                GOOD.replace("probes/p1.exr", "probes/none.exr"),
                "probe[1].hdr",
            ),
            (
                GOOD.replace("times = [0.25, 1.0]", "times = [0.25]"),
                "probe[0].times",
            ),
            (
                GOOD.replace("times = [0.25, 1.0]", "times = [0.0, 1.0]"),
                "probe[0].times",
            ),
            (GOOD.replace("id = \"p1\"", "id = \"p0\""), "probe[1].id"),
            (
                GOOD.replace("method = \"flow\"", "method = \"magic\""),
                "output.method",
            ),
            (GOOD.replace("256x128", "2x1"), "output.size"),
            (
                GOOD.replace("frame_*.jpg", "nothing_*.jpg"),
                "frames.folder",
            ),
            (GOOD.replace("poses.json", "missing.json"), "poses.file"),
            (GOOD.replace("method = \"flow\"", "method = 3"), "method"),
            (GOOD.replace("[output]", "[output]\ncolour = 1"), "colour"),
            (
                GOOD.replace("folder = \"path\"", "video = \"path\"\nfolder = \"path\""),
                "frames",
            ),
            (
                GOOD.replace("[poses]", "layout = \"fisheye\"\n[poses]"),
                "frames.layout",
            ),
            (GOOD.replace("[poses]", "fov = 200\n[poses]"), "frames.fov"),
            (
                GOOD.replace("[poses]", "layout = \"dual-fisheye\"\nfov = 120\n[poses]"),
                "frames.fov",
            ),
        ];
        for (text, key) in cases {
            let e = Manifest::parse(&text, t.path(), &f)
                .unwrap_err()
                .to_string();
            assert!(e.contains(key), "{key}: {e}");
            assert!(e.contains("m.toml"), "{e}");
        }
        let e = Manifest::load(&t.path().join("none.toml")).unwrap_err();
        assert!(e.to_string().contains("none.toml"));
    }

    #[test]
    fn init_drafts_a_manifest_that_parses() {
        let t = setup();
        let text = Manifest::draft(t.path()).unwrap();
        assert!(text.contains("brackets = \"probes/p0/wide\""), "{text}");
        assert!(text.contains("hdr = \"probes/p1.exr\""), "{text}");
        let m = Manifest::parse(&text, t.path(), &t.path().join("lumiprobe.toml")).unwrap();
        match &m.frames {
            FrameSource::Images(v) => assert_eq!(v.len(), 2, "{v:?}"),
            other => panic!("{other:?}"),
        }
        assert_eq!(m.gain, GainChoice::Auto);
        assert_eq!(m.response, ResponseChoice::Recover);
        assert!(Manifest::draft(&t.path().join("path")).is_err());
    }

    #[test]
    fn glob_matches_stars() {
        assert!(glob_match("frame_*.jpg", "frame_001.jpg"));
        assert!(!glob_match("frame_*.jpg", "frame_001_gt.exr"));
        assert!(glob_match("*", "a"));
        assert!(glob_match("a*b*c", "aXbYc"));
        assert!(!glob_match("a*b*c", "acb"));
        assert!(glob_match("x.jpg", "x.jpg"));
    }
}
