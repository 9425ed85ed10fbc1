//! Running a method over every frame of a scene: choosing each frame's probe,
//! loading what it needs once, writing one EXR per frame and a report, and resuming
//! an interrupted run without redoing finished frames.

pub mod bench;
pub mod composite;
pub mod corpus;
pub mod demo;
pub mod evaluate;
pub mod export;
pub mod memory;
pub mod plan;
pub mod probe_set;
pub mod render_eval;
pub mod report_html;
pub mod sweep;
pub mod view;
mod walk;

use crate::error::{Error, Result};
use crate::flow::method::{
    flow_frame_scaled, restore_warped_lights, FlowMethodParams, FlowReport, RotatedSource,
};
use crate::fusion::lights::{pair_lights, PairLights, Witness};
use crate::fusion::{
    fuse_with_lights,
    walk::{Mend, WalkMode},
    Evidence, FusionParams, FusionReport, Measured, ProbeEvidence,
};
use crate::image::{io, HdrImage, SdrImage};
use crate::scene::{distance_m, Frame, Scene};
use crate::warp::{self, PreparedProbe, WarpParams, WarpReport};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

/// Methods that predict a probe per frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Per-face feature homographies (thesis Part II).
    Warp,
    /// Optical flow from the two neighbouring probes, fused by a graph cut (thesis Part I).
    Flow,
    /// The two neighbours first warped by the warp method, then fused by the flow
    /// method (thesis Fig. 5.11d).
    Hybrid,
    /// The calibrated SDR frame wherever it did not clip, with the light of its
    /// clipped regions transferred from the `fusion_base` method's output.
    Fusion,
}

impl Method {
    /// How many probes (nearest first) the method uses per frame.
    pub fn probes_needed(self) -> usize {
        match self {
            Method::Warp => 1,
            Method::Flow | Method::Hybrid | Method::Fusion => 2,
        }
    }

    /// The method's name as the command line spells it.
    pub fn name(self) -> &'static str {
        match self {
            Method::Warp => "warp",
            Method::Flow => "flow",
            Method::Hybrid => "hybrid",
            Method::Fusion => "fusion",
        }
    }
}

/// Settings of a run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunParams {
    /// The method.
    pub method: Method,
    /// Working and output size; `None` keeps the frames' own size.
    pub size: Option<(usize, usize)>,
    /// Warp-method settings.
    pub warp: WarpParams,
    /// Flow-method settings.
    pub flow: FlowMethodParams,
    /// Fusion settings.
    pub fusion: FusionParams,
    /// The method whose output fills the clipped regions in [`Method::Fusion`].
    pub fusion_base: Method,
    /// Compression of the per-frame EXR outputs. Not part of a frame's fingerprint:
    /// it changes the file, not the radiance.
    #[serde(skip)]
    pub exr_compression: crate::image::io::ExrCompression,
    /// Most memory (bytes) the frames in flight and the probes may take
    /// ([`memory`]); `None`: [`memory::default_limit`]. Not part of a frame's
    /// fingerprint: it changes how many frames run at once, not their output.
    #[serde(skip)]
    pub memory_limit: Option<u64>,
}

impl RunParams {
    /// How many probes (nearest first) a frame uses: the method's, and for fusion
    /// also the probes in which far sources are looked up.
    pub fn probes_needed(&self) -> usize {
        match self.method {
            Method::Fusion => self
                .fusion
                .far_probes
                .max(self.fusion_base.probes_needed())
                .max(2),
            m => m.probes_needed(),
        }
    }

    /// Whether the run matches features against the probes: the warp and
    /// hybrid methods, as the method or as fusion's base.
    pub fn matches_features(&self) -> bool {
        match self.method {
            Method::Warp | Method::Hybrid => true,
            Method::Fusion => matches!(self.fusion_base, Method::Warp | Method::Hybrid),
            Method::Flow => false,
        }
    }
}

impl RunParams {
    /// These settings with `KEY=VALUE` assignments applied, keys being paths into
    /// the settings as serialized (`fusion.max_angle_deg=5`, `flow.censor.clip_code=245`)
    /// and values JSON (a bare word is taken as a string). For sweeping a constant
    /// over a corpus without a flag for each.
    pub fn with_settings(&self, assignments: &[String]) -> Result<RunParams> {
        let mut tree = serde_json::to_value(self)
            .map_err(|e| Error::Invalid(format!("settings cannot be serialized: {e}")))?;
        for a in assignments {
            let Some((key, value)) = a.split_once('=') else {
                return Err(Error::Invalid(format!(
                    "--set {a:?}: expected KEY=VALUE, e.g. fusion.max_angle_deg=5"
                )));
            };
            let value: serde_json::Value = serde_json::from_str(value)
                .unwrap_or_else(|_| serde_json::Value::String(value.to_string()));
            let mut node = &mut tree;
            for part in key.split('.') {
                node = match node.get_mut(part) {
                    Some(n) => n,
                    None => {
                        return Err(Error::Invalid(format!(
                            "--set {a:?}: there is no setting {key:?} (no {part:?} there)"
                        )))
                    }
                };
            }
            *node = value;
        }
        let mut out: RunParams =
            serde_json::from_value(tree).map_err(|e| Error::Invalid(format!("--set: {e}")))?;
        out.exr_compression = self.exr_compression;
        out.memory_limit = self.memory_limit;
        Ok(out)
    }
}

impl Default for RunParams {
    fn default() -> Self {
        RunParams {
            method: Method::Warp,
            size: None,
            warp: WarpParams::default(),
            flow: FlowMethodParams::default(),
            fusion: FusionParams::default(),
            fusion_base: Method::Flow,
            exr_compression: Default::default(),
            memory_limit: None,
        }
    }
}

/// What was done for one frame.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FrameRecord {
    /// Frame id (the output is `<id>.exr`).
    pub id: String,
    /// The probe used.
    pub probe: String,
    /// Distance from the frame to that probe in metres.
    pub probe_distance_m: f32,
    /// All probes the method used, nearest first.
    pub probes: Vec<String>,
    /// Warp-method details (for the hybrid, those of the nearest probe).
    pub warp: Option<WarpReport>,
    /// Flow-method details.
    pub flow: Option<FlowReport>,
    /// Fusion details.
    #[serde(default)]
    pub fusion: Option<FusionReport>,
    /// Time for the whole frame, loading excluded, in milliseconds.
    pub total_ms: f64,
    /// Samples of the probes used that were NaN, infinite or negative and were
    /// repaired on loading (see [`load_probe`]).
    pub repaired_pixels: usize,
    /// Fingerprint of inputs and settings, used to resume.
    pub fingerprint: String,
}

