//! Bracket merging speed: Debevec-Malik response recovery and the merge of seven
//! 512x256 exposures (-3..+3 EV), best of a few runs. Run with
//! `cargo bench --bench merge [-- BRACKET_DIR]`; BRACKET_DIR holds JPEGs with
//! Exif exposure times (e.g. a probe folder of the evaluation data). Without it a
//! synthetic room-like panorama is shot through the documented response.

#[path = "common/mod.rs"]
mod common;
use common::best_ms;

use std::path::PathBuf;

use lumiprobe::capture::cli::load_exposures;
use lumiprobe::capture::{merge, recover, Exposure, MergeOptions, RecoverOptions};
use lumiprobe::image::{HdrImage, SdrImage};
use lumiprobe::sphere::pixel_to_dir;
use lumiprobe::tonemap::Response;

fn synthetic() -> Vec<Exposure> {
    let (w, h) = (512, 256);
    let scene = HdrImage::from_fn(w, h, |x, y| {
        let d = pixel_to_dir(x, y, w, h);
        let s = 10f32.powf(-1.0 + 2.5 * (x as f32 / w as f32)) * (1.2 + d.y);
        [0.8 * s, s, 1.1 * s]
    });
    let resp = Response::RationalGamma {
        scale: 1.08,
        knee: 0.08,
        gamma: 2.2,
    };
    (-3..=3)
        .map(|ev: i32| {
            let t = 2f64.powi(ev) / 60.0;
            let data: Vec<u8> = scene
                .data()
                .iter()
                .map(|&e| (resp.encode((0.33 * 60.0 * t) as f32 * e) * 255.0).round() as u8)
                .collect();
            Exposure {
                name: PathBuf::from(format!("ev{ev:+}")),
                image: SdrImage::from_vec(w, h, data).expect("size"),
                time_s: t,
            }
        })
        .collect()
}

fn main() {
    let arg = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let exps = match &arg {
        Some(dir) => {
            let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
                .unwrap_or_else(|e| panic!("{dir}: {e}"))
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("jpg")))
                .collect();
            files.sort();
            load_exposures(&files, None).unwrap_or_else(|e| panic!("{e}"))
        }
        None => synthetic(),
    };
    let (w, h) = (exps[0].image.width(), exps[0].image.height());
    println!(
        "{} exposures of {w}x{h} from {}",
        exps.len(),
        arg.as_deref().unwrap_or("a synthetic panorama")
    );
    let images: Vec<&SdrImage> = exps.iter().map(|e| &e.image).collect();
    let times: Vec<f64> = exps.iter().map(|e| e.time_s).collect();
    let opts = RecoverOptions::default();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    for threads in [1, cores] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool");
        pool.install(|| {
            let rec_ms = best_ms(3, || {
                std::hint::black_box(recover(&images, &times, &opts).expect("recover"));
            });
            let curve = recover(&images, &times, &opts).expect("recover").curve;
            let merge_ms = best_ms(3, || {
                std::hint::black_box(
                    merge(&exps, &curve, &MergeOptions::default()).expect("merge"),
                );
            });
            println!(
                "{threads} thread(s): response recovery {rec_ms:.1} ms, merge {merge_ms:.1} ms"
            );
        });
    }
}
