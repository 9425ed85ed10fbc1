//! Per-frame timing of a method on a scene, with probe features already cached (as in
//! a long run, where each probe serves many frames), on a chosen number of threads.

use super::{linearize, load_frame, load_probe, RunParams};
use crate::error::{Error, Result};
use crate::warp::{self, PreparedProbe, WarpTimings};
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::Instant;

/// Timing summary of a benchmark.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BenchReport {
    /// Scene name.
    pub scene: String,
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
    /// Mean stage times per frame in ms.
    pub stages: WarpTimings,
    /// One-off cost of preparing a probe (tone map + features of the faces used), in ms.
    pub probe_prepare_ms: f64,
    /// Peak resident memory of the process in MiB (Linux VmHWM), if known.
    pub peak_rss_mib: Option<f64>,
}

/// Peak resident set size of this process in MiB, from `/proc/self/status`.
pub fn peak_rss_mib() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// Times the warp method on every frame of `scene` `repeats` times, single pass of
/// warm-up first so that probe features are cached, inside a pool of `threads`.
pub fn bench(
    scene: &crate::scene::Scene,
    params: &RunParams,
    threads: usize,
    repeats: usize,
) -> Result<BenchReport> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .map_err(|e| Error::Invalid(e.to_string()))?;
    crate::cv::set_num_threads(1);
    pool.install(|| {
        let mut probes: Vec<Option<Arc<PreparedProbe>>> = vec![None; scene.probes.len()];
        let mut inputs = Vec::new();
        let mut prep_ms = 0.0;
        let mut prepared = 0usize;
        for f in &scene.frames {
            let sdr = load_frame(f, params.size)?;
            let lin = linearize(&sdr, scene);
            let pi = scene.nearest_probe(f.pose.position);
            if probes[pi].is_none() {
                let (img, _) =
                    load_probe(scene, pi, params.size.or(Some((sdr.width(), sdr.height()))))?;
                let t = Instant::now();
                probes[pi] = Some(Arc::new(PreparedProbe::new(
                    Arc::new(img),
                    scene.probes[pi].pose,
                    params.warp.probe_tonemap,
                    &scene.response,
                    scene.path_gain,
                )));
                prep_ms += t.elapsed().as_secs_f64() * 1e3;
                prepared += 1;
            }
            inputs.push((f, sdr, lin, pi));
        }
        // Warm-up: computes every probe face's features once.
        for (f, sdr, lin, pi) in &inputs {
            let p = probes[*pi].as_ref().expect("prepared");
            warp::warp_frame(
                sdr,
                lin,
                &f.pose,
                p,
                &params.warp,
                sdr.width(),
                sdr.height(),
            )?;
        }
        let mut times = Vec::new();
        let mut stages = WarpTimings::default();
        for _ in 0..repeats.max(1) {
            for (f, sdr, lin, pi) in &inputs {
                let p = probes[*pi].as_ref().expect("prepared");
                let t = Instant::now();
                let (_, rep) = warp::warp_frame(
                    sdr,
                    lin,
                    &f.pose,
                    p,
                    &params.warp,
                    sdr.width(),
                    sdr.height(),
                )?;
                times.push(t.elapsed().as_secs_f64() * 1e3);
                stages.tonemap_ms += rep.timings.tonemap_ms;
                stages.features_ms += rep.timings.features_ms;
                stages.matching_ms += rep.timings.matching_ms;
                stages.warp_stitch_ms += rep.timings.warp_stitch_ms;
                stages.probe_features_ms += rep.timings.probe_features_ms;
            }
        }
        let n = times.len().max(1) as f64;
        stages.tonemap_ms /= n;
        stages.features_ms /= n;
        stages.matching_ms /= n;
        stages.warp_stitch_ms /= n;
        stages.probe_features_ms /= n;
        let mut sorted = times.clone();
        sorted.sort_by(f64::total_cmp);
        let size = inputs
            .first()
            .map(|(_, s, _, _)| (s.width(), s.height()))
            .unwrap_or((0, 0));
        Ok(BenchReport {
            scene: scene.name.clone(),
            size,
            threads: threads.max(1),
            frames: inputs.len(),
            repeats: repeats.max(1),
            mean_ms: times.iter().sum::<f64>() / n,
            median_ms: sorted.get(sorted.len() / 2).copied().unwrap_or(0.0),
            stages,
            probe_prepare_ms: if prepared > 0 {
                prep_ms / prepared as f64
            } else {
                0.0
            },
            peak_rss_mib: peak_rss_mib(),
        })
    })
}