/// The report of a run (`report.json`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunReport {
    /// Scene name.
    pub scene: String,
    /// What the probes' and the outputs' radiance is measured in.
    #[serde(default)]
    pub probe_unit: String,
    /// Settings used.
    pub params: RunParams,
    /// The lens vignetting divided out of the frames (`1 - k rim`,
    /// [`crate::capture::vignetting`]), when one was fitted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vignetting: Option<f32>,
    /// One record per frame, in walk order.
    pub frames: Vec<FrameRecord>,
    /// Frames skipped because their outputs were already up to date.
    pub resumed: Vec<String>,
    /// Loader and method warnings.
    pub warnings: Vec<String>,
}

/// Notes, once per run, a frame that is not a 2:1 panorama and a frame whose
/// size differs from its probe's (at the working size).
fn note_sizes(
    noted: &Mutex<Vec<String>>,
    frame: &Frame,
    (w, h): (usize, usize),
    probe: (usize, usize),
) {
    let mut found = Vec::new();
    if w != 2 * h {
        found.push(format!(
            "{}: {w}x{h} is not a 2:1 equirectangular panorama; it is read as one \
             (give --size WxH to resample every frame to 2:1)",
            frame.sdr.display()
        ));
    }
    if (w, h) != probe {
        found.push(format!(
            "{}: the frame is {w}x{h} but its probe is {}x{} (give --size WxH to work \
             at one size)",
            frame.sdr.display(),
            probe.0,
            probe.1
        ));
    }
    if found.is_empty() {
        return;
    }
    if let Ok(mut n) = noted.lock() {
        for f in found {
            // One note per kind: the first frame named.
            let kind = |s: &str| s.contains("2:1");
            if !n.iter().any(|x| kind(x) == kind(&f)) {
                n.push(f);
            }
        }
    }
}

/// Reads an SDR frame and resamples it to the working size.
pub fn load_frame(frame: &Frame, size: Option<(usize, usize)>) -> Result<SdrImage> {
    let sdr = io::read_sdr(&frame.sdr)?;
    if sdr.width() < 8 || sdr.height() < 4 {
        return Err(Error::format(
            &frame.sdr,
            format!("panorama of {}x{} is too small", sdr.width(), sdr.height()),
        ));
    }
    Ok(match size {
        Some((w, h)) if (w, h) != (sdr.width(), sdr.height()) => resize_sdr(&sdr, w, h),
        _ => sdr,
    })
}

/// Resamples an 8-bit panorama (bilinear on codes, seam- and pole-aware).
pub fn resize_sdr(sdr: &SdrImage, w: usize, h: usize) -> SdrImage {
    let disp = warp::sdr_display(sdr);
    let r = crate::sphere::resize(&disp, w, h);
    SdrImage::from_vec(w, h, crate::tonemap::quantize(r.data())).expect("size matches")
}

/// Radiance of an SDR frame: `response⁻¹(code / 255) / gain`, with `frame`'s own
/// gain per channel where it has one (clipped pixels stay at the white point's
/// radiance), divided by the scene's lens falloff when it has one (a clipped
/// pixel then bounds its radiance from below at the white point over the
/// falloff).
pub fn linearize(sdr: &SdrImage, scene: &Scene, frame: &Frame) -> HdrImage {
    let mut lin = match frame.gain {
        None => io::sdr_to_linear(sdr, &scene.response, scene.path_gain),
        Some(g) => io::sdr_to_linear_rgb(sdr, &scene.response, g),
    };
    if let Some(k) = scene.vignetting {
        crate::capture::vignetting::divide_out(&mut lin, k);
    }
    lin
}

/// Without a working size every frame of the walk must have the first frame's
/// size: the walk pass and the far sources' witnesses compare neighbouring
/// frames, and a walk whose frames differ is most often frames of two cameras
/// or exports mixed in one folder. Read from the files' headers before any
/// frame is computed, so a refused run writes nothing. Fails naming the first
/// frame that differs and the first frame.
pub(crate) fn one_frame_size(scene: &Scene) -> Result<(usize, usize)> {
    let mut first: Option<(&Path, (usize, usize))> = None;
    for f in &scene.frames {
        let d = io::sdr_dimensions(&f.sdr)?;
        match first {
            None => first = Some((&f.sdr, d)),
            Some((p, d0)) if d != d0 => {
                return Err(Error::Invalid(format!(
                    "{}: the frame is {}x{} but the walk's first frame {} is {}x{}; a walk's \
                     frames must share one size (give --size WxH to resample every frame \
                     to it)",
                    f.sdr.display(),
                    d.0,
                    d.1,
                    p.display(),
                    d0.0,
                    d0.1
                )))
            }
            Some(_) => {}
        }
    }
    Ok(first.map_or((0, 0), |(_, d)| d))
}

/// Reads a probe's HDR panorama, repairs invalid samples and resamples it down
/// to `size` when it is larger. A probe smaller than `size` keeps its own
/// pixels: every method reads probes through a rotation at any size, an
/// upsampled copy holds nothing a bilinear read of the probe does not, and at
/// 7776x3888 it would take 360 MB per probe (fusion reads up to
/// `fusion.far_probes` of them per frame). The ledger's ceiling then scales
/// the probes' peak from their own pixel size, as for any smaller probe.
pub fn load_probe(
    scene: &Scene,
    i: usize,
    size: Option<(usize, usize)>,
) -> Result<(HdrImage, usize)> {
    let p = &scene.probes[i];
    let path = p.hdr.as_ref().ok_or_else(|| {
        Error::Invalid(format!(
            "probe {} has no HDR file (merge its brackets first)",
            p.id
        ))
    })?;
    let mut img = io::read_hdr(path)?;
    let repaired = img.repair_invalid();
    if let Some((w, h)) = size {
        // Each side only ever shrinks.
        let (tw, th) = (w.min(img.width()), h.min(img.height()));
        if (tw, th) != (img.width(), img.height()) {
            img = crate::sphere::resize(&img, tw, th);
        }
    }
    Ok((img, repaired))
}

