//! `lumiprobe view`: a static web page to look through a run.
//!
//! Written into one folder:
//!
//! | file | content |
//! |------|---------|
//! | `index.html`, `view.js` | the page: a scrubber over the walk, the SDR frame, the predicted probe with an exposure slider, a glTF model lit by that frame's probe and lights, the eval plots |
//! | `frames/<id>.jpg` | the SDR frames as the camera recorded them |
//! | `probes/` | [`super::export`]'s `.hdr` probes, `_lights.gltf` and `_residual.hdr`, world-aligned (`+y` up) |
//! | `model.glb` / `model.gltf` | the model, when one is given (else three spheres: diffuse, glossy, mirror) |
//! | `eval/` | an `eval --report` folder's HTML and plots, when one is given |
//! | `vendor/` | three.js, copied from the npm package when it is found |
//! | `view.json` | what the page shows: per frame its files, world position and auto exposure; written last |
//!
//! Browsers do not run JavaScript modules from `file://` pages: open the page
//! through a web server, e.g. [`serve`] (`lumiprobe view ... --serve`).

mod serve;

pub use serve::{serve, Server};

use super::export::{export, ExportFormat, ExportOptions, Orientation};
use crate::error::{Error, Result};
use crate::image::io::read_hdr_repaired;
use crate::scene::Scene;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The page.
const INDEX_HTML: &str = include_str!("index.html");
/// The page's script.
const VIEW_JS: &str = include_str!("view.js");
/// The three.js release the page is written for (and fetched from a CDN when
/// no local copy is found).
pub const THREE_VERSION: &str = "0.171.0";
/// The files of three.js's npm package the page loads, relative to the package.
const THREE_FILES: [&str; 7] = [
    "build/three.module.js",
    "build/three.core.js",
    "examples/jsm/loaders/RGBELoader.js",
    "examples/jsm/loaders/GLTFLoader.js",
    "examples/jsm/utils/BufferGeometryUtils.js",
    "examples/jsm/controls/OrbitControls.js",
    "LICENSE",
];
/// The npm `ktx-parse` release and module file the page reads KTX 2.0 with.
const KTX_PARSE_VERSION: &str = "1.1.0";
const KTX_PARSE_FILE: &str = "dist/ktx-parse.modern.js";
/// Most files an eval folder may bring (its report, plots and thumbnails).
const MAX_EVAL_FILES: usize = 256;
/// Largest file copied from an eval folder or as the model.
const MAX_COPY_BYTES: u64 = 512 << 20;

/// What [`write_view`] puts in the page besides the run.
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// A glTF model (`.glb`, or `.gltf` with its files beside it) to light.
    pub model: Option<PathBuf>,
    /// An `eval --report` folder whose report and plots the page links.
    pub eval: Option<PathBuf>,
    /// three.js's npm package folder (`node_modules/three`); `None`: looked for
    /// ([`find_three`]).
    pub three: Option<PathBuf>,
    /// Indices into the scene's frames (walk order); `None`: every frame with a
    /// prediction.
    pub frames: Option<Vec<usize>>,
    /// Also write each frame's GGX-prefiltered cube as KTX 2.0, which the page
    /// can light with instead of the equirect (read with npm `ktx-parse`).
    pub ktx2: bool,
    /// Largest width of the probes the page loads (a browser holds each as
    /// float RGBA: 7776x3888 would take 480 MB a frame); wider ones are box
    /// filtered down, their power kept.
    pub max_width: usize,
}

/// The page's probes at most this wide by default.
pub const VIEW_MAX_WIDTH: usize = 2048;

impl Default for ViewOptions {
    fn default() -> Self {
        ViewOptions {
            model: None,
            eval: None,
            three: None,
            frames: None,
            ktx2: false,
            max_width: VIEW_MAX_WIDTH,
        }
    }
}

