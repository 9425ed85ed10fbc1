//! The outputs of `lumiprobe corpus`: totals per split and method, the text and
//! CSV tables, the worst-irradiance plot, and writing them all.

use super::{CorpusReport, CorpusRow, CorpusTotal, Split};
use crate::error::Result;
use crate::eval::summary::{Better, FlickerStat, MetricStats, RowSummary, Stat};
use crate::eval::table::{align_columns, tail_cells, tail_header, TAIL_LEGEND};
use crate::eval::METRIC_NAMES;
use crate::fsutil::write_atomic;
use std::path::Path;

/// Labels in table order: the methods as first met in `rows`, then the baselines.
fn labels(rows: &[CorpusRow]) -> Vec<String> {
    let mut v: Vec<String> = Vec::new();
    for r in rows {
        if !v.contains(&r.method) && !r.method.starts_with("baseline:") {
            v.push(r.method.clone());
        }
    }
    for r in rows {
        if !v.contains(&r.method) {
            v.push(r.method.clone());
        }
    }
    v
}

/// Mean of the values that are present; `None` when none is.
fn mean_of(v: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    let v: Vec<f64> = v.flatten().collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// The worst of `(value, scene, frame)` under `better` (NaN worst), as a value and
/// `scene/frame`.
fn worst_of<'a>(
    v: impl Iterator<Item = (Option<f64>, &'a str, Option<&'a str>)>,
    better: Better,
) -> (Option<f64>, Option<String>) {
    let mut w: Option<(f64, String)> = None;
    for (value, scene, frame) in v {
        let (Some(x), Some(f)) = (value, frame) else {
            continue;
        };
        if w.as_ref().map_or(true, |(b, _)| better.worse(x, *b)) {
            w = Some((x, format!("{scene}/{f}")));
        }
    }
    (w.as_ref().map(|w| w.0), w.map(|w| w.1))
}

/// Totals per split and label (see [`CorpusTotal`]).
pub fn totals(rows: &[CorpusRow]) -> Vec<CorpusTotal> {
    let mut out = Vec::new();
    for split in [Split::Dev, Split::Val, Split::Shared] {
        for label in labels(rows) {
            let all: Vec<&CorpusRow> = rows
                .iter()
                .filter(|r| r.split == split && r.method == label)
                .collect();
            if all.is_empty() {
                continue;
            }
            let ok: Vec<(&str, &RowSummary, usize)> = all
                .iter()
                .filter(|r| r.error.is_none())
                .filter_map(|r| r.tail.as_ref().map(|t| (r.scene.as_str(), t, r.frames)))
                .collect();
            let stat = |i: usize| {
                let (worst, worst_frame) = worst_of(
                    ok.iter().map(|(s, t, _)| {
                        let m = t.metrics.get(i);
                        (m.worst, *s, m.worst_frame.as_deref())
                    }),
                    Better::of_metric(i),
                );
                Stat {
                    mean: mean_of(ok.iter().map(|(_, t, _)| t.metrics.get(i).mean)),
                    p95: mean_of(ok.iter().map(|(_, t, _)| t.metrics.get(i).p95)),
                    worst,
                    worst_frame,
                    nan_frames: ok.iter().map(|(_, t, _)| t.metrics.get(i).nan_frames).sum(),
                }
            };
            let sum = |f: fn(&RowSummary) -> Option<usize>| -> Option<usize> {
                let v: Vec<usize> = ok.iter().filter_map(|(_, t, _)| f(t)).collect();
                (!v.is_empty()).then(|| v.iter().sum())
            };
            let (fw, ff) = worst_of(
                ok.iter()
                    .map(|(s, t, _)| (t.flicker.worst, *s, t.flicker.worst_frame.as_deref())),
                Better::Lower,
            );
            out.push(CorpusTotal {
                split,
                method: label.clone(),
                scenes: ok.len(),
                failed: all.iter().filter(|r| r.error.is_some()).count(),
                frames: ok.iter().map(|o| o.2).sum(),
                tail: RowSummary {
                    metrics: MetricStats {
                        psnr_tm: stat(0),
                        ssim_tm: stat(1),
                        mse_tm: stat(2),
                        log_lum_rmse: stat(3),
                        irradiance_rel_err: stat(4),
                        dominant_dir_err_deg: stat(5),
                    },
                    frames_over_sdr_irr: sum(|t| t.frames_over_sdr_irr),
                    frames_over_sdr_irr_margin: sum(|t| t.frames_over_sdr_irr_margin),
                    flicker: FlickerStat {
                        mean: mean_of(ok.iter().map(|(_, t, _)| t.flicker.mean)),
                        worst: fw,
                        worst_frame: ff,
                        pairs: ok.iter().map(|(_, t, _)| t.flicker.pairs).sum(),
                    },
                },
            });
        }
    }
    out
}

