//! A captured scene: sparse HDR probes, the SDR frames of the walk, their poses and
//! the camera's radiometry. Reads the dataset layout (`poses.json` beside `probes/`
//! and `path/`).

pub mod manifest;

/// The largest panorama lumiprobe works at (width, height): 16384 x 8192 is
/// 1.5 GiB as float RGB, and every per-pixel buffer of a method is sized by it.
pub const MAX_PANORAMA: (usize, usize) = (16384, 8192);

use crate::error::{Error, Result};
use crate::sphere::orthonormalize;
use crate::tonemap::Response;
use glam::{Mat3, Vec3};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// The folder holding `file`: `.` for a bare file name (whose parent is the
/// empty path, which would name nothing in messages).
pub(crate) fn parent_dir(file: &Path) -> PathBuf {
    match file.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// A path from a scene or manifest file: absolute as given, relative to `root`.
pub(crate) fn resolve_path(root: &Path, s: &str) -> PathBuf {
    let p = Path::new(s);
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        root.join(p)
    }
}

/// Distance in metres between two positions, computed in `f64` so that far-apart
/// positions (squares above `f32::MAX`) still give a finite distance.
pub fn distance_m(a: Vec3, b: Vec3) -> f32 {
    a.as_dvec3().distance(b.as_dvec3()) as f32
}

/// Where a panorama was taken and how it was turned.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Camera centre in world coordinates (metres, z up).
    pub position: Vec3,
    /// Rotation taking camera-axis directions to world directions.
    pub world_from_camera: Mat3,
}

impl Pose {
    /// Rotation that brings a panorama taken with pose `other` into this pose's
    /// camera axes: pass it to [`crate::sphere::rotate`] with `other`'s image.
    pub fn from_other(&self, other: &Pose) -> Mat3 {
        other.world_from_camera.transpose() * self.world_from_camera
    }
}

/// One exposure of a bracket set.
#[derive(Clone, Debug, PartialEq)]
pub struct Bracket {
    /// Image file.
    pub file: PathBuf,
    /// Exposure value relative to the base exposure.
    pub ev: f32,
    /// Exposure time in seconds, when known.
    pub exposure_time_s: Option<f32>,
}

/// A sparse HDR probe.
#[derive(Clone, Debug, PartialEq)]
pub struct Probe {
    /// Identifier, e.g. `probe_00`.
    pub id: String,
    /// Where it was taken.
    pub pose: Pose,
    /// Merged HDR panorama, if given.
    pub hdr: Option<PathBuf>,
    /// The exposure brackets it can be merged from.
    pub brackets: Vec<Bracket>,
    /// A second, wider bracket set (`brackets_wide` in the dataset layout).
    pub brackets_wide: Vec<Bracket>,
}

/// One SDR frame of the walk.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Identifier, e.g. `frame_000`; also the output file's stem.
    pub id: String,
    /// Where it was taken.
    pub pose: Pose,
    /// The 8-bit panorama.
    pub sdr: PathBuf,
    /// True HDR at this pose, for evaluation only (never read by a method).
    pub ground_truth: Option<PathBuf>,
    /// This frame's own exposure gain per channel (a camera with auto-exposure
    /// and white balance: `lumiprobe run --calibrate --frame-exposure`);
    /// `None`: the scene's `path_gain`.
    pub gain: Option<[f32; 3]>,
}

/// A whole capture.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Folder holding the scene (paths below are absolute).
    pub root: PathBuf,
    /// Scene name.
    pub name: String,
    /// The HDR probes.
    pub probes: Vec<Probe>,
    /// The SDR frames in walk order.
    pub frames: Vec<Frame>,
    /// How SDR codes map to exposure.
    pub response: Response,
    /// Exposure gain of the SDR frames: radiance = response⁻¹(code / 255) / gain.
    pub path_gain: f32,
    /// What the probes' (and the frames') radiance is measured in, for reports.
    pub probe_unit: String,
    /// Things the loader repaired or assumed, for the report.
    pub warnings: Vec<String>,
    /// A two-lens camera's falloff towards its lenses' rims, `k` in
    /// `1 - k rim` ([`crate::capture::vignetting`]), divided out of the frames
    /// when they are decoded; `None` (what a scene file gives): none.
    pub vignetting: Option<f32>,
}

#[derive(Deserialize)]
struct RawScene {
    #[serde(default)]
    scene: Option<String>,
    probes: Vec<RawEntry>,
    frames: Vec<RawEntry>,
    #[serde(default)]
    camera: Option<RawCamera>,
}

