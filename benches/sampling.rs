//! Bilinear sampling's floor and the flow confidence's vector length, with and
//! without the library calls (libm's `floorf` and `hypotf` on targets without
//! SSE4.1), side by side in one run, best of a few: over the sample positions
//! of a 512x256 panorama turned by a small rotation. Run with
//! `cargo bench --bench sampling`.

#[path = "common/mod.rs"]
mod common;
use common::best_ms;

use std::hint::black_box;

use glam::Mat3;
use lumiprobe::image::HdrImage;
use lumiprobe::sphere::{dir_to_uv, floor, pixel_to_dir, rotate};

fn main() {
    let (w, h) = (512, 256);
    let r = Mat3::from_euler(glam::EulerRot::YXZ, 0.3, 0.05, -0.02);
    // Sample positions (pixels) of the turned panorama, as `rotate` makes them.
    let pos: Vec<(f32, f32)> = (0..w * h)
        .map(|i| {
            let (u, v) = dir_to_uv(r * pixel_to_dir(i % w, i / w, w, h));
            (u * w as f32 - 0.5, v * h as f32 - 0.5)
        })
        .collect();
    let lib = best_ms(20, || {
        let mut s = 0.0f32;
        for &(x, y) in &pos {
            s += black_box(x).floor() + black_box(y).floor();
        }
        black_box(s);
    });
    let ours = best_ms(20, || {
        let mut s = 0.0f32;
        for &(x, y) in &pos {
            s += floor(black_box(x)) + floor(black_box(y));
        }
        black_box(s);
    });
    println!("floor of {} sample positions: f32::floor {lib:.3} ms, sphere::floor {ours:.3} ms (ratio {:.2})", 2 * pos.len(), lib / ours);
    let hyp_lib = best_ms(20, || {
        let mut s = 0.0f32;
        for &(x, y) in &pos {
            s += black_box(x * 0.01).hypot(black_box(y * 0.01));
        }
        black_box(s);
    });
    let hyp_ours = best_ms(20, || {
        let mut s = 0.0f32;
        for &(x, y) in &pos {
            let (a, b) = (black_box(x * 0.01) as f64, black_box(y * 0.01) as f64);
            s += (a * a + b * b).sqrt() as f32;
        }
        black_box(s);
    });
    println!("length of {} vectors: f32::hypot {hyp_lib:.3} ms, f64 sum and sqrt {hyp_ours:.3} ms (ratio {:.2})", pos.len(), hyp_lib / hyp_ours);
    let img = HdrImage::from_fn(w, h, |x, y| [x as f32, y as f32, 1.0]);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let turn = pool.install(|| {
        best_ms(10, || {
            black_box(rotate(&img, r, w, h));
        })
    });
    println!("rotate 512x256, one thread: {turn:.2} ms");
}