/// The text report (`corpus.txt`): the rows, the failures, the totals.
pub fn to_text(r: &CorpusReport) -> String {
    let mut s = format!(
        "corpus: {} scenes, methods {}{}\n",
        r.scenes.len(),
        r.methods.join(", "),
        r.size
            .map_or(String::new(), |(w, h)| format!(", size {w}x{h}"))
    );
    s.push_str(TAIL_LEGEND);
    let mut header: Vec<String> = ["split", "scene", "method", "frames"]
        .iter()
        .map(|h| h.to_string())
        .collect();
    header.extend(tail_header());
    let mut lines = vec![header.clone()];
    for row in &r.rows {
        let mut cells = vec![
            row.split.name().to_string(),
            row.scene.clone(),
            row.method.clone(),
        ];
        if row.error.is_some() {
            cells.push("FAILED".into());
        } else {
            cells.push(row.frames.to_string());
        }
        cells.extend(tail_cells(row.tail.as_ref()));
        lines.push(cells);
    }
    s.push_str(&align_columns(&lines, 3));
    for row in r.failed() {
        s.push_str(&format!(
            "failed: {} {}: {}\n",
            row.scene,
            row.method,
            row.error.as_deref().unwrap_or("")
        ));
    }
    s.push_str(
        "\ntotals per split: mean = mean over scenes of the scene means, p95 = mean of the \
         scene p95s, worst = worst over scenes @scene/frame, >sdr counts summed\n",
    );
    header[1] = "scenes".into();
    header[3] = "frames".into();
    let mut lines = vec![header];
    for t in &r.totals {
        let mut cells = vec![
            t.split.name().to_string(),
            if t.failed > 0 {
                format!("{} (+{} failed)", t.scenes, t.failed)
            } else {
                t.scenes.to_string()
            },
            t.method.clone(),
            t.frames.to_string(),
        ];
        cells.extend(tail_cells(Some(&t.tail)));
        lines.push(cells);
    }
    s.push_str(&align_columns(&lines, 3));
    s
}

/// A CSV field, quoted when it needs to be.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// The CSV report (`corpus.csv`): one line per row (`kind` = `scene`) and per
/// total (`kind` = `total`, `scene` empty), with mean, p95, worst and worst frame
/// of every metric, the counts over the SDR baseline and flicker; numbers with
/// full precision, empty cells where there is no value.
pub fn to_csv(r: &CorpusReport) -> String {
    let mut head: Vec<String> = [
        "kind", "split", "scene", "method", "status", "scenes", "frames",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    for m in METRIC_NAMES {
        for s in ["mean", "p95", "worst", "worst_frame"] {
            head.push(format!("{m}_{s}"));
        }
    }
    for h in [
        "frames_over_sdr_irr",
        "frames_over_sdr_irr_plus_0.02",
        "flicker_mean",
        "flicker_worst",
        "flicker_worst_frame",
        "error",
    ] {
        head.push(h.to_string());
    }
    let num = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v}"));
    let cnt = |v: Option<usize>| v.map_or(String::new(), |v| v.to_string());
    let stats = |t: Option<&RowSummary>| -> Vec<String> {
        let mut c = Vec::new();
        let d = RowSummary::default();
        let t = t.unwrap_or(&d);
        for i in 0..METRIC_NAMES.len() {
            let m = t.metrics.get(i);
            c.push(num(m.mean));
            c.push(num(m.p95));
            c.push(num(m.worst));
            c.push(m.worst_frame.clone().unwrap_or_default());
        }
        c.push(cnt(t.frames_over_sdr_irr));
        c.push(cnt(t.frames_over_sdr_irr_margin));
        c.push(num(t.flicker.mean));
        c.push(num(t.flicker.worst));
        c.push(t.flicker.worst_frame.clone().unwrap_or_default());
        c
    };
    let mut lines = vec![head];
    for row in &r.rows {
        let mut c = vec![
            "scene".to_string(),
            row.split.name().into(),
            row.scene.clone(),
            row.method.clone(),
            if row.error.is_some() { "failed" } else { "ok" }.into(),
            "1".into(),
            row.frames.to_string(),
        ];
        c.extend(stats(row.tail.as_ref()));
        c.push(row.error.clone().unwrap_or_default());
        lines.push(c);
    }
    for t in &r.totals {
        let mut c = vec![
            "total".to_string(),
            t.split.name().into(),
            String::new(),
            t.method.clone(),
            if t.failed > 0 { "partial" } else { "ok" }.into(),
            t.scenes.to_string(),
            t.frames.to_string(),
        ];
        c.extend(stats(Some(&t.tail)));
        c.push(if t.failed > 0 {
            format!("{} scene(s) failed", t.failed)
        } else {
            String::new()
        });
        lines.push(c);
    }
    let mut s = String::new();
    for l in lines {
        let cells: Vec<String> = l.iter().map(|c| csv_field(c)).collect();
        s.push_str(&cells.join(","));
        s.push('\n');
    }
    s
}