#[derive(Deserialize)]
struct RawEntry {
    id: String,
    position: [f64; 3],
    world_from_camera: [[f64; 3]; 3],
    #[serde(default)]
    hdr: Option<String>,
    #[serde(default)]
    brackets: Vec<RawBracket>,
    #[serde(default)]
    brackets_wide: Vec<RawBracket>,
    #[serde(default)]
    sdr: Option<String>,
    #[serde(default)]
    ground_truth: Option<String>,
}

#[derive(Deserialize)]
struct RawBracket {
    file: String,
    ev: f32,
    #[serde(default)]
    exposure_time_s: Option<f32>,
}

#[derive(Deserialize)]
struct RawCamera {
    #[serde(default)]
    response: Option<String>,
    #[serde(default)]
    path_gain: Option<f64>,
}

impl Scene {
    /// The exposure gain per channel frame `f` was taken with: its own
    /// ([`Frame::gain`]) or the scene's `path_gain`.
    pub fn frame_gain(&self, f: &Frame) -> [f32; 3] {
        f.gain.unwrap_or([self.path_gain; 3])
    }

    /// One gain for frame `f`: the gain that gives a pixel clipped in every
    /// channel the luminance [`Scene::frame_gain`]'s channels give it
    /// (`1 / sum(w_c / g_c)`, Rec. 709 weights); the scene's `path_gain` for a
    /// frame without its own.
    pub fn frame_luminance_gain(&self, f: &Frame) -> f32 {
        match f.gain {
            None => self.path_gain,
            Some(g) => {
                let s = 0.2126 / g[0] + 0.7152 / g[1] + 0.0722 / g[2];
                if s.is_finite() && s > 0.0 {
                    1.0 / s
                } else {
                    self.path_gain
                }
            }
        }
    }

    /// Loads `dir/poses.json` (or a `poses.json` path given directly).
    pub fn load(dir: &Path) -> Result<Scene> {
        let (root, file) = if dir.is_file() {
            (parent_dir(dir), dir.to_path_buf())
        } else {
            (dir.to_path_buf(), dir.join("poses.json"))
        };
        let text = std::fs::read_to_string(&file).map_err(|e| Error::io(&file, e))?;
        Self::parse(&text, &root, &file)
    }

