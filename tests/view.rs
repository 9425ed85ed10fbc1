//! `lumiprobe view` end to end in a real browser: the page is written for a run,
//! served by `lumiprobe view --serve` on 127.0.0.1 and opened in headless
//! Chromium (Debian's `chromium`, installed by scripts/setup.sh and .ci/run;
//! WebGL through SwiftShader). The page summarises what it shows in its
//! `#status` element (read from the DOM Chromium dumps); its screenshots are
//! read back as PNGs.

#[path = "common/data.rs"]
mod data;

use lumiprobe::image::luminance;
use std::io::{BufRead, BufReader};
#[path = "common/predictions.rs"]
mod predictions;
use predictions::scene_with_predictions;
use std::path::Path;
use std::process::{Child, Command, Stdio};

/// The server, stopped when dropped.
struct Served(Child);

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `lumiprobe ARGS`, run to its end.
fn lumiprobe(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args(args)
        .output()
        .unwrap()
}

/// `lumiprobe ARGS`, which must succeed.
fn lumiprobe_ok(args: &[&str]) {
    let o = lumiprobe(args);
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Starts `lumiprobe view ARGS --serve --port 0` and returns it with the
/// address it prints.
fn serve(args: &[&str]) -> (Served, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args(args)
        .args(["--serve", "--port", "0", "-q"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let served = Served(child);
    assert!(
        line.starts_with("http://127.0.0.1:"),
        "no address printed: {line:?}"
    );
    (served, line.trim().to_string())
}

/// Headless Chromium with WebGL on the CPU; fails with what to install when it
/// is missing.
fn chromium(args: &[String]) -> std::process::Output {
    let out = Command::new("chromium")
        .args([
            "--headless",
            "--no-sandbox",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--window-size=1280,900",
            "--virtual-time-budget=60000",
        ])
        .args(args)
        .output()
        .expect("headless Chromium is needed (Debian: apt install chromium; scripts/setup.sh and .ci/run install it)");
    assert!(
        out.status.success(),
        "chromium {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// The page's `#status` JSON once it has shown frame `k` (`query`: the
/// address's query, e.g. `?env=ktx2`, or empty).
fn status(url: &str, query: &str, k: usize) -> serde_json::Value {
    let out = chromium(&["--dump-dom".into(), format!("{url}{query}#frame={k}")]);
    let dom = String::from_utf8_lossy(&out.stdout);
    let start = dom
        .find("<pre id=\"status\">")
        .unwrap_or_else(|| panic!("no status in the page: {dom}"))
        + "<pre id=\"status\">".len();
    let end = start + dom[start..].find("</pre>").unwrap();
    let text = dom[start..end]
        .replace("&quot;", "\"")
        .replace("&amp;", "&");
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("status {text:?}: {e}"))
}

/// The page's screenshot at frame `k`, as luminance in 0..1 per pixel.
fn screenshot(url: &str, k: usize, dir: &Path) -> (usize, usize, Vec<f32>) {
    let png = dir.join(format!("shot_{k}.png"));
    chromium(&[
        format!("--screenshot={}", png.display()),
        format!("{url}#frame={k}"),
    ]);
    let img = lumiprobe::image::io::read_sdr(&png).unwrap();
    let lum = img
        .data()
        .chunks_exact(3)
        .map(|c| luminance([c[0] as f32, c[1] as f32, c[2] as f32]) / 255.0)
        .collect();
    (img.width(), img.height(), lum)
}

#[test]
fn the_page_shows_each_frame_with_a_lit_model_and_scrubbing_changes_it() {
    let tmp = tempfile::tempdir().unwrap();
    let (scene, run) = scene_with_predictions(tmp.path());
    let out = tmp.path().join("view");
    let model = data::shared_file("models/MaterialSpheres.glb");
    let args = [
        "view",
        scene.to_str().unwrap(),
        "--probes",
        run.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--model",
        model.to_str().unwrap(),
        "--ktx2",
    ];
    let (_server, url) = serve(&args);
    let view: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("view.json")).unwrap()).unwrap();
    let frames = view["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 3);
    assert_eq!(view["model"], "model.glb");
    assert_eq!(view["three"], "vendor/", "three.js not copied: {view}");

    let mut seen = Vec::new();
    for k in [0, 2] {
        let s = status(&url, "", k);
        assert_eq!(s["ready"], true, "frame {k}: {s}");
        assert!(s.get("error").is_none(), "frame {k}: {s}");
        assert_eq!(s["frame"], k);
        assert_eq!(s["id"], frames[k]["id"]);
        assert_eq!(s["lights"], frames[k]["light_count"]);
        assert!(
            s["sdr_width"].as_u64().unwrap() > 0,
            "SDR frame not shown: {s}"
        );
        // The model covers part of the viewport and is lit: its pixels are
        // neither black nor all white.
        assert!(s["model_pixels"].as_u64().unwrap() > 2000, "{s}");
        let lit = s["model_mean"].as_f64().unwrap();
        assert!(lit > 0.05 && lit < 0.98, "model mean {lit}: {s}");
        let probe = s["probe_mean"].as_f64().unwrap();
        assert!(probe > 0.02 && probe < 0.98, "probe mean {probe}: {s}");
        seen.push(s);
    }
    // Scrubbing changes the frame: the probe shown and the screenshots differ.
    assert_ne!(seen[0]["probe_mean"], seen[1]["probe_mean"]);
    let (w, h, a) = screenshot(&url, 0, tmp.path());
    let (w2, h2, b) = screenshot(&url, 2, tmp.path());
    assert_eq!((w, h), (w2, h2));
    for (k, img) in [(0, &a), (2, &b)] {
        let mean = img.iter().sum::<f32>() / img.len() as f32;
        let var = img.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / img.len() as f32;
        assert!(
            var.sqrt() > 0.05,
            "screenshot of frame {k} is blank (sd {})",
            var.sqrt()
        );
    }
    let changed = a
        .iter()
        .zip(&b)
        .filter(|(x, y)| (*x - *y).abs() > 0.02)
        .count();
    assert!(
        changed > a.len() / 50,
        "frames 0 and 2 look the same: {changed} of {} pixels changed",
        a.len()
    );
}

#[test]
fn bad_inputs_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    let (scene, run) = scene_with_predictions(tmp.path());
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let notes = tmp.path().join("notes.txt");
    std::fs::write(&notes, "not a model").unwrap();
    let v = tmp.path().join("v");
    let run_view = |extra: &[&str], probes: &Path| {
        let mut args = vec![
            "view",
            scene.to_str().unwrap(),
            "--probes",
            probes.to_str().unwrap(),
            "--out",
            v.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        lumiprobe(&args)
    };
    let o = run_view(&[], &empty);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("no prediction"),
        "{o:?}"
    );
    let o = run_view(&["--model", notes.to_str().unwrap()], &run);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("notes.txt") && err.contains("glTF"), "{err}");
    let o = run_view(&["--eval", empty.to_str().unwrap()], &run);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("eval"), "{o:?}");
}