/// Worst-frame irradiance error per scene (x) and method (one series each, side
/// by side within a scene), log y.
pub fn worst_irradiance_plot(r: &CorpusReport) -> crate::eval::plot::Plot {
    use crate::eval::plot::{Plot, Series};
    let names: Vec<String> = r.scenes.iter().map(|s| s.name.clone()).collect();
    let labels = labels(&r.rows);
    // Series side by side within a scene, so equal values stay visible.
    let n = labels.len().max(1) as f64;
    let series = labels
        .into_iter()
        .enumerate()
        .map(|(k, label)| Series {
            name: label.trim_start_matches("baseline:").to_string(),
            labels: Vec::new(),
            points: r
                .rows
                .iter()
                .filter(|row| row.method == label && row.error.is_none())
                .filter_map(|row| {
                    let x = names.iter().position(|s| *s == row.scene)? as f64
                        + 0.5 * (k as f64 - (n - 1.0) / 2.0) / n;
                    let y = row.tail.as_ref()?.metrics.irradiance_rel_err.worst?;
                    Some((x, y))
                })
                .collect(),
            line: false,
        })
        .collect();
    Plot {
        title: "worst-frame irradiance error per scene".into(),
        x_label: "scene".into(),
        y_label: "worst irradiance rel. error".into(),
        log_x: false,
        log_y: true,
        x_names: names,
        series,
    }
}

