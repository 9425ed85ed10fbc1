//! Aggregation of per-frame [`Metrics`] into one row per method, printed as a plain
//! text table or serialised as JSON, for reports and regression checks.

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
        });
    }

    /// Plain-text table: a header, then one line per row with the label, frame
    /// count, the six mean scores and the total of invalid pixels; `-` for rows
    /// without frames. Columns are aligned with spaces.
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
        let ncol = lines[0].len();
        let widths: Vec<usize> = (0..ncol)
            .map(|c| {
                lines
                    .iter()
                    .map(|l| l[c].chars().count())
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
                if c == 0 {
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
                let total = widths.iter().sum::<usize>() + 2 * (ncol - 1);
                out.push_str(&"-".repeat(total));
                out.push('\n');
            }
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
    fn json_round_trip() {
        let t = MetricsTable::from_rows(vec![("a", vec![m(20.0, 0)]), ("b", vec![])]);
        let s = t.to_json().unwrap();
        assert_eq!(MetricsTable::from_json(&s).unwrap(), t);
        assert!(MetricsTable::from_json("{").is_err());
    }
}
