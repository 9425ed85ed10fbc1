//! `eval --report`'s one-page HTML report: the scores table (mean, p95 and
//! worst irradiance error), the error-against-distance plot, and a contact
//! sheet of tone-mapped probes, each prediction beside the ground truth.

use super::evaluate::SceneEval;
use crate::error::Result;
use crate::eval::METRIC_NAMES;
use crate::image::io::read_hdr_repaired;
use crate::image::SdrImage;
use crate::scene::Scene;
use crate::sphere::resize;
use crate::tonemap::{log_average_luminance, quantize, reinhard_global};
use std::fmt::Write as _;
use std::path::Path;

/// Name of the page in the report folder.
pub const REPORT_FILE: &str = "report.html";

/// Frames in the contact sheet at most, spread over the walk.
const CONTACT_FRAMES: usize = 8;

/// Size of a contact-sheet thumbnail.
const THUMB: (usize, usize) = (256, 128);

/// `s` with the characters HTML gives a meaning escaped.
fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A thumbnail of `img` tone-mapped with the log-average `log_avg` (the
/// truth's, so that every probe of a frame is shown alike).
fn thumbnail(img: &crate::image::HdrImage, log_avg: f32) -> Result<SdrImage> {
    let small = resize(img, THUMB.0, THUMB.1);
    let v = reinhard_global(&small, 0.18, None, Some(log_avg));
    SdrImage::from_vec(THUMB.0, THUMB.1, quantize(&v))
}

/// Writes `report.html` and its contact sheet (`contact/`) into `dir`, beside
/// the `error_vs_distance.png` the caller wrote: `ev` is the evaluation of
/// `preds` (label and folder of each) on `scene`.
pub fn write_report(
    dir: &Path,
    scene: &Scene,
    ev: &SceneEval,
    preds: &[(String, &Path)],
) -> Result<()> {
    let mut h = String::new();
    let title = format!("lumiprobe evaluation: {}", escape(&ev.scene));
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{title}</title>\n\
         <style>body{{font-family:sans-serif;margin:2em}}table{{border-collapse:collapse}}\
         td,th{{border:1px solid #bbb;padding:3px 8px;text-align:right}}\
         td:first-child,th:first-child{{text-align:left}}img{{display:block}}\
         .sheet td{{text-align:center;font-size:small}}</style></head><body>\n<h1>{title}</h1>\n"
    );
    for (label, f) in &ev.scales {
        let _ = writeln!(
            h,
            "<p>{} was rescaled by {f:.5} to the truth's scale.</p>",
            escape(label)
        );
    }
    // Scores: the means of every metric, then the irradiance error's tail.
    h += "<h2>Scores (mean over frames)</h2>\n<table><tr><th>method</th><th>frames</th>";
    for n in METRIC_NAMES {
        let _ = write!(h, "<th>{n}</th>");
    }
    h += "<th>irradiance p95</th><th>irradiance worst</th></tr>\n";
    for r in &ev.table.rows {
        let _ = write!(h, "<tr><td>{}</td><td>{}</td>", escape(&r.label), r.frames);
        match &r.mean {
            Some(m) => {
                for v in m.values() {
                    let _ = write!(h, "<td>{v:.4}</td>");
                }
            }
            None => h += &"<td>-</td>".repeat(METRIC_NAMES.len()),
        }
        match &r.tail {
            Some(t) => {
                let s = &t.metrics.irradiance_rel_err;
                let num = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.4}"));
                let _ = write!(
                    h,
                    "<td>{}</td><td>{} ({})</td>",
                    num(s.p95),
                    num(s.worst),
                    escape(s.worst_frame.as_deref().unwrap_or("-"))
                );
            }
            None => h += "<td>-</td><td>-</td>",
        }
        h += "</tr>\n";
    }
    h += "</table>\n<h2>Error against distance to the nearest probe</h2>\n\
          <img src=\"error_vs_distance.png\" alt=\"error against distance\">\n";
    // The contact sheet: a few frames spread over the walk.
    let with_truth: Vec<usize> = (0..scene.frames.len())
        .filter(|&i| scene.frames[i].ground_truth.is_some())
        .collect();
    let n = with_truth.len().min(CONTACT_FRAMES);
    let picked: Vec<usize> = (0..n)
        .map(|k| with_truth[k * with_truth.len() / n.max(1)])
        .collect();
    let contact = dir.join("contact");
    std::fs::create_dir_all(&contact).map_err(|e| crate::Error::io(&contact, e))?;
    h += "<h2>Contact sheet (tone-mapped alike per frame: the truth's log-average)</h2>\n\
          <table class=\"sheet\"><tr><th>frame</th><th>truth</th>";
    for (label, _) in preds {
        let _ = write!(h, "<th>{}</th>", escape(label));
    }
    h += "</tr>\n";
    for &i in &picked {
        let f = &scene.frames[i];
        let Some(gt) = &f.ground_truth else { continue };
        let (truth, _) = read_hdr_repaired(gt)?;
        let la = log_average_luminance(&truth);
        let mut cells = vec![(format!("{}_truth.png", f.id), Some(truth))];
        for (k, (_, d)) in preds.iter().enumerate() {
            let p = d.join(format!("{}.exr", f.id));
            let img = if p.is_file() {
                Some(read_hdr_repaired(&p)?.0)
            } else {
                None
            };
            cells.push((format!("{}_{k}.png", f.id), img));
        }
        let _ = write!(h, "<tr><td>{}</td>", escape(&f.id));
        for (name, img) in cells {
            match img {
                Some(img) => {
                    crate::image::io::write_sdr(&contact.join(&name), &thumbnail(&img, la)?)?;
                    let _ = write!(
                        h,
                        "<td><img src=\"contact/{name}\" width=\"{}\" height=\"{}\" alt=\"{name}\"></td>",
                        THUMB.0, THUMB.1
                    );
                }
                None => h += "<td>no prediction</td>",
            }
        }
        h += "</tr>\n";
    }
    h += "</table>\n</body></html>\n";
    crate::fsutil::write_atomic(&dir.join(REPORT_FILE), h.as_bytes())
}