/// Writes `corpus.txt`, `corpus.csv`, `corpus_bounds.txt`
/// ([`super::bounds`]), `corpus.json` and `corpus_worst_irradiance.png` into
/// `out`, each atomically.
pub fn write_outputs(out: &Path, r: &CorpusReport) -> Result<()> {
    write_atomic(&out.join("corpus.txt"), to_text(r).as_bytes())?;
    write_atomic(&out.join("corpus.csv"), to_csv(r).as_bytes())?;
    let bounds = super::bounds::to_text(r, &super::bounds::ISSUE_19);
    write_atomic(&out.join("corpus_bounds.txt"), bounds.as_bytes())?;
    let js = crate::error::to_json(r)?.into_bytes();
    write_atomic(&out.join("corpus.json"), &js)?;
    let w = (160 + 90 * r.scenes.len()).clamp(640, 1600);
    crate::image::io::write_sdr(
        &out.join("corpus_worst_irradiance.png"),
        &worst_irradiance_plot(r).draw(w, 480),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::corpus::CorpusScene;
    use crate::pipeline::evaluate::BASELINE_SDR;
    use std::path::PathBuf;

    fn summary(irr_mean: f64, irr_worst: f64, frame: &str, over: usize) -> RowSummary {
        let mut t = RowSummary::default();
        t.metrics.irradiance_rel_err = Stat {
            mean: Some(irr_mean),
            p95: Some(irr_worst - 0.01),
            worst: Some(irr_worst),
            worst_frame: Some(frame.into()),
            nan_frames: 0,
        };
        t.metrics.psnr_tm = Stat {
            mean: Some(30.0),
            p95: Some(25.0),
            worst: Some(20.0 + irr_mean),
            worst_frame: Some(frame.into()),
            nan_frames: 0,
        };
        t.frames_over_sdr_irr = Some(over);
        t.frames_over_sdr_irr_margin = Some(0);
        t
    }

    fn row(scene: &str, split: Split, method: &str, tail: Option<RowSummary>) -> CorpusRow {
        CorpusRow {
            scene: scene.into(),
            split,
            seed: None,
            method: method.into(),
            frames: 4,
            error: tail.is_none().then(|| "run: broke, badly".to_string()),
            mean: None,
            tail,
        }
    }

    #[test]
    fn totals_per_split_and_method() {
        let rows = vec![
            row("a", Split::Dev, "warp", Some(summary(0.1, 0.3, "f1", 1))),
            row(
                "a",
                Split::Dev,
                BASELINE_SDR,
                Some(summary(0.2, 0.4, "f0", 0)),
            ),
            row("b", Split::Dev, "warp", Some(summary(0.3, 0.5, "f2", 2))),
            row(
                "b",
                Split::Dev,
                BASELINE_SDR,
                Some(summary(0.2, 0.4, "f0", 0)),
            ),
            row("c", Split::Val, "warp", None),
            row(
                "c",
                Split::Val,
                BASELINE_SDR,
                Some(summary(0.1, 0.2, "f3", 0)),
            ),
        ];
        let t = totals(&rows);
        let labels: Vec<(Split, &str)> = t.iter().map(|t| (t.split, t.method.as_str())).collect();
        assert_eq!(
            labels,
            [
                (Split::Dev, "warp"),
                (Split::Dev, BASELINE_SDR),
                (Split::Val, "warp"),
                (Split::Val, BASELINE_SDR)
            ]
        );
        let irr = &t[0].tail.metrics.irradiance_rel_err;
        assert!((irr.mean.unwrap() - 0.2).abs() < 1e-12);
        assert!((irr.p95.unwrap() - 0.39).abs() < 1e-12);
        assert_eq!(irr.worst, Some(0.5));
        assert_eq!(irr.worst_frame.as_deref(), Some("b/f2"));
        // PSNR's worst is the lowest.
        assert_eq!(
            t[0].tail.metrics.psnr_tm.worst_frame.as_deref(),
            Some("a/f1")
        );
        assert_eq!((t[0].scenes, t[0].failed, t[0].frames), (2, 0, 8));
        assert_eq!(t[0].tail.frames_over_sdr_irr, Some(3));
        assert_eq!((t[2].scenes, t[2].failed), (0, 1));
        assert_eq!(t[2].tail.metrics.irradiance_rel_err.mean, None);

        let report = CorpusReport {
            roots: vec![],
            scenes: ["a", "b", "c"]
                .iter()
                .map(|n| CorpusScene {
                    name: n.to_string(),
                    split: Split::Dev,
                    seed: None,
                    dir: PathBuf::new(),
                })
                .collect(),
            methods: vec!["warp".into()],
            size: None,
            totals: t,
            rows,
        };
        let csv = to_csv(&report);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 1 + 6 + 4);
        assert!(lines[5].ends_with(",\"run: broke, badly\""), "{}", lines[5]);
        assert!(
            lines[7].starts_with("total,dev,,warp,ok,2,8,"),
            "{}",
            lines[7]
        );
        let text = to_text(&report);
        assert!(text.contains("failed: c warp: run: broke, badly"), "{text}");
        assert!(text.contains("0.5000 @b/f2"), "{text}");
        let plot = worst_irradiance_plot(&report);
        // Two series (warp, sdr) a quarter of a scene apart, failed rows left out.
        assert_eq!(plot.series[0].points, [(-0.125, 0.3), (0.875, 0.5)]);
        assert_eq!(plot.series[1].points.len(), 3);
    }
}