/// Identifies a file's version for cache keys: its canonical path (however the
/// command spelled it: relative, absolute, through a link), size and
/// modification time.
pub(crate) fn file_stamp(p: &Path) -> String {
    let canonical = p.canonicalize();
    let shown = canonical.as_deref().unwrap_or(p);
    match std::fs::metadata(p) {
        Ok(m) => format!("{}:{}", shown.display(), size_and_time(&m)),
        Err(_) => format!("{}:missing", shown.display()),
    }
}

/// A file's size and modification time, as stamps hold them.
fn size_and_time(m: &std::fs::Metadata) -> String {
    format!("{}:{:?}", m.len(), m.modified().ok())
}

/// FNV-1a 64 of the parts as 16 hex digits: a key for resume checks and caches.
pub(crate) fn fingerprint(parts: &[String]) -> String {
    // FNV-1a 64: stable across runs and platforms.
    let mut h: u64 = 0xcbf29ce484222325;
    for s in parts {
        for b in s.bytes().chain(std::iter::once(0u8)) {
            h ^= b as u64;
            h = h.wrapping_mul(0x100000001b3);
        }
    }
    format!("{h:016x}")
}

/// The program that computes the frames: its version and the running executable's
/// size and modification time, so that a rebuilt or upgraded lumiprobe recomputes
/// frames an older build made instead of keeping them (the version alone does not
/// change between builds). Read once, without reading the file. Through the C ABI
/// the executable is the host program: there a rebuilt library of the same version
/// keeps earlier frames (remove them to recompute), and a changed host recomputes
/// them. The version alone when the executable cannot be found.
fn program_stamp() -> &'static str {
    static STAMP: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    STAMP.get_or_init(|| {
        let version = env!("CARGO_PKG_VERSION");
        match std::env::current_exe().and_then(std::fs::metadata) {
            Ok(m) => format!("{version} {}", size_and_time(&m)),
            Err(_) => version.to_string(),
        }
    })
}

/// The probes `frame` uses (nearest first) and the fingerprint of everything its
/// output depends on: settings, the frame's file, pose and radiometry, the probes'
/// files and poses, and the program build ([`program_stamp`]).
fn frame_inputs(
    scene: &Scene,
    index: usize,
    params: &RunParams,
    settings: &str,
) -> (Vec<usize>, String) {
    let frame = &scene.frames[index];
    let mut used = scene.probes_by_distance(frame.pose.position);
    used.truncate(params.probes_needed());
    let mut parts = vec![
        settings.to_string(),
        file_stamp(&frame.sdr),
        format!("{:?}", frame.pose),
        // The frame's radiometry: a new response or gain changes every pixel.
        format!("{:?} {} {:?}", scene.response, scene.path_gain, frame.gain),
        program_stamp().to_string(),
    ];
    if let Some(k) = scene.vignetting {
        parts.push(format!("vignetting {k}"));
    }
    for &u in &used {
        let m = &scene.probes[u];
        parts.push(m.hdr.as_deref().map(file_stamp).unwrap_or_default());
        parts.push(format!("{:?}", m.pose));
    }
    for n in witness_frames(scene, index, params) {
        parts.push(file_stamp(&n.sdr));
        parts.push(format!("{:?}", n.pose));
    }
    (used, fingerprint(&parts))
}

/// The frames that witness the far sources of frame `i` of the walk
/// (`fusion.far_witness_m`): the one before it and the one after it, when
/// within that distance.
fn witness_frames<'s>(scene: &'s Scene, i: usize, params: &RunParams) -> Vec<&'s Frame> {
    let reach = params.fusion.far_witness_m;
    let Some(frame) = scene.frames.get(i) else {
        return Vec::new();
    };
    if params.method != Method::Fusion || !(reach > 0.0) {
        return Vec::new();
    }
    [i.checked_sub(1), Some(i + 1)]
        .into_iter()
        .flatten()
        .filter_map(|j| scene.frames.get(j))
        .filter(|n| n.pose.position.distance(frame.pose.position) <= reach)
        .collect()
}

/// The white point the probes' lights and evidence are found above, shared by
/// frames through [`LightPairs`]: the frame's own white point on a walk with one
/// gain; with each frame's own gain, the nearest of a ladder of 1/16 EV steps
/// (within 2.2% of the frame's), so frames of similar exposure share their
/// lights, the cache stays bounded, and no frame's lights depend on which frame
/// came first (they did: the first frame's white point served every frame).
fn light_white(white: f32, own_gain: bool) -> f32 {
    if !own_gain || !(white.is_finite() && white > 0.0) {
        return white;
    }
    (2.0f32).powf((white.log2() * 16.0).round() / 16.0)
}

/// Radiance of the clip code in the frames' linearised units: the least a
/// clipped channel holds.
fn white_point(scene: &Scene, frame: &Frame, params: &RunParams) -> f32 {
    scene
        .response
        .decode(params.flow.censor.clip_code as f32 / 255.0)
        / scene.frame_luminance_gain(frame)
}

/// The frames `run` read last, at the working size: a frame is read for
/// itself and, as a witness, for the frame on either side, and with frames
/// taken in walk order those reads come close together. Each is decoded and
/// resampled once instead of three times (at 7776x3888 a resampled frame takes
/// 91 MB and about half a second). Holds at most `cap` frames, the oldest
/// dropped first; two workers missing the same frame at once both read it.
struct FrameCache {
    slots: Mutex<std::collections::VecDeque<(PathBuf, Arc<SdrImage>)>>,
    cap: usize,
}

impl FrameCache {
    fn new(cap: usize) -> Self {
        FrameCache {
            slots: Mutex::new(std::collections::VecDeque::new()),
            cap: cap.max(1),
        }
    }

    /// Frame `f` at `size`, from the cache or read (and kept).
    fn get(&self, f: &Frame, size: Option<(usize, usize)>) -> Result<Arc<SdrImage>> {
        if let Ok(slots) = self.slots.lock() {
            if let Some((_, img)) = slots.iter().find(|(p, _)| *p == f.sdr) {
                return Ok(img.clone());
            }
        }
        let img = Arc::new(load_frame(f, size)?);
        if let Ok(mut slots) = self.slots.lock() {
            if !slots.iter().any(|(p, _)| *p == f.sdr) {
                slots.push_back((f.sdr.clone(), img.clone()));
                while slots.len() > self.cap {
                    slots.pop_front();
                }
            }
        }
        Ok(img)
    }
}

