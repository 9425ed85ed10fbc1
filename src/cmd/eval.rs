//! `lumiprobe eval`: predictions scored against the ground truth, with both baselines.

use super::args::*;
use lumiprobe::image::io;
use lumiprobe::{Error, Result};
use std::path::{Path, PathBuf};

/// Arguments of `lumiprobe eval`.
#[derive(clap::Args)]
pub struct EvalArgs {
    /// Scene folder.
    pub scene: PathBuf,
    /// Prediction folder(s) from `lumiprobe run`; `LABEL=DIR` names a row.
    #[arg(long, required = true)]
    pub pred: Vec<String>,
    /// Print JSON (table and per-frame scores) instead of the text table.
    #[arg(long)]
    pub json: bool,
    /// Rescale each prediction to the truth's global scale first (one factor
    /// per folder, reported): for runs on probes merged from brackets, whose
    /// absolute scale is unknowable.
    #[arg(long)]
    pub rescale: bool,
    /// Folder of glTF models (.glb/.gltf): also render each lit by every
    /// prediction, baseline and the ground truth, and score the renders (the
    /// thesis's Table 5.1).
    #[arg(long)]
    pub models: Option<PathBuf>,
    /// Frames rendered per scene with `--models` (spread over the walk; 0 = all).
    #[arg(long, default_value_t = 5)]
    pub render_frames: usize,
    /// Render size in pixels with `--models`.
    #[arg(long, default_value_t = 256)]
    pub render_size: usize,
    /// Folder for the report: report.html (the tables, the plot and a contact
    /// sheet of tone-mapped probes against the truth), eval.json,
    /// error_vs_distance.csv and .png, and renders.json with `--models`.
    #[arg(long)]
    pub report: Option<PathBuf>,
}

/// Runs the command (progress and notes on stderr unless `quiet`).
pub fn run(a: EvalArgs, quiet: bool) -> Result<()> {
    let EvalArgs {
        scene,
        pred,
        json,
        rescale,
        models,
        render_frames,
        render_size,
        report,
    } = a;
    let scene = lumiprobe::pipeline::plan::load_scene(&scene, !quiet)?;
    let labelled: Vec<(String, PathBuf)> = pred
        .iter()
        .map(|p| match p.split_once('=') {
            Some((l, d)) => (l.to_string(), PathBuf::from(d)),
            None => {
                let label = report_method(Path::new(p)).unwrap_or_else(|| "prediction".into());
                (label, PathBuf::from(p))
            }
        })
        .collect();
    let refs: Vec<(String, &Path)> = labelled
        .iter()
        .map(|(l, d)| (l.clone(), d.as_path()))
        .collect();
    let ev = if rescale {
        lumiprobe::pipeline::evaluate::evaluate_rescaled(&scene, &refs)?
    } else {
        use lumiprobe::pipeline::evaluate::{scale_factors, scale_warning};
        for ((label, dir), (_, f)) in refs.iter().zip(scale_factors(&scene, &refs)?) {
            if let Some(w) = scale_warning(label, dir, f) {
                eprintln!("{w}");
            }
        }
        lumiprobe::pipeline::evaluate::evaluate(&scene, &refs)?
    };
    if !json {
        for (l, f) in &ev.scales {
            println!("{l}: rescaled by {f:.5}");
        }
    }
    if json {
        println!("{}", lumiprobe::error::to_json(&ev)?);
    } else {
        println!("scene {}", ev.scene);
        print!("{}", ev.table.to_text());
        print!("{}", lumiprobe::pipeline::evaluate::distance_table(&ev, 3));
    }
    let renders = match &models {
        Some(dir) => {
            let files = model_files(dir)?;
            let opts = lumiprobe::pipeline::render_eval::RenderEvalOptions {
                frames: render_frames,
                size: render_size,
                ..Default::default()
            };
            let re = lumiprobe::pipeline::render_eval::render_eval(&scene, &refs, &files, &opts)?;
            if !json {
                println!("renders (lit by each probe vs by the ground truth)");
                print!("{}", re.to_text());
            }
            Some(re)
        }
        None => None,
    };
    if let Some(dir) = report {
        std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        let js = lumiprobe::error::to_json(&ev)?.into_bytes();
        lumiprobe::fsutil::write_atomic(&dir.join("eval.json"), &js)?;
        let csv = lumiprobe::pipeline::evaluate::distance_csv(&ev);
        lumiprobe::fsutil::write_atomic(&dir.join("error_vs_distance.csv"), csv.as_bytes())?;
        let plot = lumiprobe::pipeline::evaluate::distance_plot(&ev, renders.as_ref());
        io::write_sdr(&dir.join("error_vs_distance.png"), &plot.draw(800, 500))?;
        if let Some(re) = &renders {
            let js = lumiprobe::error::to_json(re)?.into_bytes();
            lumiprobe::fsutil::write_atomic(&dir.join("renders.json"), &js)?;
        }
        lumiprobe::pipeline::report_html::write_report(&dir, &scene, &ev, &refs)?;
    }
    Ok(())
}
