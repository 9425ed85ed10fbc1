//! Aggregation of per-frame [`Metrics`] into one row per method, printed as a plain
//! text table or serialised as JSON, for reports and regression checks. Rows may
//! carry the worst-case statistics of [`super::summary`] (p95, worst frame, frames
//! over the SDR baseline, flicker), printed as a second table.

use super::summary::RowSummary;
use super::{Metrics, METRIC_NAMES};
use crate::error::{Error, Result};

/// One method's scores: its label, how many frames were scored, and the mean over
/// those frames ([`Metrics::mean`]; `None` when there were none).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MetricsRow {
    /// Method name (or any other row label).
    pub label: String,
    /// Number of frames averaged.
    pub frames: usize,
    /// Mean scores; `invalid_pixels` is the total over frames.
    pub mean: Option<Metrics>,
    /// Worst-case statistics over the frames, when the row was made with them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tail: Option<RowSummary>,
}

/// Methods (rows) x metrics (columns), built from per-frame scores.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MetricsTable {
    /// Rows in insertion order.
    pub rows: Vec<MetricsRow>,
}

/// Decimal places printed per column of [`METRIC_NAMES`].
const DECIMALS: [usize; 6] = [2, 4, 6, 4, 4, 2];

impl MetricsTable {
    /// An empty table.
    pub fn new() -> Self {
        MetricsTable::default()
    }

    /// A table with one row per `(label, per-frame metrics)` pair, each averaged.
    pub fn from_rows<I, S>(rows: I) -> Self
    where
        I: IntoIterator<Item = (S, Vec<Metrics>)>,
        S: Into<String>,
    {
        let mut t = MetricsTable::new();
        for (label, frames) in rows {
            t.push(label, &frames);
        }
        t
    }

    /// Appends a row averaging `frames` under `label`.
    pub fn push(&mut self, label: impl Into<String>, frames: &[Metrics]) {
        self.rows.push(MetricsRow {
            label: label.into(),
            frames: frames.len(),
            mean: Metrics::mean(frames),
            tail: None,
        });
    }

    /// Appends a row averaging `frames`, with their worst-case statistics.
    pub fn push_with_tail(
        &mut self,
        label: impl Into<String>,
        frames: &[Metrics],
        tail: RowSummary,
    ) {
        self.push(label, frames);
        if let Some(r) = self.rows.last_mut() {
            r.tail = Some(tail);
        }
    }

    /// Plain-text table: a header, then one line per row with the label, frame
    /// count, the six mean scores and the total of invalid pixels; `-` for rows
    /// without frames. Columns are aligned with spaces. When rows carry
    /// worst-case statistics, a second table follows with them ([`tail_header`]).
    pub fn to_text(&self) -> String {
        let mut header: Vec<String> = vec!["method".into(), "frames".into()];
        header.extend(METRIC_NAMES.iter().map(|s| s.to_string()));
        header.push("invalid_pixels".into());
        let mut lines: Vec<Vec<String>> = vec![header];
        for r in &self.rows {
            let mut cells = vec![r.label.clone(), r.frames.to_string()];
            match &r.mean {
                Some(m) => {
                    for (v, d) in m.values().iter().zip(DECIMALS) {
                        cells.push(format!("{v:.d$}"));
                    }
                    cells.push(m.invalid_pixels.to_string());
                }
                None => cells.extend(std::iter::repeat("-".to_string()).take(7)),
            }
            lines.push(cells);
        }
        let mut out = align_columns(&lines, 1);
        if self.rows.iter().any(|r| r.tail.is_some()) {
            out.push_str(TAIL_LEGEND);
            let mut header = vec!["method".to_string()];
            header.extend(tail_header());
            let mut lines = vec![header];
            for r in &self.rows {
                let mut cells = vec![r.label.clone()];
                cells.extend(tail_cells(r.tail.as_ref()));
                lines.push(cells);
            }
            out.push_str(&align_columns(&lines, 1));
        }
        out
    }

    /// Pretty-printed JSON of the table.
    pub fn to_json(&self) -> Result<String> {
        serde_json::to_string_pretty(self)
            .map_err(|e| Error::Invalid(format!("metrics table to JSON: {e}")))
    }

    /// Parses a table written by [`MetricsTable::to_json`].
    pub fn from_json(s: &str) -> Result<Self> {
        serde_json::from_str(s).map_err(|e| Error::Invalid(format!("metrics table JSON: {e}")))
    }
}

/// What the columns of the worst-case table mean, printed above it.
pub const TAIL_LEGEND: &str = "worst case over frames: p95 = the 95th-percentile-bad frame \
(the low end for PSNR), worst = value @frame; >sdr_irr = frames whose irradiance error exceeds \
the SDR baseline's (>sdr+0.02: by more than 0.02); flicker = irradiance change between \
consecutive frames that the truth does not make\n";

/// Headers of the worst-case columns of [`tail_cells`].
pub fn tail_header() -> Vec<String> {
    let mut h: Vec<String> = Vec::new();
    for m in ["irr", "dir_deg", "psnr", "log_rmse"] {
        for s in ["mean", "p95", "worst"] {
            h.push(format!("{m}_{s}"));
        }
    }
    h.extend(
        [">sdr_irr", ">sdr+0.02", "flicker_mean", "flicker_worst"]
            .iter()
            .map(|s| s.to_string()),
    );
    h
}

/// The metrics of the worst-case table (indices into [`METRIC_NAMES`]):
/// irradiance, dominant direction, PSNR, log RMSE.
const TAIL_METRICS: [usize; 4] = [4, 5, 0, 3];