/// The witnesses of frame `i` at the working size, read from their codes
/// (the frames' radiance per code, as [`linearize`] gives it); a witness that
/// cannot be read is left out (its own frame reports the error). `load` reads
/// a frame at the working size (through `run`'s [`FrameCache`]).
fn load_witnesses(
    scene: &Scene,
    i: usize,
    params: &RunParams,
    load: &dyn Fn(&Frame) -> Result<Arc<SdrImage>>,
) -> Vec<Witness> {
    let frames = witness_frames(scene, i, params);
    if frames.is_empty() {
        return Vec::new();
    }
    let white = white_point(scene, &scene.frames[i], params);
    frames
        .into_iter()
        .filter_map(|n| {
            let sdr = load(n).ok()?;
            let g = scene.frame_luminance_gain(n);
            let radiance = scene.response.decode_lut().map(|v| v / g);
            Some(Witness::from_codes(&sdr, &radiance, white, n.pose))
        })
        .collect()
}

/// The frame's record when its probe and sidecar in `out_dir` are both present
/// and were made from inputs with fingerprint `fp`.
fn up_to_date(out_dir: &Path, frame: &Frame, fp: &str) -> Option<FrameRecord> {
    let out = out_dir.join(format!("{}.exr", frame.id));
    let side = out_dir.join(format!("{}.json", frame.id));
    if !out.exists() {
        return None;
    }
    let text = std::fs::read_to_string(&side).ok()?;
    let rec = serde_json::from_str::<FrameRecord>(&text).ok()?;
    (rec.fingerprint == fp).then_some(rec)
}

/// Ids of the frames `run` would compute (outputs missing or out of date); the
/// others it would keep.
pub fn pending_frames(scene: &Scene, out_dir: &Path, params: &RunParams) -> Result<Vec<String>> {
    let settings =
        serde_json::to_string(params).map_err(|e| Error::Internal(format!("settings: {e}")))?;
    Ok(scene
        .frames
        .iter()
        .enumerate()
        .filter(|&(i, f)| {
            let (_, fp) = frame_inputs(scene, i, params, &settings);
            up_to_date(out_dir, f, &fp).is_none()
        })
        .map(|(_, f)| f.id.clone())
        .collect())
}

/// How many frames `run` computes at once ([`memory::plan`]) when `frames`
/// frames of `frame` pixels are to be computed with the probes some
/// `remaining` frame still uses loaded: each at its own size read from its OpenEXR header, no
/// larger than the working size when one is given (`load_probe`); other
/// formats count at the frame's size.
fn memory_plan(
    scene: &Scene,
    params: &RunParams,
    remaining: &[AtomicUsize],
    (fw, fh): (usize, usize),
    threads: usize,
    frames: usize,
) -> memory::Plan {
    let probes_px: u64 = scene
        .probes
        .iter()
        .zip(remaining)
        .filter(|(_, n)| n.load(Ordering::SeqCst) > 0)
        .map(|(p, _)| {
            let own = p.hdr.as_deref().and_then(io::hdr_size_hint);
            let (w, h) = match (own, params.size) {
                (Some((w, h)), Some((sw, sh))) => (w.min(sw), h.min(sh)),
                (Some(d), None) => d,
                (None, _) => (fw, fh),
            };
            (w as u64).saturating_mul(h as u64)
        })
        .fold(0u64, u64::saturating_add);
    let limit = params.memory_limit.unwrap_or_else(memory::default_limit);
    memory::plan(
        params.method,
        (fw as u64).saturating_mul(fh as u64),
        probes_px,
        params.matches_features(),
        threads,
        frames,
        limit,
    )
}

