//! Error against run time: the settings that trade time for quality are varied one
//! at a time around a base setting, each variant is timed per frame (as
//! [`super::bench::bench`] does) and scored against the scene's ground truth, and the
//! variants that no other variant beats on both time and error form the Pareto
//! front a user chooses from.

use super::bench::{bench_scored, reset_peak_rss, BenchReport};
use super::{Method, RunParams};
use crate::cv::Detector;
use crate::error::{Error, Result};
use crate::eval::plot::{Plot, Series};
use crate::eval::Metrics;
use crate::flow::dense::FlowPreset;
use crate::scene::Scene;
use serde::{Deserialize, Serialize};

/// One variant of the base setting.
#[derive(Clone, Debug)]
pub struct SweepPoint {
    /// The setting varied (`method`, `size`, `yaw_steps`, ...; `base` for the base).
    pub axis: String,
    /// Its value in this variant, as text.
    pub value: String,
    /// The full settings of the variant.
    pub params: RunParams,
}

/// The measured time, memory and error of one variant.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SweepRow {
    /// The setting varied.
    pub axis: String,
    /// Its value.
    pub value: String,
    /// Method of the variant.
    pub method: Method,
    /// Working size.
    pub size: (usize, usize),
    /// Mean time per frame in ms: the worker thread's CPU time in single-thread
    /// runs (steady on a shared machine), else wall-clock time; for fusion it
    /// includes the probe pairs' light search spread over the frames.
    pub ms_per_frame: f64,
    /// Mean wall-clock time per frame in ms.
    pub wall_ms_per_frame: f64,
    /// One-off time to load and prepare a probe (features of every rotation and
    /// face), in ms; a probe serves many frames, so it is not in the per-frame time.
    pub probe_ms: f64,
    /// Peak resident memory in MiB while the variant ran (process-wide when the
    /// peak could not be reset).
    pub peak_rss_mib: Option<f64>,
    /// Mean scores over the frames.
    pub quality: Metrics,
    /// No other variant is both faster and lower in log-luminance RMSE.
    pub pareto: bool,
    /// The base setting (the defaults when the sweep starts from them).
    pub base: bool,
}

/// Whether the method runs the flow method's graph cut (itself or as fusion's base).
fn uses_flow(p: &RunParams) -> bool {
    match p.method {
        Method::Flow | Method::Hybrid => true,
        Method::Fusion => matches!(p.fusion_base, Method::Flow | Method::Hybrid),
        Method::Warp => false,
    }
}