/// The worst-case cells of one row under [`tail_header`]; `-` where there is no
/// value (or no statistics at all).
pub fn tail_cells(tail: Option<&RowSummary>) -> Vec<String> {
    let n = tail_header().len();
    let Some(t) = tail else {
        return vec!["-".to_string(); n];
    };
    let num = |v: Option<f64>, d: usize| v.map_or("-".to_string(), |v| format!("{v:.d$}"));
    let worst = |v: Option<f64>, f: &Option<String>, d: usize| match (v, f) {
        (Some(v), Some(f)) => format!("{v:.d$} @{f}"),
        (None, Some(f)) => format!("NaN @{f}"),
        _ => num(v, d),
    };
    let mut cells = Vec::with_capacity(n);
    for i in TAIL_METRICS {
        let s = t.metrics.get(i);
        let d = DECIMALS[i];
        cells.push(num(s.mean, d));
        cells.push(num(s.p95, d));
        cells.push(worst(s.worst, &s.worst_frame, d));
    }
    let count = |c: Option<usize>| c.map_or("-".to_string(), |c| c.to_string());
    cells.push(count(t.frames_over_sdr_irr));
    cells.push(count(t.frames_over_sdr_irr_margin));
    cells.push(num(t.flicker.mean, 4));
    cells.push(worst(t.flicker.worst, &t.flicker.worst_frame, 4));
    cells
}

/// Lines of cells as aligned text: the first `left` columns left-aligned, the
/// others right-aligned, two spaces apart, a dashed line under the first (header)
/// line.
pub fn align_columns(lines: &[Vec<String>], left: usize) -> String {
    let ncol = lines.iter().map(|l| l.len()).max().unwrap_or(0);
    let widths: Vec<usize> = (0..ncol)
        .map(|c| {
            lines
                .iter()
                .map(|l| l.get(c).map_or(0, |s| s.chars().count()))
                .max()
                .unwrap_or(0)
        })
        .collect();
    let mut out = String::new();
    for (i, l) in lines.iter().enumerate() {
        let mut line = String::new();
        for (c, cell) in l.iter().enumerate() {
            if c > 0 {
                line.push_str("  ");
            }
            let pad = widths[c] - cell.chars().count();
            if c < left {
                line.push_str(cell);
                line.extend(std::iter::repeat(' ').take(pad));
            } else {
                line.extend(std::iter::repeat(' ').take(pad));
                line.push_str(cell);
            }
        }
        out.push_str(line.trim_end());
        out.push('\n');
        if i == 0 {
            let total = widths.iter().sum::<usize>() + 2 * ncol.saturating_sub(1);
            out.push_str(&"-".repeat(total));
            out.push('\n');
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(psnr: f64, invalid: u64) -> Metrics {
        Metrics {
            psnr_tm: psnr,
            ssim_tm: 0.9,
            mse_tm: 0.001,
            log_lum_rmse: 0.2,
            irradiance_rel_err: 0.1,
            dominant_dir_err_deg: 5.0,
            invalid_pixels: invalid,
        }
    }

    #[test]
    fn table_averages_rows_and_formats_text() {
        let t = MetricsTable::from_rows(vec![
            ("nearest", vec![m(20.0, 1), m(30.0, 2)]),
            ("warp", vec![m(35.0, 0)]),
            ("empty", vec![]),
        ]);
        assert_eq!(t.rows[0].frames, 2);
        let mean = t.rows[0].mean.unwrap();
        assert!((mean.psnr_tm - 25.0).abs() < 1e-12);
        assert_eq!(mean.invalid_pixels, 3);
        assert!(t.rows[2].mean.is_none());
        let text = t.to_text();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 5, "{text}");
        assert!(lines[0].starts_with("method") && lines[0].contains("psnr_tm"));
        assert!(lines[2].starts_with("nearest") && lines[2].contains("25.00"));
        assert!(lines[4].starts_with("empty") && lines[4].ends_with('-'));
    }

    #[test]
    fn rows_with_worst_case_statistics_print_a_second_table() {
        use crate::eval::summary::{summarize, FrameSample};
        let frames = [m(20.0, 0), m(30.0, 0)];
        let e = [1.0];
        let samples: Vec<FrameSample> = frames
            .iter()
            .zip(["f0", "f1"])
            .map(|(m, id)| FrameSample {
                id,
                metrics: m,
                irradiance: &e,
                truth_irradiance: &e,
                sdr_irradiance_err: Some(0.05),
            })
            .collect();
        let mut t = MetricsTable::new();
        t.push_with_tail("warp", &frames, summarize(&samples));
        t.push("empty", &[]);
        let text = t.to_text();
        assert!(text.contains("psnr_worst"), "{text}");
        let row = text.lines().rev().nth(1).unwrap();
        assert!(row.starts_with("warp"), "{text}");
        // Worst PSNR 20 at f0; both frames over the SDR baseline's 0.05 by 0.05.
        assert!(row.contains("20.00 @f0"), "{row}");
        let cells: Vec<&str> = row.split_whitespace().collect();
        assert_eq!(
            &cells[cells.len() - 5..cells.len() - 3],
            &["2", "2"],
            "{row}"
        );
        assert!(text.lines().last().unwrap().ends_with('-'));
        let back = MetricsTable::from_json(&t.to_json().unwrap()).unwrap();
        assert_eq!(back, t);
        // Old JSON without the statistics still reads.
        let old = r#"{"rows":[{"label":"a","frames":0,"mean":null}]}"#;
        assert!(MetricsTable::from_json(old).unwrap().rows[0].tail.is_none());
    }

    #[test]
    fn json_round_trip() {
        let t = MetricsTable::from_rows(vec![("a", vec![m(20.0, 0)]), ("b", vec![])]);
        let s = t.to_json().unwrap();
        assert_eq!(MetricsTable::from_json(&s).unwrap(), t);
        assert!(MetricsTable::from_json("{").is_err());
    }
}