#[test]
fn an_eval_report_comes_with_every_picture_it_shows() {
    let tmp = tempfile::tempdir().unwrap();
    let (scene, run) = scene_with_predictions(tmp.path());
    let report = tmp.path().join("report");
    let out = tmp.path().join("view");
    let (s, r) = (scene.to_str().unwrap(), run.to_str().unwrap());
    lumiprobe_ok(&["eval", s, "--pred", r, "--report", report.to_str().unwrap()]);
    lumiprobe_ok(&[
        "view",
        s,
        "--probes",
        r,
        "--out",
        out.to_str().unwrap(),
        "--eval",
        report.to_str().unwrap(),
    ]);
    let view: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("view.json")).unwrap()).unwrap();
    assert_eq!(view["eval"][0], "eval/report.html", "{view}");
    let html = std::fs::read_to_string(out.join("eval/report.html")).unwrap();
    let srcs: Vec<&str> = html
        .split("src=\"")
        .skip(1)
        .map(|t| &t[..t.find('"').unwrap()])
        .filter(|s| !s.starts_with("data:"))
        .collect();
    assert!(srcs.len() > 2, "the report shows pictures: {srcs:?}");
    for src in srcs {
        assert!(
            out.join("eval").join(src).is_file(),
            "{src} is missing beside the copied report"
        );
    }
}

#[test]
fn the_pages_probes_are_at_most_max_width_wide_with_their_light_kept() {
    let tmp = tempfile::tempdir().unwrap();
    let (scene, run) = scene_with_predictions(tmp.path());
    let (s, r) = (scene.to_str().unwrap(), run.to_str().unwrap());
    let power = |width: &str| {
        let out = tmp.path().join(format!("view{width}"));
        let out = out.to_str().unwrap();
        lumiprobe_ok(&[
            "view",
            s,
            "--probes",
            r,
            "--frames",
            "0",
            "--max-width",
            width,
            "--out",
            out,
        ]);
        let img =
            lumiprobe::image::io::read_hdr(&Path::new(out).join("probes/frame_000.hdr")).unwrap();
        (img.width(), lumiprobe::ibl::lights::integral(&img))
    };
    let (full_w, full) = power("4096");
    let (small_w, small) = power("32");
    assert_eq!((full_w, small_w), (128, 32));
    // RGBE rounding aside, the light is the same, channel by channel.
    for c in 0..3 {
        assert!(
            (small[c] / full[c] - 1.0).abs() < 0.01,
            "channel {c}: {small:?} against {full:?}"
        );
    }
}