/// Runs the configured method over every frame of `scene`, writing
/// `out_dir/<frame id>.exr`, a sidecar `<frame id>.json` per frame and
/// `out_dir/report.json`. Frames whose outputs match the current inputs and
/// settings are kept as they are. `progress(done, total)` is called per frame.
pub fn run(
    scene: &Scene,
    out_dir: &Path,
    params: &RunParams,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<RunReport> {
    run_named(scene, out_dir, params, progress, "report.json", None)
}

fn run_named(
    scene: &Scene,
    out_dir: &Path,
    params: &RunParams,
    progress: &(dyn Fn(usize, usize) + Sync),
    report_name: &str,
    shard: Option<(usize, usize)>,
) -> Result<RunReport> {
    // A shard computes every `count`-th frame of the whole walk (whose
    // neighbours, not the shard's, witness its far sources); the walk as one
    // sequence needs every frame.
    let mine = |i: usize| shard.map_or(true, |(k, c)| i % c == k);
    let whole_walk = shard.map_or(true, |(_, c)| c == 1);
    let (fw, fh) = match params.size {
        Some(s) => s,
        None => one_frame_size(scene)?,
    };
    use rayon::prelude::*;
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    crate::fsutil::remove_stale_temps(out_dir);
    crate::cv::set_num_threads(1);
    let settings =
        serde_json::to_string(params).map_err(|e| Error::Internal(format!("settings: {e}")))?;
    // Per frame: the probes it uses, its fingerprint, and its record when its
    // outputs are already up to date.
    let inputs: Vec<(Vec<usize>, String, Option<FrameRecord>)> = scene
        .frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let (used, fp) = frame_inputs(scene, i, params, &settings);
            let kept = if mine(i) {
                up_to_date(out_dir, f, &fp)
            } else {
                None
            };
            (used, fp, kept)
        })
        .collect();
    // A probe is loaded when a frame first needs it and dropped once no frame left
    // to compute needs it, so memory does not grow with the number of probes (at
    // 7776 x 3888 each takes 360 MB).
    let remaining: Vec<AtomicUsize> = scene.probes.iter().map(|_| AtomicUsize::new(0)).collect();
    for (i, (used, _, kept)) in inputs.iter().enumerate() {
        if kept.is_none() && mine(i) {
            for &u in used {
                remaining[u].fetch_add(1, Ordering::SeqCst);
            }
        }
    }
    type Slot = Mutex<Option<std::result::Result<(Arc<PreparedProbe>, usize), String>>>;
    let probes: Vec<Slot> = scene.probes.iter().map(|_| Mutex::new(None)).collect();
    let get_probe = |i: usize| -> Result<(Arc<PreparedProbe>, usize)> {
        let mut slot = probes[i]
            .lock()
            .map_err(|_| Error::Invalid("probe cache poisoned".into()))?;
        slot.get_or_insert_with(|| {
            load_probe(scene, i, params.size)
                .map(|(img, rep)| {
                    let pp = PreparedProbe::new(
                        Arc::new(img),
                        scene.probes[i].pose,
                        params.warp.probe_tonemap,
                        &scene.response,
                        scene.path_gain,
                    );
                    (Arc::new(pp), rep)
                })
                .map_err(|e| e.to_string())
        })
        .clone()
        .map_err(Error::Invalid)
    };
    let release = |used: &[usize]| {
        for &u in used {
            if remaining[u].fetch_sub(1, Ordering::SeqCst) == 1 {
                if let Ok(mut slot) = probes[u].lock() {
                    *slot = None;
                }
            }
        }
    };
    let done = AtomicUsize::new(0);
    let total = (0..scene.frames.len()).filter(|&i| mine(i)).count();
    // Fewer frames to compute than workers (one frame of a large panorama):
    // the idle threads help compress.
    let pending = inputs
        .iter()
        .enumerate()
        .filter(|(i, (_, _, kept))| kept.is_none() && mine(*i))
        .count();
    let threads = rayon::current_num_threads();
    let mem = memory_plan(scene, params, &remaining, (fw, fh), threads, pending);
    let workers = mem.workers;
    let exr = io::ExrWriteOptions {
        compression: params.exr_compression,
        parallel: Some(pending.min(workers) < threads),
        ..Default::default()
    };
    let pairs = LightPairs::default();
    let access = ProbeAccess {
        get: &get_probe,
        pairs: &pairs,
    };
    let noted: Mutex<Vec<String>> =
        Mutex::new(mem.note.filter(|_| pending > 0).into_iter().collect());
    // A frame and its two witnesses per worker in flight, neighbours sharing.
    let frames = FrameCache::new(2 * workers);
    let compute = |i: usize, used: &[usize], fp: &str, holds: &[Mend]| -> Result<FrameRecord> {
        let frame = &scene.frames[i];
        let probe_meta = &scene.probes[used[0]];
        let out = out_dir.join(format!("{}.exr", frame.id));
        let side = out_dir.join(format!("{}.json", frame.id));
        let sdr = frames.get(frame, params.size)?;
        let mut repaired = 0;
        for &u in used {
            repaired += get_probe(u)?.1;
        }
        // At a size given, a smaller probe keeps its own pixels (load_probe):
        // nothing to note.
        let probe_size = match params.size {
            Some(_) => (sdr.width(), sdr.height()),
            None => get_probe(used[0])
                .map(|(p, _)| (p.image.width(), p.image.height()))
                .unwrap_or((sdr.width(), sdr.height())),
        };
        note_sizes(&noted, frame, (sdr.width(), sdr.height()), probe_size);
        let t = Instant::now();
        let lin = linearize(&sdr, scene, frame);
        let witnesses = load_witnesses(scene, i, params, &|n| frames.get(n, params.size));
        let (img, warp_report, flow_report, fusion_report) = predict_held(
            scene, frame, &sdr, &lin, used, access, params, holds, &witnesses,
        )?;
        let total_ms = t.elapsed().as_secs_f64() * 1e3;
        drop((sdr, lin));
        io::write_hdr_with(&out, &img, &exr)?;
        let rec = FrameRecord {
            id: frame.id.clone(),
            probe: probe_meta.id.clone(),
            probe_distance_m: distance_m(probe_meta.pose.position, frame.pose.position),
            probes: used.iter().map(|&u| scene.probes[u].id.clone()).collect(),
            warp: warp_report,
            flow: flow_report,
            fusion: fusion_report,
            total_ms,
            repaired_pixels: repaired,
            fingerprint: fp.to_string(),
        };
        let json = crate::error::to_json(&rec)?.into_bytes();
        crate::fsutil::write_atomic(&side, &json)?;
        Ok(rec)
    };
    // Each worker takes the next frame in walk order, so the frames in flight are
    // neighbours that share their probes.
    let next = AtomicUsize::new(0);
    let results: Vec<Mutex<Option<Result<(FrameRecord, bool)>>>> =
        scene.frames.iter().map(|_| Mutex::new(None)).collect();
    (0..workers).into_par_iter().for_each(|_| loop {
        let i = next.fetch_add(1, Ordering::SeqCst);
        if i >= scene.frames.len() {
            break;
        }
        if !mine(i) {
            continue;
        }
        let (used, fp, kept) = &inputs[i];
        let r = match kept {
            Some(rec) => Ok((rec.clone(), true)),
            None => {
                let r = compute(i, used, fp, &[]).map(|rec| (rec, false));
                release(used);
                r
            }
        };
        if r.is_ok() {
            progress(done.fetch_add(1, Ordering::SeqCst) + 1, total);
        }
        if let Ok(mut slot) = results[i].lock() {
            *slot = Some(r);
        }
    });
    let mut frames = Vec::new();
    let mut resumed = Vec::new();
    for (i, r) in results.into_iter().enumerate() {
        if !mine(i) {
            continue;
        }
        let r = r
            .into_inner()
            .map_err(|_| Error::Invalid("frame result lock poisoned".into()))?
            .ok_or_else(|| Error::Invalid("a frame was not processed".into()))?;
        let (rec, was_resumed) = r?;
        if was_resumed {
            resumed.push(rec.id.clone());
        }
        frames.push(rec);
    }
    // The walk as one sequence: frames whose regions the walk holds are fused
    // again with those holds (and a frame held before whose holds changed).
    let mut warnings = scene.warnings.clone();
    if let Ok(n) = noted.lock() {
        warnings.extend(n.iter().cloned());
    }
    let walk_on = params.method == Method::Fusion && params.fusion.walk.mode != WalkMode::Off;
    if walk_on && !whole_walk {
        warnings.push(
            "this shard's frames are fused one by one: once every shard is done, \
             run the scene again without --shard to fuse the walk as one sequence \
             (it resumes every frame and fuses again only the frames it holds)"
                .into(),
        );
    }
    if walk_on && whole_walk {
        let wanted = walk::wanted(scene, &frames, &params.fusion.walk);
        let redo: Vec<usize> = (0..frames.len())
            .filter(|&i| walk::held(&frames[i]) != wanted[i])
            .collect();
        // The probes these frames use are loaded again and dropped once no
        // frame left needs them; no more frames in flight than their own
        // memory plan allows.
        for &i in &redo {
            for &u in &inputs[i].0 {
                remaining[u].fetch_add(1, Ordering::SeqCst);
            }
        }
        let again = memory_plan(scene, params, &remaining, (fw, fh), threads, redo.len());
        if pending == 0 && !redo.is_empty() {
            warnings.extend(again.note);
        }
        let redone: Vec<Result<FrameRecord>> = redo
            .chunks(again.workers)
            .flat_map(|chunk| {
                chunk
                    .par_iter()
                    .map(|&i| {
                        let (used, fp, _) = &inputs[i];
                        let r = compute(i, used, fp, &wanted[i]);
                        release(used);
                        r
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        for (&i, r) in redo.iter().zip(redone) {
            frames[i] = r?;
            resumed.retain(|id| id != &frames[i].id);
        }
    }
    let report = RunReport {
        scene: scene.name.clone(),
        probe_unit: scene.probe_unit.clone(),
        params: params.clone(),
        vignetting: scene.vignetting,
        frames,
        resumed,
        warnings,
    };
    let json = crate::error::to_json(&report)?.into_bytes();
    crate::fsutil::write_atomic(&out_dir.join(report_name), &json)?;
    Ok(report)
}

/// Runs shard `index` of `count` (frames whose position in the walk is `index`
/// modulo `count`), so a long walk splits over machines (a Slurm array or a
/// Kubernetes indexed job: one shard per task, all into the same folder). Each
/// shard fuses its frames one by one, so the union of the shards' outputs is
/// byte-identical to one run with the walk's sequence off; a run without
/// shards afterwards resumes every frame and applies the walk
/// ([`crate::fusion::walk`]). Each shard writes
/// `report.shard-<index>-of-<count>.json`.
pub fn run_shard(
    scene: &Scene,
    out_dir: &Path,
    params: &RunParams,
    index: usize,
    count: usize,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<RunReport> {
    if count == 0 || index >= count {
        return Err(Error::Invalid(format!(
            "shard {index}/{count}: the index must be below the count"
        )));
    }
    run_named(
        scene,
        out_dir,
        params,
        progress,
        &format!("report.shard-{index}-of-{count}.json"),
        Some((index, count)),
    )
}

/// The lights of probe pairs ([`PairLights`]), found once per ordered pair of probe
/// indices and white point, and shared by every frame between the two with that
/// white point (a run's fusion settings do not change; its white point does when
/// each frame has its own gain, [`light_white`]): fitting a light's surface does
/// not depend on the frame, and was most of fusion's time per frame on kitchen
/// and flat.
#[derive(Default)]
pub struct LightPairs {
    cells: Mutex<HashMap<(usize, usize, u32), PairCell>>,
    probes: Mutex<HashMap<(usize, u32), ProbeCell>>,
    spent: Mutex<(f64, usize)>,
}

/// One probe's evidence for the fusion's ledger, filled by the first frame that
/// needs it.
type ProbeCell = Arc<OnceLock<Arc<ProbeEvidence>>>;

/// One pair's lights, filled by the first frame that needs them.
type PairCell = Arc<OnceLock<Arc<PairLights>>>;

impl LightPairs {
    /// The lights of probes `(a, b)` above `white`, made by `make` the first time
    /// they are asked for.
    pub fn get(
        &self,
        key: (usize, usize),
        white: f32,
        make: impl FnOnce() -> PairLights,
    ) -> Arc<PairLights> {
        let cell = {
            let mut cells = self.cells.lock().unwrap_or_else(|e| e.into_inner());
            cells
                .entry((key.0, key.1, white.to_bits()))
                .or_default()
                .clone()
        };
        cell.get_or_init(|| {
            let t = Instant::now();
            let made = Arc::new(make());
            let mut spent = self.spent.lock().unwrap_or_else(|e| e.into_inner());
            spent.0 += t.elapsed().as_secs_f64() * 1e3;
            spent.1 += 1;
            made
        })
        .clone()
    }

    /// The evidence of probe `index` above `white` ([`ProbeEvidence`]), made by
    /// `make` the first time it is asked for.
    pub fn probe(
        &self,
        index: usize,
        white: f32,
        make: impl FnOnce() -> ProbeEvidence,
    ) -> Arc<ProbeEvidence> {
        let cell = {
            let mut cells = self.probes.lock().unwrap_or_else(|e| e.into_inner());
            cells.entry((index, white.to_bits())).or_default().clone()
        };
        cell.get_or_init(|| Arc::new(make())).clone()
    }

    /// Time spent finding pairs' lights (ms) and how many pairs.
    pub fn spent(&self) -> (f64, usize) {
        *self.spent.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Where a frame's probes come from: each prepared once, by index, and the lights
/// of each pair of them found once.
#[derive(Clone, Copy)]
pub struct ProbeAccess<'a> {
    /// The prepared probe of a scene index, with the count of repaired pixels.
    pub get: &'a (dyn Fn(usize) -> Result<(Arc<PreparedProbe>, usize)> + Sync),
    /// The lights of probe pairs.
    pub pairs: &'a LightPairs,
}

/// A frame's prediction and the reports of the methods that made it.
pub type Prediction = (
    HdrImage,
    Option<WarpReport>,
    Option<FlowReport>,
    Option<FusionReport>,
);

/// Predicts one frame with the configured method from its SDR image `sdr`, its
/// radiance `lin`, and the probes `used` (nearest first), read through `access`.
pub fn predict_frame(
    scene: &Scene,
    frame: &Frame,
    sdr: &SdrImage,
    lin: &HdrImage,
    used: &[usize],
    access: ProbeAccess,
    params: &RunParams,
) -> Result<Prediction> {
    // The frame's place in the walk, for its neighbours.
    let witnesses = scene
        .frames
        .iter()
        .position(|f| f.id == frame.id)
        .map(|i| {
            load_witnesses(scene, i, params, &|n| {
                load_frame(n, params.size).map(Arc::new)
            })
        })
        .unwrap_or_default();
    predict_held(
        scene,
        frame,
        sdr,
        lin,
        used,
        access,
        params,
        &[],
        &witnesses,
    )
}

/// [`predict_frame`], with the fusion's regions named in `walk` held to the
/// power the neighbouring frames carry to them ([`crate::fusion::walk`]).
#[allow(clippy::too_many_arguments)]
fn predict_held(
    scene: &Scene,
    frame: &Frame,
    sdr: &SdrImage,
    lin: &HdrImage,
    used: &[usize],
    access: ProbeAccess,
    params: &RunParams,
    walk: &[Mend],
    witnesses: &[Witness],
) -> Result<Prediction> {
    let (w, h) = (sdr.width(), sdr.height());
    let (get_probe, pairs) = (access.get, access.pairs);
    if params.method == Method::Fusion {
        if params.fusion_base == Method::Fusion {
            return Err(Error::Invalid(
                "fusion needs another method as its base".into(),
            ));
        }
        // The base method's graph cut (flow, hybrid) carries the calibrated SDR
        // frame as a label of its own: cheap where it measured, infeasible where it
        // clipped, so one mechanism decides which pixels the probes fill.
        let mut base = RunParams {
            method: params.fusion_base,
            ..params.clone()
        };
        base.flow.sdr_calibrated = true;
        base.flow.sdr_cost = params.fusion.sdr_label_cost;
        base.flow.work_width = base.flow.work_width_at_most(params.fusion.base_pixel_deg);
        base.flow.flow.finest_scale = base
            .flow
            .finest_scale_at_least(w, params.fusion.base_flow_deg);
        let mut base_used = used.to_vec();
        base_used.truncate(params.fusion_base.probes_needed());
        let (est, wr, fr, _) =
            predict_held(scene, frame, sdr, lin, &base_used, access, &base, &[], &[])?;
        let white = white_point(scene, frame, params);
        let lw = light_white(white, frame.gain.is_some());
        // Lights seen by both probes, placed in 3-D and carried to this frame.
        let t = Instant::now();
        let probes: Vec<_> = used
            .iter()
            .map(|&u| get_probe(u).map(|(pp, _)| pp))
            .collect::<Result<_>>()?;
        fn view(pp: &Arc<PreparedProbe>) -> crate::fusion::lights::View<'_> {
            (&*pp.image, &pp.pose)
        }
        let (mut placed, mut near) = (Vec::new(), Vec::new());
        if params.fusion.place_lights && probes.len() >= 2 {
            let (a, b) = (view(&probes[0]), view(&probes[1]));
            let pair = pairs.get((used[0], used[1]), lw, || {
                pair_lights(a, b, lw, &params.fusion)
            });
            placed = pair.at_frame(a, b, &frame.pose);
            near = pair.near();
        }
        // Far sources (sky through a window) are looked up in the nearest
        // `far_probes` probes.
        let sky = (params.fusion.far_probes > 0).then(|| crate::fusion::lights::SkyView {
            probes: probes
                .iter()
                .take(params.fusion.far_probes)
                .map(view)
                .collect(),
            frame: frame.pose,
            floor: white,
            near,
            witnesses,
        });
        // What the probes measured, for the ledger: each probe's light above
        // the white point and its peak, found once.
        let probe_ev: Vec<Arc<ProbeEvidence>> = used
            .iter()
            .zip(&probes)
            .take(params.fusion.far_probes.max(2))
            .map(|(&u, pp)| pairs.probe(u, lw, || ProbeEvidence::new(&pp.image, &pp.pose, lw)))
            .collect();
        let refs: Vec<&ProbeEvidence> = probe_ev.iter().map(|e| &**e).collect();
        let evidence = Evidence {
            walk: walk.to_vec(),
            ..Evidence::at_frame(&refs, &frame.pose, w, h)
        };
        let (img, mut rep) = fuse_with_lights(
            &Measured {
                codes: sdr,
                radiance: lin,
                white,
                censor: params.flow.censor,
            },
            &est,
            &placed,
            sky.as_ref(),
            Some(&evidence),
            &params.fusion,
        )?;
        rep.time_ms = t.elapsed().as_secs_f64() * 1e3;
        return Ok((img, wr, fr, Some(rep)));
    }
    Ok(match params.method {
        Method::Warp => {
            let (probe, _) = get_probe(used[0])?;
            let (img, r) = warp::warp_frame(sdr, lin, &frame.pose, &probe, &params.warp, w, h)?;
            (img, Some(r), None, None)
        }
        Method::Fusion => unreachable!("handled above"),
        Method::Flow | Method::Hybrid => {
            // The flow method reads the probes where they are, through their
            // rotation into the frame (hybrid: the probes warped to the frame), and
            // works at a reduced size for wide frames.
            let mut probes = Vec::with_capacity(used.len());
            let mut warped = Vec::new();
            let mut first_warp = None;
            // The hybrid's warp supplies probes: where the frame clipped, their
            // bottom face holds the probe's own radiance.
            let wp = warp::WarpParams {
                bottom_bounded_by_frame: false,
                ..params.warp.clone()
            };
            for &u in used {
                let (pp, _) = get_probe(u)?;
                if params.method == Method::Hybrid {
                    let (img, r) = warp::warp_frame(sdr, lin, &frame.pose, &pp, &wp, w, h)?;
                    first_warp.get_or_insert(r);
                    warped.push(img);
                }
                probes.push(pp);
            }
            let rotated_source = |i: usize, image| RotatedSource {
                name: scene.probes[used[i]].id.clone(),
                image,
                rotation: frame.pose.from_other(&probes[i].pose),
                distance_m: distance_m(scene.probes[used[i]].pose.position, frame.pose.position),
            };
            // The hybrid's warp may move a light at infinity by the parallax of the
            // features its homographies fitted; the rotation alone puts it in place.
            let mut restored = Vec::new();
            if params.method == Method::Hybrid {
                let unwarped: Vec<RotatedSource> = (0..used.len())
                    .map(|i| rotated_source(i, &*probes[i].image))
                    .collect();
                restored = restore_warped_lights(
                    sdr,
                    &mut warped,
                    &unwarped,
                    &scene.response,
                    scene.frame_luminance_gain(frame),
                    &params.flow,
                )?;
            }
            let sources: Vec<RotatedSource> = (0..used.len())
                .map(|i| {
                    if params.method == Method::Hybrid {
                        RotatedSource {
                            rotation: glam::Mat3::IDENTITY,
                            ..rotated_source(i, &warped[i])
                        }
                    } else {
                        rotated_source(i, &*probes[i].image)
                    }
                })
                .collect();
            let (img, mut r) = flow_frame_scaled(
                sdr,
                lin,
                &sources,
                &scene.response,
                scene.frame_luminance_gain(frame),
                &params.flow,
            )?;
            r.restored_light_px = restored;
            (img, first_warp, Some(r), None)
        }
    })
}

/// Output path of a frame's prediction.
pub fn prediction_path(out_dir: &Path, frame: &Frame) -> PathBuf {
    out_dir.join(format!("{}.exr", frame.id))
}

/// [`prediction_path`], or an error naming it when the run has not produced it.
pub fn existing_prediction(out_dir: &Path, frame: &Frame) -> Result<PathBuf> {
    let p = prediction_path(out_dir, frame);
    if !p.exists() {
        return Err(Error::Invalid(format!(
            "{}: prediction for frame {} is missing (run `lumiprobe run` first)",
            p.display(),
            frame.id
        )));
    }
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pairs_lights_are_made_once_per_ordered_pair() {
        let pairs = LightPairs::default();
        let made = AtomicUsize::new(0);
        let make = || {
            made.fetch_add(1, Ordering::SeqCst);
            PairLights::default()
        };
        use rayon::prelude::*;
        (0..64).into_par_iter().for_each(|k| {
            pairs.get((k % 2, 1 - k % 2), 1.0, make);
        });
        assert_eq!(made.load(Ordering::SeqCst), 2);
        assert_eq!(pairs.spent().1, 2);
        // Another white point (a frame with its own gain) finds its own lights.
        pairs.get((0, 1), 2.0, make);
        pairs.get((0, 1), 2.0, make);
        assert_eq!(made.load(Ordering::SeqCst), 3);
    }

    #[test]
    fn a_fitted_vignetting_is_divided_out_of_the_frames_and_keys_their_outputs() {
        let frame = Frame {
            id: "f".into(),
            pose: crate::scene::Pose {
                position: glam::Vec3::ZERO,
                world_from_camera: glam::Mat3::IDENTITY,
            },
            sdr: PathBuf::from("/nonexistent/f.png"),
            ground_truth: None,
            gain: None,
        };
        let mut scene = Scene {
            root: PathBuf::from("/nonexistent"),
            name: "v".into(),
            probes: Vec::new(),
            frames: vec![frame.clone()],
            response: Default::default(),
            path_gain: 1.0,
            probe_unit: String::new(),
            warnings: Vec::new(),
            vignetting: None,
        };
        let (w, h) = (64, 32);
        let sdr = SdrImage::from_vec(w, h, vec![128; w * h * 3]).unwrap();
        let plain = linearize(&sdr, &scene, &frame);
        let key = |scene: &Scene| frame_inputs(scene, 0, &RunParams::default(), "s").1;
        let before = key(&scene);
        scene.vignetting = Some(0.3);
        let lin = linearize(&sdr, &scene, &frame);
        // On a lens axis (the panorama's centre looks along -z) nothing
        // changes; at 90 degrees from both axes (a quarter of the width) the
        // lens saw 1 - 0.3 of the light, so the radiance is 1 / 0.7 times.
        let (cx, cy) = (w / 2, h / 2);
        let axis = crate::capture::vignetting::rim(crate::sphere::pixel_to_dir(cx, cy, w, h));
        assert!(axis < 0.01, "{axis}");
        let side = crate::capture::vignetting::rim(crate::sphere::pixel_to_dir(w / 4, cy, w, h));
        assert!(side > 0.9, "{side}");
        for (x, want) in [
            (cx, 1.0 / (1.0 - 0.3 * axis)),
            (w / 4, 1.0 / (1.0 - 0.3 * side)),
        ] {
            let (a, b) = (lin.get(x, cy)[1], plain.get(x, cy)[1]);
            assert!((a / b - want).abs() < 1e-4, "x {x}: {a} / {b} vs {want}");
        }
        assert!(lin.get(w / 4, cy)[1] > 1.35 * plain.get(w / 4, cy)[1]);
        // A new falloff is a new input: the frame's outputs are made again.
        assert_ne!(key(&scene), before);
        let k3 = key(&scene);
        scene.vignetting = Some(0.2);
        assert_ne!(key(&scene), k3);
    }

    #[test]
    fn frames_with_their_own_gain_share_lights_on_a_ladder_of_sixteenth_stops() {
        // One gain for the walk: the frame's white point as it is.
        assert_eq!(light_white(0.7371, false), 0.7371);
        // Each frame's own: within 1/32 EV (2.2%), the same for nearby exposures.
        for w in [1e-3f32, 0.05, 0.7371, 1.0, 3.3, 250.0] {
            let q = light_white(w, true);
            assert!((q / w - 1.0).abs() < 0.022, "{w} -> {q}");
            assert_eq!(light_white(w * 1.001, true), q, "{w}");
        }
        assert_ne!(light_white(1.0, true), light_white(1.05, true));
    }
}

#[cfg(test)]
mod settings_tests {
    use super::RunParams;

    #[test]
    fn a_setting_is_changed_by_its_path_and_a_wrong_path_is_named() {
        let base = RunParams::default();
        let p = base
            .with_settings(&[
                "fusion.max_angle_deg=5".into(),
                "flow.censor.clip_code=245".into(),
            ])
            .unwrap();
        assert_eq!(p.fusion.max_angle_deg, 5.0);
        assert_eq!(p.flow.censor.clip_code, 245);
        assert_eq!(p.fusion.margin_px, base.fusion.margin_px);
        let e = base
            .with_settings(&["fusion.no_such=1".into()])
            .unwrap_err();
        assert!(e.to_string().contains("no_such"), "{e}");
        let e = base
            .with_settings(&["fusion.max_angle_deg".into()])
            .unwrap_err();
        assert!(e.to_string().contains("KEY=VALUE"), "{e}");
        assert!(base
            .with_settings(&["flow.censor.clip_code=\"x\"".into()])
            .is_err());
    }
}
