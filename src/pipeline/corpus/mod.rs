//! `lumiprobe corpus`: every method on every scene of one or more corpora, scored
//! with the worst-case statistics of [`crate::eval::summary`], one row per scene
//! and method and totals per split.
//!
//! A root is either
//!
//! * a corpus folder holding `corpus.json`:
//!   `{"generator_version": str, "scenes": [{"name": str, "seed": int, "split":
//!   "dev" | "val", "dir": path relative to the root}]}` (unknown keys ignored), or
//! * a folder of scene folders, each holding a `poses.json` (the evaluation data's
//!   `scenes/`): every such subfolder is a scene of split `shared`, named after
//!   the subfolder; subfolders without a `poses.json` are skipped.
//!
//! A `summary.json` next to a scene's `poses.json` (written by the corpus
//! generator) is read for its `unanswerable_frames` (`[{"id": str, ...}]`): the
//! frames whose light no probe saw, which no method can recover. Every row of
//! such a scene is then also scored over its other frames, as a row
//! `<method>@answerable` ([`super::evaluate::evaluate_apart`]), totals
//! included. Scenes without one (the shared scenes) have no such rows.
//!
//! Every scene's `poses.json` is loaded before anything runs, so a bad root or an
//! invalid `poses.json` stops the command at once with an error naming the file.
//! Each method then runs exactly as `lumiprobe run SCENE --out OUT/<scene>/<method>
//! --method M` with the same settings ([`super::run`]: frames already up to date
//! are kept, so a rerun resumes), and the methods and both baselines are scored
//! by [`super::evaluate::evaluate`] (also written to `OUT/<scene>/eval.json`).
//!
//! Failures: a method that fails (or panics) on a scene is reported as a failed
//! row with its message and the other methods and scenes go on; a scene whose
//! evaluation fails has all its rows failed. The outputs are written in any case,
//! and [`CorpusReport::failed`] lets the caller exit with an error afterwards: a
//! corpus run with a failure is not a success, but one bad scene should not cost
//! the results of the others.
//!
//! Outputs (written atomically): `corpus.txt`, `corpus.csv`, `corpus.json` and
//! `corpus_worst_irradiance.png` (worst-frame irradiance error per scene and
//! method, log y axis).

pub mod bounds;
pub mod report;

pub use report::{to_csv, to_text, totals, worst_irradiance_plot, write_outputs};

use super::evaluate::{evaluate, evaluate_apart, ANSWERABLE, BASELINE_PROBE, BASELINE_SDR};
use super::{run, Method, RunParams};
use crate::error::{Error, Result};
use crate::eval::summary::RowSummary;
use crate::eval::Metrics;
use crate::fsutil::write_atomic;
use crate::scene::Scene;
use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// Which part of a corpus a scene belongs to.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    /// Scenes to develop on.
    Dev,
    /// Held-out scenes.
    Val,
    /// The shared evaluation scenes (a folder of scene folders).
    Shared,
}

impl Split {
    /// The split's name as written in `corpus.json` and the outputs.
    pub fn name(self) -> &'static str {
        match self {
            Split::Dev => "dev",
            Split::Val => "val",
            Split::Shared => "shared",
        }
    }
}

/// One scene found under a root.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorpusScene {
    /// Name (also its output folder under `OUT`).
    pub name: String,
    /// Split.
    pub split: Split,
    /// Generator seed, for corpus scenes.
    pub seed: Option<i64>,
    /// The scene folder (holding `poses.json`).
    pub dir: PathBuf,
}

/// A root and what it said about itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorpusRoot {
    /// The root folder as given.
    pub path: PathBuf,
    /// `generator_version` of its `corpus.json` (none for a folder of scenes).
    pub generator_version: Option<String>,
}

#[derive(Deserialize)]
struct CorpusFile {
    generator_version: String,
    scenes: Vec<CorpusEntry>,
}

#[derive(Deserialize)]
struct CorpusEntry {
    name: String,
    seed: i64,
    split: String,
    dir: String,
}

/// Whether `name` can name an output folder.
fn valid_name(name: &str) -> bool {
    !name.is_empty() && !name.contains(['/', '\\']) && !name.starts_with('.')
}

