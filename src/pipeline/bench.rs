//! Per-frame timing of a method on a scene, with probes loaded and their features
//! cached first (as in a long run, where each probe serves many frames), on a chosen
//! number of threads.

use super::{linearize, load_frame, load_probe, predict_frame, RunParams};
use crate::error::{Error, Result};
use crate::flow::method::FlowTimings;
use crate::warp::{PreparedProbe, WarpTimings};
use serde::{Deserialize, Serialize};
use std::sync::{Arc, OnceLock};
use std::time::Instant;

/// Timing summary of a benchmark.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BenchReport {
    /// Scene name.
    pub scene: String,
    /// Method timed.
    pub method: super::Method,
    /// Working size.
    pub size: (usize, usize),
    /// Threads used.
    pub threads: usize,
    /// Frames timed per repetition.
    pub frames: usize,
    /// Repetitions.
    pub repeats: usize,
    /// Mean wall-clock time per frame in ms.
    pub mean_ms: f64,
    /// Median wall-clock time per frame in ms.
    pub median_ms: f64,
    /// Mean CPU time per frame in ms of the one worker thread (single-thread runs on
    /// Linux only): unlike wall-clock time it barely changes when other work shares
    /// the machine.
    pub cpu_ms: Option<f64>,
    /// Mean warp-stage times per frame in ms (summed over the probes warped).
    pub warp_stages: WarpTimings,
    /// Mean flow-stage times per frame in ms.
    pub flow_stages: FlowTimings,
    /// Mean time of the fusion step per frame in ms (fusion only).
    pub fusion_ms: f64,
    /// One-off cost of loading and preparing a probe, in ms.
    pub probe_prepare_ms: f64,
    /// One-off cost of finding and placing the lights of a probe pair (fusion), in
    /// ms, and how many pairs the frames use; the untimed first pass pays it.
    #[serde(default)]
    pub pair_lights_ms: f64,
    /// Probe pairs whose lights were found.
    #[serde(default)]
    pub light_pairs: usize,
    /// Peak resident memory of the process in MiB (Linux VmHWM), if known.
    pub peak_rss_mib: Option<f64>,
    /// Mean scores of the last repetition's predictions against the frames' ground
    /// truth (scored outside the timed section), when asked for and available.
    pub quality: Option<crate::eval::Metrics>,
}

/// CPU time this thread has run, in nanoseconds (Linux `schedstat`).
fn thread_cpu_ns() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    s.split_whitespace().next()?.parse().ok()
}

/// Resets this process's peak resident memory (Linux `clear_refs` 5), so the next
/// [`peak_rss_mib`] reports the peak of what runs after it. Returns whether it could.
pub fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// Peak resident set size of this process in MiB, from `/proc/self/status`.
pub fn peak_rss_mib() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn add_warp(acc: &mut WarpTimings, t: &WarpTimings) {
    acc.tonemap_ms += t.tonemap_ms;
    acc.features_ms += t.features_ms;
    acc.probe_features_ms += t.probe_features_ms;
    acc.matching_ms += t.matching_ms;
    acc.warp_stitch_ms += t.warp_stitch_ms;
}

/// Times the configured method on every frame of `scene` `repeats` times inside a
/// pool of `threads`, after one untimed pass that loads probes and caches features.
pub fn bench(
    scene: &crate::scene::Scene,
    params: &RunParams,
    threads: usize,
    repeats: usize,
) -> Result<BenchReport> {
    bench_scored(scene, params, threads, repeats, false)
}