    /// Parses the text of a `poses.json`; `root` resolves relative paths and `file`
    /// names the source in errors.
    pub fn parse(text: &str, root: &Path, file: &Path) -> Result<Scene> {
        let raw: RawScene = serde_json::from_str(text).map_err(|e| {
            Error::format(
                file,
                format!(
                    "not a valid scene description: {e}{}",
                    if e.is_syntax() {
                        json_context(text, e.line(), e.column())
                    } else {
                        String::new()
                    }
                ),
            )
        })?;
        let mut warnings = Vec::new();
        let mut pose_of = |kind: &str, e: &RawEntry| -> Result<Pose> {
            let p = Vec3::new(
                e.position[0] as f32,
                e.position[1] as f32,
                e.position[2] as f32,
            );
            if !p.is_finite() {
                return Err(Error::format(
                    file,
                    format!("{kind} {}: position is not finite", e.id),
                ));
            }
            let m = e.world_from_camera;
            // Row-major in the file; glam is column-major.
            let mat = Mat3::from_cols(
                Vec3::new(m[0][0] as f32, m[1][0] as f32, m[2][0] as f32),
                Vec3::new(m[0][1] as f32, m[1][1] as f32, m[2][1] as f32),
                Vec3::new(m[0][2] as f32, m[1][2] as f32, m[2][2] as f32),
            );
            let fixed = orthonormalize(mat).ok_or_else(|| {
                let det = mat.determinant();
                let why = if det < 0.0 {
                    format!(" (determinant {det:.3}: a reflection; check the axes' handedness)")
                } else {
                    String::new()
                };
                Error::format(
                    file,
                    format!("{kind} {}: world_from_camera is not a rotation{why}", e.id),
                )
            })?;
            let err = (fixed - mat)
                .to_cols_array()
                .iter()
                .fold(0.0f32, |a, v| a.max(v.abs()));
            if err > 1e-3 {
                warnings.push(format!("{kind} {}: world_from_camera was not orthonormal (max deviation {err:.4}); used the nearest rotation", e.id));
            }
            Ok(Pose {
                position: p,
                world_from_camera: fixed,
            })
        };
        let resolve = |s: &str| resolve_path(root, s);
        let mut probes = Vec::new();
        for e in &raw.probes {
            let pose = pose_of("probe", e)?;
            let hdr = e.hdr.as_deref().map(resolve).or_else(|| {
                let p = root.join("probes").join(format!("{}.exr", e.id));
                p.exists().then_some(p)
            });
            let to_brackets = |list: &[RawBracket]| -> Vec<Bracket> {
                list.iter()
                    .map(|b| Bracket {
                        file: resolve(&b.file),
                        ev: b.ev,
                        exposure_time_s: b.exposure_time_s,
                    })
                    .collect()
            };
            let brackets = to_brackets(&e.brackets);
            let brackets_wide = to_brackets(&e.brackets_wide);
            probes.push(Probe {
                id: e.id.clone(),
                pose,
                hdr,
                brackets,
                brackets_wide,
            });
        }
        let mut frames = Vec::new();
        for e in &raw.frames {
            let pose = pose_of("frame", e)?;
            let sdr =
                e.sdr.as_deref().map(resolve).ok_or_else(|| {
                    Error::format(file, format!("frame {}: missing key `sdr`", e.id))
                })?;
            frames.push(Frame {
                id: e.id.clone(),
                pose,
                sdr,
                ground_truth: e.ground_truth.as_deref().map(resolve),
                gain: None,
            });
        }
        if probes.is_empty() {
            return Err(Error::format(
                file,
                "`probes` is empty: at least one probe is needed",
            ));
        }
        let mut ids = std::collections::HashSet::new();
        for f in &frames {
            if f.id.is_empty() || f.id.contains(['/', '\\']) || f.id.starts_with('.') {
                return Err(Error::format(
                    file,
                    format!("frame id {:?} cannot name an output file", f.id),
                ));
            }
            if !ids.insert(&f.id) {
                return Err(Error::format(
                    file,
                    format!("frame id {:?} appears twice", f.id),
                ));
            }
        }
        let camera = raw.camera.unwrap_or(RawCamera {
            response: None,
            path_gain: None,
        });
        let response = match camera.response.as_deref() {
            Some(t) => Response::parse(t).unwrap_or_else(|| {
                warnings.push(format!(
                    "camera.response {t:?} not understood; assuming sRGB"
                ));
                Response::Srgb
            }),
            None => {
                warnings.push("camera.response missing; assuming sRGB".into());
                Response::Srgb
            }
        };
        let path_gain = match camera.path_gain {
            Some(g) if g.is_finite() && g > 0.0 => g as f32,
            Some(g) => {
                return Err(Error::format(
                    file,
                    format!("camera.path_gain must be a positive number, got {g}"),
                ))
            }
            None => {
                warnings.push("camera.path_gain missing; assuming 1".into());
                1.0
            }
        };
        // A walk's frames come from one camera: the first one's Photo Sphere
        // metadata speaks for them.
        if let Some(n) = frames
            .first()
            .and_then(|f| crate::image::io::gpano::note(&f.sdr))
        {
            warnings.push(n);
        }
        Ok(Scene {
            root: root.to_path_buf(),
            name: raw.scene.unwrap_or_else(|| {
                root.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default()
            }),
            probes,
            frames,
            response,
            path_gain,
            probe_unit: "as given (HDR files)".into(),
            warnings,
            vignetting: None,
        })
    }

    /// Index of the probe nearest to `position` (ties go to the lower index).
    pub fn nearest_probe(&self, position: Vec3) -> usize {
        self.probes_by_distance(position)[0]
    }