/// The scenes of one root (module docs), in the order of `corpus.json` or by
/// folder name.
pub fn discover_root(root: &Path) -> Result<(CorpusRoot, Vec<CorpusScene>)> {
    let file = root.join("corpus.json");
    if file.is_file() {
        let text = std::fs::read_to_string(&file).map_err(|e| Error::io(&file, e))?;
        let c: CorpusFile = serde_json::from_str(&text)
            .map_err(|e| Error::format(&file, format!("not a valid corpus description: {e}")))?;
        let mut scenes = Vec::new();
        for e in c.scenes {
            let split = match e.split.as_str() {
                "dev" => Split::Dev,
                "val" => Split::Val,
                s => {
                    return Err(Error::format(
                        &file,
                        format!(
                            "scene {:?}: split {s:?} is neither \"dev\" nor \"val\"",
                            e.name
                        ),
                    ))
                }
            };
            if !valid_name(&e.name) {
                return Err(Error::format(
                    &file,
                    format!("scene name {:?} cannot name an output folder", e.name),
                ));
            }
            scenes.push(CorpusScene {
                name: e.name,
                split,
                seed: Some(e.seed),
                dir: root.join(e.dir),
            });
        }
        if scenes.is_empty() {
            return Err(Error::format(&file, "`scenes` is empty"));
        }
        let info = CorpusRoot {
            path: root.to_path_buf(),
            generator_version: Some(c.generator_version),
        };
        return Ok((info, scenes));
    }
    let entries = std::fs::read_dir(root).map_err(|e| Error::io(root, e))?;
    let mut scenes: Vec<CorpusScene> = entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.join("poses.json").is_file())
        .filter_map(|dir| {
            let name = dir.file_name()?.to_string_lossy().into_owned();
            valid_name(&name).then_some(CorpusScene {
                name,
                split: Split::Shared,
                seed: None,
                dir,
            })
        })
        .collect();
    if scenes.is_empty() {
        return Err(Error::format(
            root,
            "no corpus.json and no scene folder with a poses.json",
        ));
    }
    scenes.sort_by(|a, b| a.name.cmp(&b.name));
    let info = CorpusRoot {
        path: root.to_path_buf(),
        generator_version: None,
    };
    Ok((info, scenes))
}

/// The scenes of all roots; two scenes of the same name are an error (they would
/// share an output folder).
pub fn discover(roots: &[PathBuf]) -> Result<(Vec<CorpusRoot>, Vec<CorpusScene>)> {
    let mut infos = Vec::new();
    let mut all: Vec<CorpusScene> = Vec::new();
    for root in roots {
        let (info, scenes) = discover_root(root)?;
        for s in scenes {
            if let Some(o) = all.iter().find(|o| o.name == s.name) {
                return Err(Error::Invalid(format!(
                    "scene name {:?} appears twice ({} and {}); names must be unique",
                    s.name,
                    o.dir.display(),
                    s.dir.display()
                )));
            }
            all.push(s);
        }
        infos.push(info);
    }
    Ok((infos, all))
}

/// The frames `dir/summary.json` flags as unanswerable (module docs); `None`
/// without that file.
pub fn unanswerable_frames(dir: &Path) -> Result<Option<HashSet<String>>> {
    #[derive(Deserialize)]
    struct Summary {
        #[serde(default)]
        unanswerable_frames: Vec<Flagged>,
    }
    #[derive(Deserialize)]
    struct Flagged {
        id: String,
    }
    let file = dir.join("summary.json");
    if !file.is_file() {
        return Ok(None);
    }
    let text = crate::fsutil::read_to_string_limited(&file, SUMMARY_MAX_BYTES)?;
    let s: Summary = serde_json::from_str(&text)
        .map_err(|e| Error::format(&file, format!("not a valid scene summary: {e}")))?;
    Ok(Some(
        s.unanswerable_frames.into_iter().map(|f| f.id).collect(),
    ))
}

/// Largest `summary.json` read (a scene of thousands of frames is well under).
const SUMMARY_MAX_BYTES: u64 = 64 << 20;

/// What to run on each scene.
#[derive(Clone, Debug)]
pub struct CorpusOptions {
    /// Methods, in table order.
    pub methods: Vec<Method>,
    /// Settings of each run; `method` is replaced by each of `methods`.
    pub params: RunParams,
    /// Only scenes of these splits (all when empty): settings are chosen on the
    /// development scenes and reported on the validation ones.
    pub splits: Vec<Split>,
}

/// One `(scene, method or baseline)` row.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorpusRow {
    /// Scene name.
    pub scene: String,
    /// The scene's split.
    pub split: Split,
    /// The scene's generator seed.
    pub seed: Option<i64>,
    /// Method or baseline label.
    pub method: String,
    /// Frames scored.
    pub frames: usize,
    /// Why the row failed; `None` when it was scored.
    pub error: Option<String>,
    /// Mean scores.
    pub mean: Option<Metrics>,
    /// Worst-case statistics over the scene's frames.
    pub tail: Option<RowSummary>,
}