/// The variants of `base` that the sweep measures: every method; panorama widths
/// 256 to 2048 for the base method and for warp and flow; for the warp method's
/// matching (on `base` if it matches features, else on warp) yaw rotations 1 to 24,
/// SIFT/AKAZE/ORB and the ratio threshold; for the flow method's graph cut (on `base`
/// if it runs one, else on flow) the DIS preset, the most expansion cycles and the
/// no-smoothness ablation; and fusion's base method.
pub fn plan(base: &RunParams, frame_size: (usize, usize)) -> Vec<SweepPoint> {
    let mut pts = vec![SweepPoint {
        axis: "base".into(),
        value: base.method.name().into(),
        params: base.clone(),
    }];
    let mut add = |axis: &str, value: String, params: RunParams| {
        pts.push(SweepPoint {
            axis: axis.into(),
            value,
            params,
        })
    };
    for m in [Method::Warp, Method::Flow, Method::Hybrid, Method::Fusion] {
        if m != base.method {
            add(
                "method",
                m.name().into(),
                RunParams {
                    method: m,
                    ..base.clone()
                },
            );
        }
    }
    let base_size = base.size.unwrap_or(frame_size);
    let mut size_methods = vec![base.method];
    for m in [Method::Warp, Method::Flow] {
        if !size_methods.contains(&m) {
            size_methods.push(m);
        }
    }
    for &m in &size_methods {
        for wdt in [256usize, 512, 1024, 2048] {
            let size = (wdt, wdt / 2);
            // The base size is the `method` axis's variant (or the base itself).
            if size == base_size {
                continue;
            }
            add(
                "size",
                format!("{}x{} {}", size.0, size.1, m.name()),
                RunParams {
                    method: m,
                    size: Some(size),
                    ..base.clone()
                },
            );
        }
    }
    let warp_base = if base.matches_features() {
        base.clone()
    } else {
        RunParams {
            method: Method::Warp,
            ..base.clone()
        }
    };
    let wm = warp_base.method.name();
    for steps in [1usize, 2, 4, 8, 24] {
        if steps != warp_base.warp.yaw_steps {
            let mut p = warp_base.clone();
            p.warp.yaw_steps = steps;
            add("yaw_steps", format!("{steps} {wm}"), p);
        }
    }
    for d in [Detector::Sift, Detector::Akaze, Detector::Orb] {
        if d != warp_base.warp.detector {
            let mut p = warp_base.clone();
            p.warp.detector = d;
            add("detector", format!("{d:?} {wm}").to_lowercase(), p);
        }
    }
    for r in [0.6f32, 0.7, 0.8, 0.9] {
        if (r - warp_base.warp.ratio).abs() > 1e-6 {
            let mut p = warp_base.clone();
            p.warp.ratio = r;
            add("ratio", format!("{r} {wm}"), p);
        }
    }
    let flow_base = if uses_flow(base) {
        base.clone()
    } else {
        RunParams {
            method: Method::Flow,
            ..base.clone()
        }
    };
    let fm = flow_base.method.name();
    for preset in [FlowPreset::Ultrafast, FlowPreset::Fast, FlowPreset::Medium] {
        if preset != flow_base.flow.flow.preset {
            let mut p = flow_base.clone();
            p.flow.flow.preset = preset;
            add("flow_preset", format!("{preset:?} {fm}").to_lowercase(), p);
        }
    }
    for cycles in [1usize, 2, 4, 8] {
        if cycles != flow_base.flow.max_cycles {
            let mut p = flow_base.clone();
            p.flow.max_cycles = cycles;
            add("cut_cycles", format!("{cycles} {fm}"), p);
        }
    }
    if !flow_base.flow.no_smoothness {
        let mut p = flow_base.clone();
        p.flow.no_smoothness = true;
        add("no_smoothness", format!("ablation {fm}"), p);
    }
    if base.method == Method::Fusion {
        for m in [Method::Warp, Method::Flow, Method::Hybrid] {
            if m != base.fusion_base {
                let mut p = base.clone();
                p.fusion_base = m;
                add("fusion_base", m.name().into(), p);
            }
        }
    }
    pts
}

/// Relative differences in time below this are measurement noise.
pub const TIME_TOLERANCE: f64 = 0.05;
/// Relative differences in error below this are noise (frame sampling, rounding).
pub const ERROR_TOLERANCE: f64 = 0.005;

/// Marks the rows that no other row beats: another row beats this one when it is
/// no slower and no worse in log-luminance RMSE, and clearly better in one of the
/// two (by more than [`TIME_TOLERANCE`] or [`ERROR_TOLERANCE`]), so that settings
/// that differ only by noise stay on the front together.
pub fn mark_pareto(rows: &mut [SweepRow]) {
    let key: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (r.ms_per_frame, r.quality.log_lum_rmse))
        .collect();
    let (tt, te) = (TIME_TOLERANCE, ERROR_TOLERANCE);
    for (i, r) in rows.iter_mut().enumerate() {
        let (t, e) = key[i];
        r.pareto = t.is_finite()
            && e.is_finite()
            && !key.iter().enumerate().any(|(j, &(tj, ej))| {
                j != i
                    && tj <= t * (1.0 + tt)
                    && ej <= e * (1.0 + te)
                    && (tj < t * (1.0 - tt) || ej < e * (1.0 - te))
            });
    }
}

/// Measures one point in this process: one timed pass after an untimed one, scored.
/// Memory is then the process's (a sweep in one process keeps what earlier points
/// freed); the CLI measures each point in a fresh process instead.
pub fn measure_in_process(
    scene: &Scene,
    threads: usize,
) -> impl FnMut(&SweepPoint) -> Result<BenchReport> + '_ {
    move |pt| {
        let reset = reset_peak_rss();
        let mut r = bench_scored(scene, &pt.params, threads, 1, true)?;
        if !reset {
            r.peak_rss_mib = None;
        }
        Ok(r)
    }
}