    /// Probe indices sorted by distance to `position` (stable for ties).
    pub fn probes_by_distance(&self, position: Vec3) -> Vec<usize> {
        let mut idx: Vec<usize> = (0..self.probes.len()).collect();
        // In f64: squared distances of far-apart positions overflow f32.
        let p = position.as_dvec3();
        idx.sort_by(|&a, &b| {
            let da = self.probes[a].pose.position.as_dvec3().distance_squared(p);
            let db = self.probes[b].pose.position.as_dvec3().distance_squared(p);
            da.total_cmp(&db).then(a.cmp(&b))
        });
        idx
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"{"scene":"t","probes":[{"id":"p0","position":[0,0,1.5],"world_from_camera":[[1,0,0],[0,0,-1],[0,1,0]],"hdr":"probes/p0.exr"},
        {"id":"p1","position":[2,0,1.5],"world_from_camera":[[1,0,0],[0,0,-1],[0,1,0]],"hdr":"probes/p1.exr"}],
        "frames":[{"id":"f0","position":[1.5,0,1.5],"world_from_camera":[[1.01,0,0],[0,0,-1],[0,1,0]],"sdr":"path/f0.jpg"}],
        "camera":{"response":"f(x) = min(1, 1.08 * x^(1/2.2) / (1 + 0.08 * x^(1/2.2)))","path_gain":0.5}}"#;

    #[test]
    fn parses_and_repairs_rotation() {
        let s = Scene::parse(GOOD, Path::new("/data"), Path::new("/data/poses.json")).unwrap();
        assert_eq!(s.probes.len(), 2);
        assert_eq!(s.nearest_probe(s.frames[0].pose.position), 1);
        assert!(s.warnings.iter().any(|w| w.contains("orthonormal")));
        assert!((s.frames[0].pose.world_from_camera.determinant() - 1.0).abs() < 1e-4);
        assert_eq!(
            s.probes[0].hdr.as_deref(),
            Some(Path::new("/data/probes/p0.exr"))
        );
        // Camera +y (up) is world +z.
        assert!((s.probes[0].pose.world_from_camera * Vec3::Y - Vec3::Z).length() < 1e-6);
    }

    #[test]
    fn bad_scenes_name_file_and_problem() {
        let e = Scene::parse(
            "{\"probes\": 3}",
            Path::new("/d"),
            Path::new("/d/poses.json"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("/d/poses.json") && e.contains("invalid type"),
            "{e}"
        );
        let no_sdr = GOOD.replace("\"sdr\":\"path/f0.jpg\"", "\"x\":1");
        let e = Scene::parse(&no_sdr, Path::new("/d"), Path::new("/d/poses.json"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("sdr"), "{e}");
        let singular = GOOD.replace("[[1.01,0,0],[0,0,-1],[0,1,0]]", "[[0,0,0],[0,0,0],[0,0,0]]");
        assert!(Scene::parse(&singular, Path::new("/d"), Path::new("/d/poses.json")).is_err());
    }
}

/// Where in a JSON text a parse error at (`line`, `column`) (1-based, as
/// serde_json counts) sits, in the file's own words: the key and entry id it
/// belongs to, and a word on values JSON cannot hold (NaN, Infinity).
fn json_context(text: &str, line: usize, column: usize) -> String {
    if line == 0 {
        return String::new();
    }
    let Some(start) = text
        .split_inclusive('\n')
        .take(line - 1)
        .map(str::len)
        .sum::<usize>()
        .checked_add(column.saturating_sub(1))
    else {
        return String::new();
    };
    let mut at = start.min(text.len());
    while !text.is_char_boundary(at) {
        at -= 1;
    }
    let before = &text[..at];
    // The value's token: the error points at or just past it.
    let from = before
        .rfind(|c: char| c == ':' || c == ',' || c == '[' || c == '{')
        .map_or(0, |i| i + 1);
    let token: String = text[from..]
        .trim_start()
        .chars()
        .take_while(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '+' || *c == '.')
        .collect();
    let quoted = |s: &str, key: &str| -> Option<String> {
        let k = s.rfind(&format!("\"{key}\""))?;
        let rest = s[k + key.len() + 2..]
            .trim_start()
            .strip_prefix(':')?
            .trim_start();
        let rest = rest.strip_prefix('"')?;
        Some(rest[..rest.find('"')?].to_string())
    };
    // The last key before the error.
    let key = {
        let mut k = None;
        let mut s = before;
        while let Some(c) = s.rfind("\":") {
            let open = s[..c].rfind('"');
            if let Some(o) = open {
                k = Some(s[o + 1..c].to_string());
                break;
            }
            s = &s[..c];
        }
        k
    };
    let mut out = String::new();
    if let Some(k) = key {
        out += &format!(" (in \"{k}\"");
        if let Some(id) = quoted(before, "id") {
            out += &format!(" of the entry with id \"{id}\"");
        }
        out += ")";
    }
    let t = token.trim_start_matches(['-', '+']);
    if t.eq_ignore_ascii_case("nan")
        || t.eq_ignore_ascii_case("infinity")
        || t.eq_ignore_ascii_case("inf")
    {
        out += &format!(": {token} is not a number JSON can hold; give a finite number");
    }
    out
}

#[cfg(test)]
mod json_context_tests {
    use super::*;

    #[test]
    fn a_nan_in_poses_is_named_by_key_and_entry() {
        let rot = "\"world_from_camera\": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]";
        let text = format!(
            "{{\n  \"frames\": [\n    {{\"id\": \"f0\", \"position\": [0, 0, 0], {rot}}},\n    {{\"id\": \"f1\", \"position\": [1, NaN, 0], {rot}}}\n  ]\n}}\n"
        );
        let e = Scene::parse(&text, Path::new("."), Path::new("poses.json"))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("poses.json"), "{e}");
        assert!(e.contains("line 4"), "{e}");
        assert!(
            e.contains("\"position\" of the entry with id \"f1\""),
            "{e}"
        );
        assert!(e.contains("NaN is not a number JSON can hold"), "{e}");
        // Any position in any text gives an answer, never a panic.
        let odd = "{\"é\": [\"ü\", NaN]}";
        for line in 0..4 {
            for col in 0..20 {
                let _ = json_context(odd, line, col);
            }
        }
        // A plain syntax error keeps serde's words without a NaN remark.
        let e = Scene::parse("{\"frames\": [}", Path::new("."), Path::new("p.json"))
            .err()
            .unwrap()
            .to_string();
        assert!(!e.contains("NaN"), "{e}");
    }
}