/// Totals of one method over the scenes of one split. In [`CorpusTotal::tail`]
/// each metric's `mean` is the mean over scenes of the scene means, `p95` the mean
/// over scenes of the scene p95s, `worst` the worst over scenes of the scene
/// worsts with `worst_frame` written `scene/frame`; the frame counts over the
/// SDR baseline are summed; flicker `mean` is the mean of the scene means and its
/// `worst` the worst over scenes (`pairs` summed).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorpusTotal {
    /// Split.
    pub split: Split,
    /// Method or baseline label.
    pub method: String,
    /// Scenes scored.
    pub scenes: usize,
    /// Scenes whose row failed.
    pub failed: usize,
    /// Frames scored over those scenes.
    pub frames: usize,
    /// The statistics (see the type's docs for how scenes are combined).
    pub tail: RowSummary,
}

/// Everything `lumiprobe corpus` reports (`corpus.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorpusReport {
    /// The roots.
    pub roots: Vec<CorpusRoot>,
    /// The scenes, in row order.
    pub scenes: Vec<CorpusScene>,
    /// Methods run (baselines are added to the rows).
    pub methods: Vec<String>,
    /// Working size of the runs, when not the frames' own.
    pub size: Option<(usize, usize)>,
    /// One row per scene and method or baseline.
    pub rows: Vec<CorpusRow>,
    /// One row per split and method or baseline.
    pub totals: Vec<CorpusTotal>,
}

impl CorpusReport {
    /// The rows that failed.
    pub fn failed(&self) -> Vec<&CorpusRow> {
        self.rows.iter().filter(|r| r.error.is_some()).collect()
    }
}

/// A method's name as on the command line.
pub fn method_name(m: Method) -> String {
    format!("{m:?}").to_lowercase()
}

/// `f`'s result, with an error or a panic turned into a one-line message.
fn guarded<T>(f: impl FnOnce() -> Result<T>) -> std::result::Result<T, String> {
    let one_line = |s: String| s.split_whitespace().collect::<Vec<_>>().join(" ");
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(one_line(e.to_string())),
        Err(p) => {
            let msg = p
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "no message".into());
            Err(one_line(format!("panicked: {msg}")))
        }
    }
}

