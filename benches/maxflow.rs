//! Throughput of the Boykov–Kolmogorov max-flow and of alpha-expansion / swap on
//! panorama-sized grids. Run with `cargo bench --bench maxflow`.
//!
//! The max-flow graphs mimic a binary segmentation (Boykov & Jolly 2001): a noisy
//! image of bright blobs on a dark background, t-links from Gaussian likelihoods,
//! n-links `2 exp(-dI^2 / 2 beta)`. Timings cover the whole `max_flow` call
//! (validation, graph packing and the solve); best of a few runs.

use std::time::Instant;

use lumiprobe::flow::graphcut::{self, GridEnergy, Optimizer, INFEASIBLE};
use lumiprobe::synth::rng::SplitMix64;

type Graph = (usize, Vec<(u32, u32, f64, f64)>, Vec<(f64, f64)>);

/// Smooth structure plus Gaussian noise, values roughly in [0, 1].
fn image(w: usize, h: usize, seed: u64) -> Vec<f64> {
    let mut rng = SplitMix64::new(seed);
    let blobs: Vec<(f64, f64, f64)> = (0..12)
        .map(|_| {
            (
                rng.range(0.0, w as f64),
                rng.range(0.0, h as f64),
                rng.range(0.05, 0.2) * h as f64,
            )
        })
        .collect();
    let mut img = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let inside = blobs.iter().any(|&(cx, cy, r)| {
                let (dx, dy) = (x as f64 - cx, y as f64 - cy);
                dx * dx + dy * dy < r * r
            });
            let base = if inside { 0.75 } else { 0.25 };
            img[y * w + x] = base + 0.15 * rng.gaussian();
        }
    }
    img
}

fn segmentation_graph(w: usize, h: usize, seed: u64) -> Graph {
    let img = image(w, h, seed);
    let sigma2 = 2.0 * 0.15 * 0.15;
    let terminals = img
        .iter()
        .map(|&v| {
            let fg = (v - 0.75) * (v - 0.75) / sigma2;
            let bg = (v - 0.25) * (v - 0.25) / sigma2;
            (bg, fg) // source side = foreground pays fg on the sink link
        })
        .collect();
    let beta = 2.0 * 0.15 * 0.15;
    let mut edges = Vec::with_capacity(2 * w * h);
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let mut link = |q: usize| {
                let d = img[p] - img[q];
                let c = 2.0 * (-d * d / beta).exp();
                edges.push((p as u32, q as u32, c, c));
            };
            if x + 1 < w {
                link(p + 1);
            }
            if y + 1 < h {
                link(p + w);
            }
        }
    }
    (w * h, edges, terminals)
}

fn best_of<T>(runs: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..runs {
        let t = Instant::now();
        let r = f();
        best = best.min(t.elapsed().as_secs_f64() * 1e3);
        out = Some(r);
    }
    (best, out.unwrap())
}

/// Three candidate "probes" on a panorama: smooth tone-mapped colours that differ
/// per label, data costs with structure, one label infeasible in a band.
fn fusion_problem(w: usize, h: usize, seed: u64) -> (Vec<f32>, Vec<f32>) {
    let (l, c) = (3usize, 3usize);
    let mut rng = SplitMix64::new(seed);
    let base = image(w, h, seed ^ 0x55);
    let mut data = vec![0.0f32; w * h * l];
    let mut feat = vec![0.0f32; w * h * l * c];
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let u = x as f64 / w as f64;
            for k in 0..l {
                let shift = 0.1 * (u * std::f64::consts::TAU * (k + 1) as f64).sin();
                for ch in 0..c {
                    feat[(p * l + k) * c + ch] =
                        (base[p] + shift + 0.02 * ch as f64 + 0.03 * rng.gaussian()) as f32;
                }
                let pref = ((u * 3.0) as usize % l == k) as u8 as f64;
                data[p * l + k] = (1.0 - 0.8 * pref + 0.3 * rng.next_f64()) as f32;
            }
            if (h / 3..h / 2).contains(&y) {
                data[p * l + 2] = INFEASIBLE;
            }
        }
    }
    (data, feat)
}

fn main() {
    println!(
        "{:<38} {:>9} {:>9} {:>10} {:>12}",
        "case", "nodes", "edges", "ms", "Mnodes/s"
    );
    for &(w, h, runs) in &[(512usize, 256usize, 5usize), (2048, 1024, 2)] {
        let (n, edges, terminals) = segmentation_graph(w, h, 7);
        let (ms, (flow, side)) =
            best_of(runs, || graphcut::max_flow(n, &edges, &terminals).unwrap());
        let fg = side.iter().filter(|&&s| s).count();
        println!(
            "{:<38} {:>9} {:>9} {:>10.1} {:>12.2}   flow {:.1}, {:.1}% source side",
            format!("max-flow {w}x{h} segmentation"),
            n,
            edges.len(),
            ms,
            n as f64 / ms / 1e3,
            flow,
            100.0 * fg as f64 / n as f64
        );
    }
    let (w, h) = (512usize, 256usize);
    let (data, feat) = fusion_problem(w, h, 11);
    for lambda in [1.0f32, 5.0] {
        let e = GridEnergy {
            width: w,
            height: h,
            labels: 3,
            data: &data,
            features: &feat,
            channels: 3,
            lambda,
            wrap_x: true,
        };
        let e0 = {
            let (d, s) = graphcut::energy(&e, &graphcut::argmin_labels(&e)).unwrap();
            d + s
        };
        for opt in [Optimizer::Expansion, Optimizer::Swap] {
            let (ms, r) = best_of(3, || graphcut::optimize(&e, opt, 20, None).unwrap());
            let changed = r
                .labels
                .iter()
                .zip(graphcut::argmin_labels(&e))
                .filter(|(a, b)| **a != *b)
                .count();
            println!(
                "{:<38} {:>9} {:>9} {:>10.1} {:>12.2}   {} cycles, energy {:.0} -> {:.0}, {:.1}% relabelled",
                format!("{opt:?} 3 labels {w}x{h} lambda {lambda}").to_lowercase(),
                w * h,
                2 * w * h - w,
                ms,
                (w * h) as f64 / ms / 1e3,
                r.cycles,
                e0,
                r.energy,
                100.0 * changed as f64 / (w * h) as f64
            );
        }
    }
}
