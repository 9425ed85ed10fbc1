//! `lumiprobe view`: a web page to look through a run.

use clap::Args;
use lumiprobe::pipeline::view::{serve, write_view, ViewOptions};
use lumiprobe::Result;
use std::path::PathBuf;

/// Arguments of `lumiprobe view`.
#[derive(Args)]
pub struct ViewArgs {
    /// Scene folder, poses.json or manifest (for the SDR frames and poses).
    scene: PathBuf,
    /// A `lumiprobe run` output folder (frame_XXX.exr).
    #[arg(long)]
    probes: PathBuf,
    /// Folder for the page (default: `view` inside the run's folder).
    #[arg(long)]
    out: Option<PathBuf>,
    /// A glTF model (.glb, or .gltf with its files) to light (default: three
    /// spheres, diffuse, glossy and mirror).
    #[arg(long)]
    model: Option<PathBuf>,
    /// An `eval --report` folder whose report and plots the page shows.
    #[arg(long)]
    eval: Option<PathBuf>,
    /// Frames to show, by index in walk order: `3`, `0-9`, `0,4,8-12`
    /// (default: every frame with a prediction).
    #[arg(long, value_parser = super::export::parse_frames)]
    frames: Option<super::export::FrameList>,
    /// three.js's npm package folder (default: tools/js/node_modules/three,
    /// else the page loads it from a CDN).
    #[arg(long)]
    three: Option<PathBuf>,
    /// Also write each frame's GGX-prefiltered cube as KTX 2.0: the page can
    /// light the model with it (read with npm ktx-parse) instead of the
    /// equirect and the lights.
    #[arg(long)]
    ktx2: bool,
    /// Largest width of the probes the page loads (wider ones are box filtered
    /// down, their light kept).
    #[arg(long, default_value_t = lumiprobe::pipeline::view::VIEW_MAX_WIDTH)]
    max_width: usize,
    /// Serve the page on 127.0.0.1 until interrupted (browsers run the page's
    /// modules only from http://).
    #[arg(long)]
    serve: bool,
    /// Port to serve on (0: any free one).
    #[arg(long, default_value_t = 8000)]
    port: u16,
}

/// Runs the command; prints what was written (and where it is served) unless
/// `quiet`.
pub fn run(a: ViewArgs, quiet: bool) -> Result<()> {
    let scene = lumiprobe::pipeline::plan::load_scene(&a.scene, !quiet)?;
    let out = a.out.unwrap_or_else(|| a.probes.join("view"));
    let opts = ViewOptions {
        model: a.model,
        eval: a.eval,
        three: a.three,
        frames: a.frames.map(|f| f.0),
        ktx2: a.ktx2,
        max_width: a.max_width,
    };
    let rep = write_view(&scene, &a.probes, &out, &opts)?;
    for w in &rep.warnings {
        eprintln!("{w}");
    }
    if !quiet {
        eprintln!(
            "{} frames in {}",
            rep.frames.len(),
            out.join("index.html").display()
        );
    }
    if a.serve {
        let server = serve(&out, a.port)?;
        // The address on stdout, alone on its line, for scripts (and tests).
        println!("{}", server.url()?);
        use std::io::Write;
        let _ = std::io::stdout().flush();
        if !quiet {
            eprintln!("serving until interrupted (Ctrl-C)");
        }
        server.run()?;
    } else if !quiet {
        eprintln!(
            "open it through a web server, e.g. `lumiprobe view {} --probes {} --out {} --serve`",
            a.scene.display(),
            a.probes.display(),
            out.display()
        );
    }
    Ok(())
}