/// Runs every point of the sweep with `measure` (which times and scores one
/// setting, e.g. [`measure_in_process`]) and marks the Pareto front. `progress`
/// sees each row as it is measured.
pub fn run(
    scene: &Scene,
    points: &[SweepPoint],
    mut measure: impl FnMut(&SweepPoint) -> Result<BenchReport>,
    mut progress: impl FnMut(&SweepRow),
) -> Result<Vec<SweepRow>> {
    let mut rows = Vec::with_capacity(points.len());
    for pt in points {
        let r = measure(pt)?;
        let quality = r.quality.ok_or_else(|| {
            Error::Invalid(format!(
                "scene {}: no frame has ground truth, so the sweep cannot score",
                scene.name
            ))
        })?;
        let row = SweepRow {
            axis: pt.axis.clone(),
            value: pt.value.clone(),
            method: pt.params.method,
            size: r.size,
            // A run pays each probe pair's light search once; spread over the
            // scene's frames it belongs to the time per frame (bench times it apart).
            ms_per_frame: r.cpu_ms.unwrap_or(r.mean_ms) + pair_ms_per_frame(&r),
            wall_ms_per_frame: r.mean_ms + pair_ms_per_frame(&r),
            probe_ms: r.probe_prepare_ms,
            peak_rss_mib: r.peak_rss_mib,
            quality,
            pareto: false,
            base: pt.axis == "base",
        };
        progress(&row);
        rows.push(row);
    }
    mark_pareto(&mut rows);
    Ok(rows)
}

/// The one-off light search of the probe pairs a bench used, spread over its frames.
fn pair_ms_per_frame(r: &super::bench::BenchReport) -> f64 {
    r.pair_lights_ms * r.light_pairs as f64 / r.frames.max(1) as f64
}

/// The rows as CSV (one line per variant).
pub fn to_csv(rows: &[SweepRow]) -> String {
    let mut s = String::from(
        "axis,value,method,width,height,ms_per_frame,wall_ms_per_frame,probe_ms,peak_rss_mib,psnr_tm,ssim_tm,mse_tm,\
         log_lum_rmse,irradiance_rel_err,dominant_dir_err_deg,pareto,base\n",
    );
    for r in rows {
        let q = &r.quality;
        s += &format!(
            "{},{},{},{},{},{:.2},{:.2},{:.1},{},{:.4},{:.5},{:.6},{:.5},{:.5},{:.3},{},{}\n",
            r.axis,
            r.value.replace(',', ";"),
            r.method.name(),
            r.size.0,
            r.size.1,
            r.ms_per_frame,
            r.wall_ms_per_frame,
            r.probe_ms,
            r.peak_rss_mib
                .map(|m| format!("{m:.0}"))
                .unwrap_or_default(),
            q.psnr_tm,
            q.ssim_tm,
            q.mse_tm,
            q.log_lum_rmse,
            q.irradiance_rel_err,
            q.dominant_dir_err_deg,
            r.pareto,
            r.base
        );
    }
    s
}

/// The rows as an aligned text table, numbered as the plot labels its points,
/// Pareto rows marked `*`, the base `(base)`.
pub fn to_text(rows: &[SweepRow]) -> String {
    let mut s = format!(
        "{:>3} {:<14} {:<22} {:>10} {:>10} {:>8} {:>8} {:>8} {:>8} {:>7} {:>7}\n",
        "#",
        "setting",
        "value",
        "ms/frame",
        "ms/probe",
        "MiB",
        "PSNR",
        "logRMSE",
        "irr",
        "dir",
        "front"
    );
    for (k, r) in rows.iter().enumerate() {
        let q = &r.quality;
        s += &format!(
            "{:>3} {:<14} {:<22} {:>10.1} {:>10.1} {:>8} {:>8.2} {:>8.4} {:>8.3} {:>7.2} {:>7}\n",
            k + 1,
            r.axis,
            r.value,
            r.ms_per_frame,
            r.probe_ms,
            r.peak_rss_mib
                .map(|m| format!("{m:.0}"))
                .unwrap_or("-".into()),
            q.psnr_tm,
            q.log_lum_rmse,
            q.irradiance_rel_err,
            q.dominant_dir_err_deg,
            match (r.pareto, r.base) {
                (true, true) => "* base",
                (true, false) => "*",
                (false, true) => "base",
                _ => "",
            }
        );
    }
    s
}