/// One frame as the page shows it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ViewFrame {
    /// The frame's id.
    pub id: String,
    /// The SDR frame, relative to the page.
    pub sdr: String,
    /// The predicted probe (`+y` up equirect `.hdr`).
    pub probe: String,
    /// The probe without its dominant lights.
    pub residual: String,
    /// The dominant lights as glTF `KHR_lights_punctual`.
    pub lights: String,
    /// How many lights.
    pub light_count: usize,
    /// The GGX-prefiltered specular cube (KTX 2.0), when written.
    #[serde(default)]
    pub specular: Option<String>,
    /// The frame's position in the page's axes (`+y` up, the poses' unit): the
    /// model stands there, so point lights keep their distance.
    pub position: [f32; 3],
    /// Exposure (a multiplier of the radiance) that maps the probe's
    /// log-average luminance to 0.18 ([`crate::tonemap::auto_exposure_ev`]).
    pub exposure: f32,
}

/// What the page shows; `view.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ViewReport {
    /// The scene's name.
    pub scene: String,
    /// The frames, in walk order.
    pub frames: Vec<ViewFrame>,
    /// The model's file, relative to the page (`None`: spheres).
    pub model: Option<String>,
    /// The eval report and plots, relative to the page.
    pub eval: Vec<String>,
    /// Where three.js comes from: `vendor/` or a CDN address.
    pub three: String,
    /// Notes for the user (no local three.js, frames with no prediction).
    pub warnings: Vec<String>,
}

/// three.js's npm package next to lumiprobe's sources (`tools/js`), where the
/// setup script installs it; `None` when it is not there.
pub fn find_three() -> Option<PathBuf> {
    let mut candidates = Vec::new();
    if let Some(p) = std::env::var_os("LUMIPROBE_THREE") {
        candidates.push(PathBuf::from(p));
    }
    candidates.push(Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/js/node_modules/three"));
    if let Ok(exe) = std::env::current_exe() {
        for up in exe.ancestors().skip(1).take(4) {
            candidates.push(up.join("tools/js/node_modules/three"));
        }
    }
    candidates
        .into_iter()
        .find(|c| c.join("build/three.module.js").is_file())
}

/// Copies `from` to `to` atomically, refusing files over [`MAX_COPY_BYTES`].
fn copy_file(from: &Path, to: &Path) -> Result<()> {
    let len = std::fs::metadata(from)
        .map_err(|e| Error::io(from, e))?
        .len();
    if len > MAX_COPY_BYTES {
        return Err(Error::limit(
            Some(from),
            format!("a file of {len} bytes"),
            format!("{MAX_COPY_BYTES} bytes"),
        ));
    }
    let bytes = crate::fsutil::read(from)?;
    if let Some(dir) = to.parent() {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    crate::fsutil::write_atomic(to, &bytes)
}

/// A relative path inside its folder: no root, no `..`, no drive.
fn is_inside(rel: &str) -> bool {
    let p = Path::new(rel);
    !rel.is_empty()
        && p.components()
            .all(|c| matches!(c, std::path::Component::Normal(_)))
}

/// Copies the model into `out` (`model.glb`, or `model.gltf` with the files its
/// buffers and images name), returning the page's path to it.
fn copy_model(model: &Path, out: &Path) -> Result<String> {
    let ext = model
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("glb") => {
            copy_file(model, &out.join("model.glb"))?;
            Ok("model.glb".into())
        }
        Some("gltf") => {
            let text = crate::fsutil::read_to_string_limited(model, MAX_COPY_BYTES)?;
            let json: serde_json::Value = serde_json::from_str(&text)
                .map_err(|e| Error::format(model, format!("not glTF JSON: {e}")))?;
            let dir = model.parent().unwrap_or(Path::new("."));
            for key in ["buffers", "images"] {
                let items = json.get(key).and_then(|v| v.as_array());
                for item in items.into_iter().flatten() {
                    let Some(uri) = item.get("uri").and_then(|u| u.as_str()) else {
                        continue;
                    };
                    if uri.starts_with("data:") {
                        continue;
                    }
                    if !is_inside(uri) {
                        return Err(Error::unsupported(
                            Some(model),
                            format!("the model names {uri:?}, not a file beside it"),
                        ));
                    }
                    copy_file(&dir.join(uri), &out.join(uri))?;
                }
            }
            copy_file(model, &out.join("model.gltf"))?;
            Ok("model.gltf".into())
        }
        _ => Err(Error::unsupported(
            Some(model),
            "a model must be glTF (.glb or .gltf)",
        )),
    }
}

/// The report, plots and thumbnails of an `eval --report` folder, copied into
/// `out/eval`; the page's paths to them (the report first).
fn copy_eval(eval: &Path, out: &Path) -> Result<Vec<String>> {
    // The report's files and those of its subfolders one level down (the
    // contact sheet's thumbnails), as paths relative to `eval`.
    let mut names = Vec::new();
    let list = |dir: &Path| -> Result<Vec<(String, bool)>> {
        let mut v = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
            let entry = entry.map_err(|e| Error::io(dir, e))?;
            let path = entry.path();
            v.push((
                entry.file_name().to_string_lossy().into_owned(),
                path.is_dir(),
            ));
        }
        Ok(v)
    };
    let keep = |name: &str| {
        [".html", ".png", ".csv", ".json"]
            .iter()
            .any(|e| name.ends_with(e))
    };
    for (name, is_dir) in list(eval)? {
        if is_dir {
            for (inner, inner_dir) in list(&eval.join(&name))? {
                if !inner_dir && inner.ends_with(".png") {
                    names.push(format!("{name}/{inner}"));
                }
            }
        } else if keep(&name) {
            names.push(name);
        }
        if names.len() > MAX_EVAL_FILES {
            break;
        }
    }
    if names.len() > MAX_EVAL_FILES {
        return Err(Error::limit(
            Some(eval),
            format!("{} report files", names.len()),
            format!("{MAX_EVAL_FILES}"),
        ));
    }
    if !names
        .iter()
        .any(|n| n.ends_with(".html") || n.ends_with(".png"))
    {
        return Err(Error::Invalid(format!(
            "{}: no report.html or plot in it; make one with `lumiprobe eval ... --report {}`",
            eval.display(),
            eval.display()
        )));
    }
    names.sort_by_key(|n| (n != "report.html", !n.ends_with(".png"), n.clone()));
    for n in &names {
        copy_file(&eval.join(n), &out.join("eval").join(n))?;
    }
    // The page shows the report's link and its top-level plots.
    Ok(names
        .into_iter()
        .filter(|n| !n.contains('/') && (n.ends_with(".html") || n.ends_with(".png")))
        .map(|n| format!("eval/{n}"))
        .collect())
}

