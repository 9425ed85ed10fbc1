//! The bounds a method is held to on every scene (`corpus_bounds.txt`): the
//! irradiance error's mean, 95th percentile and worst frame, the dominant
//! light's direction, no frame much worse than the linearised SDR frame,
//! tone-mapped PSNR at least the SDR frame's, and log-luminance RMSE below every
//! other method's and baseline's on the same scene. Each scene row says which
//! bounds it meets; the totals count the scenes per split that meet each.

use super::{CorpusReport, CorpusRow, Split};
use crate::pipeline::evaluate::{ANSWERABLE, BASELINE_SDR};

/// The bounds, as fractions and degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    /// Largest mean irradiance error over a scene's frames.
    pub irr_mean: f64,
    /// Largest 95th percentile of the irradiance error over a scene's frames.
    pub irr_p95: f64,
    /// Largest irradiance error of any frame.
    pub irr_worst: f64,
    /// Largest mean dominant-light direction error on a scene (degrees).
    pub dir_scene_deg: f64,
    /// Largest dominant-light direction error averaged over a split's scenes.
    pub dir_split_deg: f64,
}

/// The bounds of issue 19.
pub const ISSUE_19: Bounds = Bounds {
    irr_mean: 0.06,
    irr_p95: 0.15,
    irr_worst: 0.35,
    dir_scene_deg: 6.0,
    dir_split_deg: 3.0,
};

/// Names of the checks, in column order.
pub const CHECKS: [&str; 7] = [
    "irr_mean",
    "irr_p95",
    "irr_worst",
    "dir",
    "no_frame>sdr+2",
    "psnr>=sdr",
    "log_rmse_best",
];

/// One scene's checks for one method row: `None` where the row lacks the
/// figure (a failed run, no SDR baseline, no frames).
#[derive(Clone, Debug, PartialEq)]
pub struct SceneChecks {
    /// Scene name.
    pub scene: String,
    /// The scene's split.
    pub split: Split,
    /// The method's row label (`fusion` or `fusion@answerable`).
    pub method: String,
    /// One per [`CHECKS`].
    pub pass: [Option<bool>; 7],
    /// The scene's mean dominant-light direction error, for the split average.
    pub dir_deg: Option<f64>,
}

/// The row of `label` on `scene`, scored.
fn find<'a>(rows: &'a [CorpusRow], scene: &str, label: &str) -> Option<&'a CorpusRow> {
    rows.iter()
        .find(|r| r.scene == scene && r.method == label && r.error.is_none() && r.frames > 0)
}

/// The checks of every method row that is not a baseline.
pub fn check(r: &CorpusReport, b: &Bounds) -> Vec<SceneChecks> {
    let mut out = Vec::new();
    for row in &r.rows {
        if row.method.starts_with("baseline:") {
            continue;
        }
        let Some(t) = row
            .tail
            .as_ref()
            .filter(|_| row.error.is_none() && row.frames > 0)
        else {
            continue;
        };
        let m = &t.metrics;
        let le = |v: Option<f64>, bound: f64| v.map(|v| v <= bound);
        // Compared on the same frames: the answerable row against the others'
        // answerable rows.
        let suffix = if row.method.ends_with(ANSWERABLE) {
            ANSWERABLE
        } else {
            ""
        };
        let sdr = find(&r.rows, &row.scene, &format!("{BASELINE_SDR}{suffix}"))
            .and_then(|s| s.tail.as_ref());
        let psnr = match (m.psnr_tm.mean, sdr.and_then(|s| s.metrics.psnr_tm.mean)) {
            (Some(a), Some(s)) => Some(a >= s),
            _ => None,
        };
        let others: Vec<f64> = r
            .rows
            .iter()
            .filter(|o| {
                o.scene == row.scene
                    && o.method != row.method
                    && o.error.is_none()
                    && o.frames > 0
                    && o.method.ends_with(ANSWERABLE) != suffix.is_empty()
            })
            .filter_map(|o| o.tail.as_ref().and_then(|t| t.metrics.log_lum_rmse.mean))
            .collect();
        let best = m
            .log_lum_rmse
            .mean
            .filter(|_| !others.is_empty())
            .map(|v| others.iter().all(|&o| v < o));
        out.push(SceneChecks {
            scene: row.scene.clone(),
            split: row.split,
            method: row.method.clone(),
            pass: [
                le(m.irradiance_rel_err.mean, b.irr_mean),
                le(m.irradiance_rel_err.p95, b.irr_p95),
                le(m.irradiance_rel_err.worst, b.irr_worst),
                le(m.dominant_dir_err_deg.mean, b.dir_scene_deg),
                t.frames_over_sdr_irr_margin.map(|n| n == 0),
                psnr,
                best,
            ],
            dir_deg: m.dominant_dir_err_deg.mean,
        });
    }
    out
}