/// Error (log-luminance RMSE) against time per frame: one series per method, the
/// Pareto front as a line, the base setting on its own.
pub fn plot(rows: &[SweepRow], scene: &str) -> Plot {
    let mut series = Vec::new();
    // Each point labelled with its row's number in the table (`to_text`'s
    // first column).
    let numbered = |keep: &dyn Fn(&SweepRow) -> bool| -> (Vec<(f64, f64)>, Vec<String>) {
        rows.iter()
            .enumerate()
            .filter(|(_, r)| keep(r))
            .map(|(k, r)| {
                (
                    (r.ms_per_frame, r.quality.log_lum_rmse),
                    (k + 1).to_string(),
                )
            })
            .unzip()
    };
    for m in [Method::Warp, Method::Flow, Method::Hybrid, Method::Fusion] {
        let (pts, labels) = numbered(&|r: &SweepRow| r.method == m && !r.base);
        if !pts.is_empty() {
            series.push(Series {
                name: m.name().into(),
                points: pts,
                line: false,
                labels,
            });
        }
    }
    let mut front: Vec<(f64, f64)> = rows
        .iter()
        .filter(|r| r.pareto)
        .map(|r| (r.ms_per_frame, r.quality.log_lum_rmse))
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    series.push(Series {
        name: "pareto front".into(),
        points: front,
        line: true,
        labels: Vec::new(),
    });
    let (points, labels) = numbered(&|r: &SweepRow| r.base);
    series.push(Series {
        name: "base (defaults)".into(),
        points,
        line: false,
        labels,
    });
    Plot {
        title: format!("{scene}: error against run time"),
        x_label: "CPU time per frame (ms, 1 thread)".into(),
        y_label: "log-luminance RMSE".into(),
        log_x: true,
        log_y: false,
        x_names: Vec::new(),
        series,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(ms: f64, err: f64) -> SweepRow {
        SweepRow {
            axis: "x".into(),
            value: "v".into(),
            method: Method::Warp,
            size: (8, 4),
            ms_per_frame: ms,
            wall_ms_per_frame: ms,
            probe_ms: 0.0,
            peak_rss_mib: None,
            quality: Metrics {
                psnr_tm: 0.0,
                ssim_tm: 0.0,
                mse_tm: 0.0,
                log_lum_rmse: err,
                irradiance_rel_err: 0.0,
                dominant_dir_err_deg: 0.0,
                invalid_pixels: 0,
            },
            pareto: false,
            base: false,
        }
    }

    #[test]
    fn pareto_front_keeps_only_undominated_rows() {
        let mut rows = vec![
            row(10.0, 0.5),
            row(20.0, 0.3),
            row(30.0, 0.3), // beaten by the 20 ms row (equal error, slower)
            row(15.0, 0.6), // beaten by the 10 ms row
            row(100.0, 0.1),
            row(f64::NAN, 0.0),
            row(20.5, 0.3005), // within the noise of the 20 ms row: both stay
            row(104.0, 0.08),  // as fast as the 100 ms row within noise, better
        ];
        mark_pareto(&mut rows);
        let front: Vec<bool> = rows.iter().map(|r| r.pareto).collect();
        assert_eq!(
            front,
            vec![true, true, false, false, false, false, true, true]
        );
    }

    #[test]
    fn plan_varies_one_setting_at_a_time_and_skips_the_base_value() {
        let base = RunParams {
            method: Method::Fusion,
            ..RunParams::default()
        };
        let pts = plan(&base, (512, 256));
        assert_eq!(pts[0].axis, "base");
        // No variant repeats the base setting.
        assert!(pts.iter().skip(1).all(|p| !(p.params.method == base.method
            && p.params.size.unwrap_or((512, 256)) == (512, 256)
            && p.params.warp.yaw_steps == base.warp.yaw_steps
            && p.params.warp.detector == base.warp.detector
            && p.params.warp.ratio == base.warp.ratio
            && p.params.flow.flow.preset == base.flow.flow.preset
            && p.params.flow.max_cycles == base.flow.max_cycles
            && p.params.flow.no_smoothness == base.flow.no_smoothness
            && p.params.fusion_base == base.fusion_base)));
        for axis in [
            "method",
            "size",
            "yaw_steps",
            "detector",
            "ratio",
            "flow_preset",
            "cut_cycles",
            "no_smoothness",
            "fusion_base",
        ] {
            assert!(pts.iter().any(|p| p.axis == axis), "no {axis} variant");
        }
        // Fusion on flow matches no features: matching settings go to the warp method.
        assert!(pts
            .iter()
            .filter(|p| p.axis == "yaw_steps")
            .all(|p| p.params.method == Method::Warp));
    }
}