/// Runs every method on every scene of `roots` into `out/<scene>/<method>`,
/// scores them, and writes the corpus outputs (module docs). `log` gets one line
/// per step, `progress` the frames of each run. Fails only on a bad root or scene
/// description, or when an output cannot be written.
pub fn run_corpus(
    roots: &[PathBuf],
    out: &Path,
    opts: &CorpusOptions,
    log: &dyn Fn(&str),
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<CorpusReport> {
    let (infos, mut scenes) = discover(roots)?;
    if !opts.splits.is_empty() {
        scenes.retain(|s| opts.splits.contains(&s.split));
        if scenes.is_empty() {
            return Err(Error::Invalid(format!(
                "no scene of the corpora is in the splits asked for ({})",
                opts.splits
                    .iter()
                    .map(|s| s.name())
                    .collect::<Vec<_>>()
                    .join(", ")
            )));
        }
    }
    let loaded: Vec<Scene> = scenes
        .iter()
        .map(|s| Scene::load(&s.dir))
        .collect::<Result<_>>()?;
    let flagged: Vec<Option<HashSet<String>>> = scenes
        .iter()
        .map(|s| unanswerable_frames(&s.dir))
        .collect::<Result<_>>()?;
    let mut methods: Vec<Method> = Vec::new();
    for &m in &opts.methods {
        if !methods.contains(&m) {
            methods.push(m);
        }
    }
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let mut rows = Vec::new();
    for ((cs, scene), flagged) in scenes.iter().zip(&loaded).zip(&flagged) {
        let row = |method: &str, error: Option<String>| CorpusRow {
            scene: cs.name.clone(),
            split: cs.split,
            seed: cs.seed,
            method: method.to_string(),
            frames: 0,
            error,
            mean: None,
            tail: None,
        };
        for w in &scene.warnings {
            log(&format!("{}: warning: {w}", cs.name));
        }
        let mut ran: Vec<(String, PathBuf)> = Vec::new();
        let mut scene_rows: Vec<CorpusRow> = Vec::new();
        for &m in &methods {
            let name = method_name(m);
            let dir = out.join(&cs.name).join(&name);
            log(&format!("{} ({}): {name}", cs.name, cs.split.name()));
            let params = RunParams {
                method: m,
                ..opts.params.clone()
            };
            let error = match guarded(|| run(scene, &dir, &params, progress)) {
                Ok(_) => {
                    ran.push((name.clone(), dir));
                    None
                }
                Err(e) => {
                    log(&format!(
                        "{} ({}): {name} failed: {e}",
                        cs.name,
                        cs.split.name()
                    ));
                    Some(format!("run: {e}"))
                }
            };
            scene_rows.push(row(&name, error));
        }
        for b in [BASELINE_PROBE, BASELINE_SDR] {
            scene_rows.push(row(b, None));
        }
        // The same rows over the answerable frames, where the scene says which.
        if flagged.is_some() {
            let apart: Vec<CorpusRow> = scene_rows
                .iter()
                .map(|r| CorpusRow {
                    method: format!("{}{ANSWERABLE}", r.method),
                    ..r.clone()
                })
                .collect();
            scene_rows.extend(apart);
        }
        log(&format!("{} ({}): scoring", cs.name, cs.split.name()));
        let refs: Vec<(String, &Path)> =
            ran.iter().map(|(l, d)| (l.clone(), d.as_path())).collect();
        let scored = guarded(|| {
            let ev = match flagged {
                Some(f) => evaluate_apart(scene, &refs, f)?,
                None => evaluate(scene, &refs)?,
            };
            let js = crate::error::to_json(&ev)?.into_bytes();
            write_atomic(&out.join(&cs.name).join("eval.json"), &js)?;
            Ok(ev)
        });
        // Rows of methods whose run failed keep that message.
        for r in scene_rows.iter_mut().filter(|r| r.error.is_none()) {
            match &scored {
                Ok(ev) => match ev.table.rows.iter().find(|t| t.label == r.method) {
                    Some(t) => {
                        r.frames = t.frames;
                        r.mean = t.mean;
                        r.tail = t.tail.clone();
                    }
                    // Every frame of the scene is unanswerable: nothing to score.
                    None if r.method.ends_with(ANSWERABLE) => r.frames = 0,
                    None => r.error = Some("evaluation: no such row".into()),
                },
                Err(e) => r.error = Some(format!("evaluation: {e}")),
            }
        }
        rows.extend(scene_rows);
    }
    let report = CorpusReport {
        roots: infos,
        scenes,
        methods: methods.iter().map(|&m| method_name(m)).collect(),
        size: opts.params.size,
        totals: totals(&rows),
        rows,
    };
    write_outputs(out, &report)?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(p: &Path, text: &str) {
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    }

    #[test]
    fn roots_are_corpus_files_or_folders_of_scenes() {
        let tmp = tempfile::tempdir().unwrap();
        let c = tmp.path().join("c");
        write(
            &c.join("corpus.json"),
            r#"{"generator_version": "g1", "extra": 1, "scenes": [
                {"name": "b", "seed": 7, "split": "val", "dir": "scenes/b"},
                {"name": "a", "seed": 3, "split": "dev", "dir": "scenes/a"}]}"#,
        );
        let (info, scenes) = discover_root(&c).unwrap();
        assert_eq!(info.generator_version.as_deref(), Some("g1"));
        assert_eq!(scenes[0].name, "b", "corpus order is kept");
        assert_eq!((scenes[0].split, scenes[0].seed), (Split::Val, Some(7)));
        assert_eq!(scenes[1].dir, c.join("scenes/a"));
        let s = tmp.path().join("s");
        write(&s.join("kitchen/poses.json"), "{}");
        write(&s.join("flat/poses.json"), "{}");
        write(&s.join("models/readme.txt"), "");
        let (info, scenes) = discover_root(&s).unwrap();
        assert_eq!(info.generator_version, None);
        let names: Vec<&str> = scenes.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["flat", "kitchen"]);
        assert!(scenes.iter().all(|s| s.split == Split::Shared));
        // The same scene twice is an error.
        let e = discover(&[s.clone(), s.clone()]).unwrap_err().to_string();
        assert!(e.contains("appears twice"), "{e}");
    }

    #[test]
    fn bad_roots_name_their_file() {
        let tmp = tempfile::tempdir().unwrap();
        let empty = tmp.path().join("empty");
        std::fs::create_dir_all(&empty).unwrap();
        let e = discover_root(&empty).unwrap_err().to_string();
        assert!(e.contains("empty") && e.contains("no corpus.json"), "{e}");
        assert!(!e.contains('\n'));
        let bad = tmp.path().join("bad");
        for (text, want) in [
            ("{", "not a valid corpus description"),
            (r#"{"generator_version": "g", "scenes": []}"#, "empty"),
            (
                r#"{"generator_version": "g", "scenes": [{"name": "a", "seed": 1, "split": "test", "dir": "a"}]}"#,
                "split \"test\"",
            ),
            (
                r#"{"generator_version": "g", "scenes": [{"name": "../a", "seed": 1, "split": "dev", "dir": "a"}]}"#,
                "cannot name",
            ),
        ] {
            write(&bad.join("corpus.json"), text);
            let e = discover_root(&bad).unwrap_err().to_string();
            assert!(e.contains("corpus.json") && e.contains(want), "{e}");
        }
        assert!(discover_root(&tmp.path().join("missing")).is_err());
    }
}