/// Writes the page for `scene`'s predictions in `pred_dir` (a `lumiprobe run`
/// output) into `out_dir`; `view.json` last.
pub fn write_view(
    scene: &Scene,
    pred_dir: &Path,
    out_dir: &Path,
    opts: &ViewOptions,
) -> Result<ViewReport> {
    let probes = out_dir.join("probes");
    let ex = export(
        scene,
        pred_dir,
        &probes,
        &ExportOptions {
            orientation: Orientation::Y,
            formats: if opts.ktx2 {
                vec![ExportFormat::Hdr, ExportFormat::Lights, ExportFormat::Ktx2]
            } else {
                vec![ExportFormat::Hdr, ExportFormat::Lights]
            },
            frames: opts.frames.clone(),
            max_width: Some(opts.max_width),
            ..ExportOptions::default()
        },
    )?;
    let mut warnings = ex.warnings.clone();
    if !ex.missing.is_empty() {
        warnings.push(format!(
            "{} frames have no prediction in {} yet and are not shown",
            ex.missing.len(),
            pred_dir.display()
        ));
    }
    let mut frames = Vec::new();
    for fe in &ex.frames {
        let Some(frame) = scene.frames.iter().find(|f| f.id == fe.id) else {
            continue;
        };
        let probe = format!("probes/{}.hdr", fe.id);
        let img = read_hdr_repaired(&out_dir.join(&probe))?.0;
        let sdr_ext = frame
            .sdr
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("jpg")
            .to_ascii_lowercase();
        let sdr = format!("frames/{}.{sdr_ext}", fe.id);
        copy_file(&frame.sdr, &out_dir.join(&sdr))?;
        let p = frame.pose.position;
        frames.push(ViewFrame {
            id: fe.id.clone(),
            sdr,
            probe,
            residual: format!("probes/{}_residual.hdr", fe.id),
            lights: format!("probes/{}_lights.gltf", fe.id),
            light_count: fe.lights.as_ref().map_or(0, |l| l.lights.len()),
            specular: opts.ktx2.then(|| format!("probes/{}_specular.ktx2", fe.id)),
            position: [p.x, p.z, -p.y],
            exposure: 2f32.powf(crate::tonemap::auto_exposure_ev(&img)),
        });
    }
    if frames.is_empty() {
        return Err(Error::Invalid(format!(
            "{}: no prediction of {}'s frames to show; run `lumiprobe run` first",
            pred_dir.display(),
            scene.name
        )));
    }
    let model = opts
        .model
        .as_deref()
        .map(|m| copy_model(m, out_dir))
        .transpose()?;
    let eval = match &opts.eval {
        Some(e) => copy_eval(e, out_dir)?,
        None => Vec::new(),
    };
    let three_dir = opts.three.clone().or_else(find_three);
    let three = match three_dir {
        Some(dir) => {
            for f in THREE_FILES {
                let src = dir.join(f);
                if !src.is_file() {
                    return Err(Error::Invalid(format!(
                        "{}: not three.js's npm package ({f} is missing)",
                        dir.display()
                    )));
                }
                let rel = f
                    .strip_prefix("examples/jsm/")
                    .map(|r| format!("addons/{r}"))
                    .unwrap_or_else(|| f.replace("build/", ""));
                copy_file(&src, &out_dir.join("vendor").join(rel))?;
            }
            // ktx-parse sits beside three in node_modules.
            let ktx = dir
                .parent()
                .map(|d| d.join("ktx-parse").join(KTX_PARSE_FILE));
            match ktx.filter(|k| k.is_file()) {
                Some(k) => copy_file(&k, &out_dir.join("vendor/ktx-parse.js"))?,
                None if opts.ktx2 => {
                    return Err(Error::Invalid(format!(
                        "{}: npm ktx-parse is not beside three.js (npm ci --prefix tools/js installs both)",
                        dir.display()
                    )))
                }
                None => {}
            }
            "vendor/".to_string()
        }
        None => {
            let cdn = format!("https://cdn.jsdelivr.net/npm/three@{THREE_VERSION}/");
            warnings.push(format!(
                "three.js was not found (npm ci --prefix tools/js installs it): the page loads it from {cdn}"
            ));
            cdn
        }
    };
    let (module, addons, ktx) = if three == "vendor/" {
        (
            "./vendor/three.module.js".to_string(),
            "./vendor/addons/".to_string(),
            "./vendor/ktx-parse.js".to_string(),
        )
    } else {
        (
            format!("{three}build/three.module.js"),
            format!("{three}examples/jsm/"),
            format!("https://cdn.jsdelivr.net/npm/ktx-parse@{KTX_PARSE_VERSION}/{KTX_PARSE_FILE}"),
        )
    };
    let html = INDEX_HTML
        .replace("{{TITLE}}", &html_escape(&scene.name))
        .replace("{{THREE}}", &module)
        .replace("{{ADDONS}}", &addons)
        .replace("{{KTX}}", &ktx);
    crate::fsutil::write_atomic(&out_dir.join("index.html"), html.as_bytes())?;
    crate::fsutil::write_atomic(&out_dir.join("view.js"), VIEW_JS.as_bytes())?;
    let report = ViewReport {
        scene: scene.name.clone(),
        frames,
        model,
        eval,
        three,
        warnings,
    };
    let text = crate::error::to_json(&report)?;
    crate::fsutil::write_atomic(&out_dir.join("view.json"), text.as_bytes())?;
    Ok(report)
}

/// `s` with the characters HTML gives a meaning escaped.
fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_paths_must_stay_beside_the_model() {
        assert!(is_inside("a/b.bin"));
        assert!(!is_inside("../b.bin"));
        assert!(!is_inside("/etc/passwd"));
        assert!(!is_inside(""));
    }
}