/// [`bench`], and with `score` also the mean quality of the predictions against the
/// frames' ground truth (for error-against-time sweeps).
pub fn bench_scored(
    scene: &crate::scene::Scene,
    params: &RunParams,
    threads: usize,
    repeats: usize,
    score: bool,
) -> Result<BenchReport> {
    if params.size.is_none() {
        super::one_frame_size(scene)?;
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .map_err(|e| Error::Internal(format!("thread pool: {e}")))?;
    crate::cv::set_num_threads(1);
    pool.install(|| {
        let prep_total = std::sync::Mutex::new((0.0f64, 0usize));
        let cells: Vec<OnceLock<std::result::Result<(Arc<PreparedProbe>, usize), String>>> =
            scene.probes.iter().map(|_| OnceLock::new()).collect();
        let get_probe = |i: usize| -> Result<(Arc<PreparedProbe>, usize)> {
            cells[i]
                .get_or_init(|| {
                    let t = Instant::now();
                    let r = load_probe(scene, i, params.size)
                        .map(|(img, rep)| {
                            (
                                Arc::new(PreparedProbe::new(
                                    Arc::new(img),
                                    scene.probes[i].pose,
                                    params.warp.probe_tonemap,
                                    &scene.response,
                                    scene.path_gain,
                                )),
                                rep,
                            )
                        })
                        .map_err(|e| e.to_string());
                    if let Ok(mut p) = prep_total.lock() {
                        p.0 += t.elapsed().as_secs_f64() * 1e3;
                        p.1 += 1;
                    }
                    r
                })
                .clone()
                .map_err(Error::Invalid)
        };
        let pairs = super::LightPairs::default();
        let access = super::ProbeAccess {
            get: &get_probe,
            pairs: &pairs,
        };
        // Frames are read (untimed) when they are predicted, one at a time as in a
        // run: holding every frame would dominate the peak memory at large sizes.
        let load = |f: &crate::scene::Frame| -> Result<_> {
            let sdr = load_frame(f, params.size)?;
            let lin = linearize(&sdr, scene, f);
            Ok((sdr, lin))
        };
        let mut inputs = Vec::new();
        let mut size = None;
        for f in &scene.frames {
            let mut used = scene.probes_by_distance(f.pose.position);
            used.truncate(params.probes_needed());
            inputs.push((f, used));
        }
        // Untimed pass: loads probes and computes every probe face's features once.
        for (f, used) in &inputs {
            let (sdr, lin) = load(f)?;
            size.get_or_insert((sdr.width(), sdr.height()));
            predict_frame(scene, f, &sdr, &lin, used, access, params)?;
        }
        let mut times = Vec::new();
        let mut warp_stages = WarpTimings::default();
        let mut flow_stages = FlowTimings::default();
        let mut fusion_ms = 0.0;
        let mut scores = Vec::new();
        let mut cpu_ns = Some(0u64);
        for rep in 0..repeats.max(1) {
            let last = rep + 1 == repeats.max(1);
            for (f, used) in &inputs {
                let (sdr, lin) = load(f)?;
                let c0 = thread_cpu_ns();
                let t = Instant::now();
                let (pred, wr, fr, fu) = predict_frame(scene, f, &sdr, &lin, used, access, params)?;
                times.push(t.elapsed().as_secs_f64() * 1e3);
                cpu_ns = match (cpu_ns, c0, thread_cpu_ns()) {
                    (Some(acc), Some(a), Some(b)) => Some(acc + b.saturating_sub(a)),
                    _ => None,
                };
                if score && last {
                    if let Some(gt) = &f.ground_truth {
                        let gt = crate::image::io::read_hdr(gt)?;
                        scores.push(crate::eval::compare_resized(&pred, &gt)?);
                    }
                }
                if let Some(w) = wr {
                    add_warp(&mut warp_stages, &w.timings);
                }
                if let Some(fu) = fu {
                    fusion_ms += fu.time_ms;
                }
                if let Some(fr) = fr {
                    flow_stages.tonemap_ms += fr.timings.tonemap_ms;
                    flow_stages.flow_ms += fr.timings.flow_ms;
                    flow_stages.warp_ms += fr.timings.warp_ms;
                    flow_stages.graphcut_ms += fr.timings.graphcut_ms;
                }
            }
        }
        let n = times.len().max(1) as f64;
        for v in [
            &mut warp_stages.tonemap_ms,
            &mut warp_stages.features_ms,
            &mut warp_stages.probe_features_ms,
            &mut warp_stages.matching_ms,
            &mut warp_stages.warp_stitch_ms,
        ] {
            *v /= n;
        }
        for v in [
            &mut flow_stages.tonemap_ms,
            &mut flow_stages.flow_ms,
            &mut flow_stages.warp_ms,
            &mut flow_stages.graphcut_ms,
        ] {
            *v /= n;
        }
        let mut sorted = times.clone();
        sorted.sort_by(f64::total_cmp);
        let size = size.unwrap_or((0, 0));
        let (pair_ms, light_pairs) = pairs.spent();
        let (prep_ms, prepared) = *prep_total
            .lock()
            .map_err(|_| Error::Invalid("timer lock".into()))?;
        Ok(BenchReport {
            scene: scene.name.clone(),
            method: params.method,
            size,
            threads: threads.max(1),
            frames: inputs.len(),
            repeats: repeats.max(1),
            mean_ms: times.iter().sum::<f64>() / n,
            median_ms: sorted.get(sorted.len() / 2).copied().unwrap_or(0.0),
            cpu_ms: cpu_ns
                .filter(|_| threads.max(1) == 1)
                .map(|ns| ns as f64 / 1e6 / n),
            warp_stages,
            flow_stages,
            fusion_ms: fusion_ms / n,
            probe_prepare_ms: if prepared > 0 {
                prep_ms / prepared as f64
            } else {
                0.0
            },
            pair_lights_ms: pair_ms / light_pairs.max(1) as f64,
            light_pairs,
            peak_rss_mib: peak_rss_mib(),
            quality: crate::eval::Metrics::mean(&scores),
        })
    })
}