/// The text of `corpus_bounds.txt`.
pub fn to_text(r: &CorpusReport, b: &Bounds) -> String {
    let checks = check(r, b);
    let mut s = format!(
        "bounds per scene: irradiance error mean <= {}, p95 <= {}, worst <= {}; dominant \
         direction <= {} deg per scene and <= {} deg over a split; no frame over the SDR \
         frame's irradiance error + 0.02; PSNR >= the SDR frame's; log-luminance RMSE below \
         every other row's on the scene (answerable rows against answerable rows). \
         yes / NO / - (no figure)\n",
        b.irr_mean, b.irr_p95, b.irr_worst, b.dir_scene_deg, b.dir_split_deg
    );
    let mut header: Vec<String> = vec!["split".into(), "scene".into(), "method".into()];
    header.extend(CHECKS.iter().map(|c| c.to_string()));
    let mut lines = vec![header.clone()];
    let mark = |p: Option<bool>| match p {
        Some(true) => "yes".to_string(),
        Some(false) => "NO".to_string(),
        None => "-".to_string(),
    };
    for c in &checks {
        let mut cells = vec![
            c.split.name().to_string(),
            c.scene.clone(),
            c.method.clone(),
        ];
        cells.extend(c.pass.iter().map(|&p| mark(p)));
        lines.push(cells);
    }
    s.push_str(&crate::eval::table::align_columns(&lines, 3));
    s.push_str(
        "\nscenes meeting each bound, per split and method (of the scenes with the figure)\n",
    );
    header[1] = "scenes".into();
    header.push("dir_split_mean".into());
    let mut lines = vec![header];
    let mut keys: Vec<(Split, String)> = Vec::new();
    for c in &checks {
        if !keys.contains(&(c.split, c.method.clone())) {
            keys.push((c.split, c.method.clone()));
        }
    }
    keys.sort_by_key(|(s, _)| *s);
    for (split, method) in keys {
        let of: Vec<&SceneChecks> = checks
            .iter()
            .filter(|c| c.split == split && c.method == method)
            .collect();
        let mut cells = vec![split.name().to_string(), of.len().to_string(), method];
        for k in 0..CHECKS.len() {
            let with: Vec<bool> = of.iter().filter_map(|c| c.pass[k]).collect();
            let met = with.iter().filter(|&&p| p).count();
            cells.push(format!("{met}/{}", with.len()));
        }
        let dirs: Vec<f64> = of.iter().filter_map(|c| c.dir_deg).collect();
        cells.push(if dirs.is_empty() {
            "-".into()
        } else {
            let m = dirs.iter().sum::<f64>() / dirs.len() as f64;
            format!("{m:.2} {}", if m <= b.dir_split_deg { "yes" } else { "NO" })
        });
        lines.push(cells);
    }
    s.push_str(&crate::eval::table::align_columns(&lines, 3));
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::summary::{RowSummary, Stat};

    fn stat(mean: f64, p95: f64, worst: f64) -> Stat {
        Stat {
            mean: Some(mean),
            p95: Some(p95),
            worst: Some(worst),
            worst_frame: Some("f0".into()),
            nan_frames: 0,
        }
    }

    fn row(scene: &str, method: &str, irr: (f64, f64, f64), psnr: f64, log: f64) -> CorpusRow {
        let mut t = RowSummary::default();
        t.metrics.irradiance_rel_err = stat(irr.0, irr.1, irr.2);
        t.metrics.psnr_tm = stat(psnr, psnr, psnr);
        t.metrics.log_lum_rmse = stat(log, log, log);
        t.metrics.dominant_dir_err_deg = stat(2.0, 3.0, 4.0);
        t.frames_over_sdr_irr_margin = Some(0);
        CorpusRow {
            scene: scene.into(),
            split: Split::Dev,
            seed: None,
            method: method.into(),
            frames: 3,
            error: None,
            mean: None,
            tail: Some(t),
        }
    }

    fn report(rows: Vec<CorpusRow>) -> CorpusReport {
        CorpusReport {
            roots: vec![],
            scenes: vec![],
            methods: vec![],
            size: None,
            rows,
            totals: vec![],
        }
    }

    #[test]
    fn each_bound_is_checked_against_the_scene_rows() {
        let r = report(vec![
            row("a", "fusion", (0.05, 0.2, 0.3), 31.0, 0.05),
            row("a", "flow", (0.3, 0.5, 0.9), 25.0, 0.04),
            row("a", BASELINE_SDR, (0.6, 0.7, 0.8), 30.0, 0.1),
        ]);
        let c = check(&r, &ISSUE_19);
        let fusion = c.iter().find(|c| c.method == "fusion").unwrap();
        // Mean within, p95 over, worst within, direction within, no frame over,
        // PSNR above the SDR frame's, log RMSE above flow's.
        assert_eq!(
            fusion.pass,
            [
                Some(true),
                Some(false),
                Some(true),
                Some(true),
                Some(true),
                Some(true),
                Some(false)
            ]
        );
        let text = to_text(&r, &ISSUE_19);
        assert!(text.contains("1/1"), "{text}");
        assert!(text.contains("0/1"), "{text}");
    }

    #[test]
    fn a_row_without_the_sdr_baseline_has_no_psnr_check() {
        let r = report(vec![row("a", "fusion", (0.01, 0.02, 0.03), 31.0, 0.05)]);
        let c = check(&r, &ISSUE_19);
        assert_eq!(c.len(), 1);
        assert_eq!(c[0].pass[5], None);
        assert_eq!(c[0].pass[6], None);
    }
}
