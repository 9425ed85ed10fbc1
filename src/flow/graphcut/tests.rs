use super::*;
use crate::synth::rng::SplitMix64;

type Edge = (u32, u32, f64, f64);

/// A `w` x `h` grid of two labels with one feature channel, weight 1, no wrap.
fn two_labels<'a>(w: usize, h: usize, data: &'a [f32], feat: &'a [f32]) -> GridEnergy<'a> {
    GridEnergy {
        width: w,
        height: h,
        labels: 2,
        data,
        features: feat,
        channels: 1,
        lambda: 1.0,
        wrap_x: false,
    }
}

fn cut_capacity(edges: &[Edge], terminals: &[(f64, f64)], src: &[bool]) -> f64 {
    let mut c = 0.0;
    for (i, &(s, t)) in terminals.iter().enumerate() {
        c += if src[i] { t } else { s };
    }
    for &(u, v, cap, rev) in edges {
        match (src[u as usize], src[v as usize]) {
            (true, false) => c += cap,
            (false, true) => c += rev,
            _ => {}
        }
    }
    c
}

fn random_graph(rng: &mut SplitMix64, integer: bool) -> (usize, Vec<Edge>, Vec<(f64, f64)>) {
    let n = 1 + rng.below(12) as usize;
    let cap = |rng: &mut SplitMix64| -> f64 {
        if rng.below(4) == 0 {
            0.0
        } else if integer {
            rng.below(10) as f64
        } else {
            rng.range(0.0, 5.0)
        }
    };
    let m = rng.below(3 * n as u64 + 1) as usize;
    let mut edges = Vec::new();
    for _ in 0..m {
        let u = rng.below(n as u64) as u32;
        let v = rng.below(n as u64) as u32;
        let e = (u, v, cap(rng), cap(rng));
        edges.push(e);
        if rng.below(5) == 0 {
            // A parallel pair, sometimes reversed.
            edges.push((v, u, cap(rng), cap(rng)));
        }
    }
    let terminals = (0..n).map(|_| (cap(rng), cap(rng))).collect();
    (n, edges, terminals)
}

#[test]
fn max_flow_of_a_small_known_graph() {
    // s->a 3, s->b 2, a->b 1, a->t 2, b->t 3: max flow 5.
    let (f, side) = max_flow(2, &[(0, 1, 1.0, 0.0)], &[(3.0, 2.0), (2.0, 3.0)]).unwrap();
    assert_eq!(f, 5.0);
    assert_eq!(
        cut_capacity(&[(0, 1, 1.0, 0.0)], &[(3.0, 2.0), (2.0, 3.0)], &side),
        5.0
    );
    // No nodes, no flow.
    assert_eq!(max_flow(0, &[], &[]).unwrap(), (0.0, vec![]));
}

#[test]
fn max_flow_equals_brute_force_min_cut_on_random_graphs() {
    let mut rng = SplitMix64::new(2004);
    for trial in 0..3000 {
        let integer = trial % 2 == 0;
        let (n, edges, terminals) = random_graph(&mut rng, integer);
        let (flow, side) = max_flow(n, &edges, &terminals).unwrap();
        let mut best = f64::INFINITY;
        for mask in 0u32..(1 << n) {
            let src: Vec<bool> = (0..n).map(|i| mask >> i & 1 == 1).collect();
            best = best.min(cut_capacity(&edges, &terminals, &src));
        }
        let tol = 1e-9 * best.max(1.0);
        assert!(
            (flow - best).abs() <= tol,
            "trial {trial}: flow {flow} vs brute-force min cut {best}: {edges:?} {terminals:?}"
        );
        let c = cut_capacity(&edges, &terminals, &side);
        assert!(
            (c - flow).abs() <= tol,
            "trial {trial}: cut {c} vs flow {flow}"
        );
        if integer {
            assert_eq!(flow, best, "trial {trial}");
        }
        // Both final search trees are complete: "not in the sink tree" is a
        // minimum cut as well.
        let ge: Vec<cv::GcEdge> = edges
            .iter()
            .map(|&(u, v, c, r)| cv::GcEdge {
                from: u,
                to: v,
                cap: c,
                rev_cap: r,
            })
            .collect();
        let t: Vec<f64> = terminals.iter().flat_map(|&(s, k)| [s, k]).collect();
        let raw = cv::gc_max_flow(n as u32, &ge, &t).unwrap();
        let big: Vec<bool> = raw.side.iter().map(|&s| s != 2).collect();
        let c2 = cut_capacity(&edges, &terminals, &big);
        assert!(
            (c2 - flow).abs() <= tol,
            "trial {trial}: cut {c2} vs flow {flow}"
        );
    }
}

/// Reference max flow by shortest augmenting paths (Edmonds–Karp) on a dense
/// residual matrix, node `n` = source, `n + 1` = sink.
fn edmonds_karp(n: usize, edges: &[Edge], terminals: &[(f64, f64)]) -> f64 {
    let m = n + 2;
    let (s, t) = (n, n + 1);
    let mut r = vec![0.0f64; m * m];
    for &(u, v, c, rc) in edges {
        if u != v {
            r[u as usize * m + v as usize] += c;
            r[v as usize * m + u as usize] += rc;
        }
    }
    for (i, &(a, b)) in terminals.iter().enumerate() {
        r[s * m + i] += a;
        r[i * m + t] += b;
    }
    let mut flow = 0.0;
    loop {
        let mut prev = vec![usize::MAX; m];
        prev[s] = s;
        let mut queue = std::collections::VecDeque::from([s]);
        while let Some(u) = queue.pop_front() {
            for v in 0..m {
                if prev[v] == usize::MAX && r[u * m + v] > 0.0 {
                    prev[v] = u;
                    queue.push_back(v);
                }
            }
        }
        if prev[t] == usize::MAX {
            return flow;
        }
        let mut b = f64::INFINITY;
        let mut v = t;
        while v != s {
            b = b.min(r[prev[v] * m + v]);
            v = prev[v];
        }
        let mut v = t;
        while v != s {
            r[prev[v] * m + v] -= b;
            r[v * m + prev[v]] += b;
            v = prev[v];
        }
        flow += b;
    }
}

#[test]
fn max_flow_matches_edmonds_karp_on_larger_graphs() {
    // Integer capacities, so both algorithms must agree exactly; many orphans.
    let mut rng = SplitMix64::new(1984);
    for trial in 0..60 {
        let n = 20 + rng.below(180) as usize;
        let m = n * (1 + rng.below(6) as usize);
        let cap = |rng: &mut SplitMix64, hi: u64| {
            if rng.below(3) == 0 {
                0.0
            } else {
                rng.below(hi) as f64
            }
        };
        let edges: Vec<Edge> = (0..m)
            .map(|_| {
                let u = rng.below(n as u64) as u32;
                let v = rng.below(n as u64) as u32;
                (u, v, cap(&mut rng, 20), cap(&mut rng, 20))
            })
            .collect();
        let terminals: Vec<(f64, f64)> = (0..n)
            .map(|_| (cap(&mut rng, 40), cap(&mut rng, 40)))
            .collect();
        let (flow, side) = max_flow(n, &edges, &terminals).unwrap();
        assert_eq!(flow, edmonds_karp(n, &edges, &terminals), "trial {trial}");
        assert_eq!(
            cut_capacity(&edges, &terminals, &side),
            flow,
            "trial {trial}"
        );
    }
}

#[test]
fn max_flow_on_a_grid_matches_its_cut() {
    // A 40x30 4-connected grid with segmentation-like capacities.
    let (w, h) = (40usize, 30usize);
    let mut rng = SplitMix64::new(9);
    let mut edges = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let p = (y * w + x) as u32;
            if x + 1 < w {
                let c = rng.range(0.0, 2.0);
                edges.push((p, p + 1, c, c));
            }
            if y + 1 < h {
                let c = rng.range(0.0, 2.0);
                edges.push((p, p + w as u32, c, c));
            }
        }
    }
    let terminals: Vec<(f64, f64)> = (0..w * h)
        .map(|i| {
            let inside = (i % w) as f64 > 10.0 && (i % w) < 30 && i / w > 5 && i / w < 25;
            let s = rng.range(0.0, 3.0) + if inside { 2.0 } else { 0.0 };
            (s, rng.range(0.0, 3.0))
        })
        .collect();
    let (f, side) = max_flow(w * h, &edges, &terminals).unwrap();
    let c = cut_capacity(&edges, &terminals, &side);
    assert!((c - f).abs() < 1e-9 * f, "cut {c} flow {f}");
}

#[test]
fn max_flow_rejects_bad_input() {
    let t = [(1.0, 1.0), (1.0, 1.0)];
    assert!(max_flow(2, &[(0, 1, f64::NAN, 0.0)], &t).is_err());
    assert!(max_flow(2, &[(0, 1, -1.0, 0.0)], &t).is_err());
    assert!(max_flow(2, &[(0, 1, 1.0, f64::INFINITY)], &t).is_err());
    assert!(max_flow(2, &[(0, 2, 1.0, 1.0)], &t).is_err());
    assert!(max_flow(2, &[], &t[..1]).is_err());
    assert!(max_flow(2, &[], &[(1.0, -0.5), (1.0, 1.0)]).is_err());
    // The C++ layer validates on its own too (std::invalid_argument -> Err).
    let e = [cv::GcEdge {
        from: 0,
        to: 1,
        cap: -1.0,
        rev_cap: 0.0,
    }];
    let err = cv::gc_max_flow(2, &e, &[1.0, 1.0, 1.0, 1.0]).unwrap_err();
    assert!(err.to_string().contains("capacit"), "{err}");
    assert!(cv::gc_max_flow(2, &[], &[1.0, f64::NAN, 1.0, 1.0]).is_err());
    assert!(cv::gc_max_flow(2, &[], &[1.0]).is_err());
}

/// A random energy: data in [0, 2), features in [0, 1) with `channels` channels.
struct Problem {
    w: usize,
    h: usize,
    l: usize,
    c: usize,
    data: Vec<f32>,
    feat: Vec<f32>,
}

impl Problem {
    fn random(rng: &mut SplitMix64, w: usize, h: usize, l: usize, c: usize) -> Self {
        let data = (0..w * h * l).map(|_| rng.range_f32(0.0, 2.0)).collect();
        let feat = (0..w * h * l * c)
            .map(|_| rng.range_f32(0.0, 1.0))
            .collect();
        Problem {
            w,
            h,
            l,
            c,
            data,
            feat,
        }
    }
    /// Features one-hot per label: V is the Potts model (2 sqrt 2 per seam).
    fn potts(rng: &mut SplitMix64, w: usize, h: usize, l: usize) -> Self {
        let data = (0..w * h * l).map(|_| rng.range_f32(0.0, 4.0)).collect();
        let mut feat = vec![0.0f32; w * h * l * l];
        for p in 0..w * h {
            for k in 0..l {
                feat[(p * l + k) * l + k] = 1.0;
            }
        }
        Problem {
            w,
            h,
            l,
            c: l,
            data,
            feat,
        }
    }
    fn energy(&self, lambda: f32, wrap_x: bool) -> GridEnergy<'_> {
        GridEnergy {
            width: self.w,
            height: self.h,
            labels: self.l,
            data: &self.data,
            features: &self.feat,
            channels: self.c,
            lambda,
            wrap_x,
        }
    }
}

/// Seams that cost something only in a few small blobs (one across the
/// `x = 0 / width - 1` seam, one at a corner, two touching): solving the blobs
/// as separate problems gives the same labels and energy as the whole grid.
#[test]
fn pieces_give_the_same_result_as_the_whole_grid() {
    let mut rng = SplitMix64::new(7);
    for trial in 0..24 {
        let (w, h, l, c) = (23, 11, 3, 4);
        let mut pr = Problem::random(&mut rng, w, h, l, c);
        let centres = [(0usize, 5usize), (w - 1, 0), (10, 4), (12, 5), (17, 9)];
        for p in 0..w * h {
            let (x, y) = (p % w, p / w);
            let near = centres.iter().take(2 + trial % 4).any(|&(cx, cy)| {
                let dx = (x as i64 - cx as i64).rem_euclid(w as i64);
                let dx = dx.min(w as i64 - dx);
                dx.abs() <= 1 && (y as i64 - cy as i64).abs() <= 1
            });
            if !near {
                // All labels share the pixel's features: no seam cost here.
                let first: Vec<f32> = pr.feat[p * l * c..p * l * c + c].to_vec();
                for k in 1..l {
                    pr.feat[(p * l + k) * c..(p * l + k + 1) * c].copy_from_slice(&first);
                }
            }
        }
        for &(wrap, op) in &[
            (true, Optimizer::Expansion),
            (false, Optimizer::Expansion),
            (true, Optimizer::Swap),
        ] {
            let e = pr.energy(0.8, wrap);
            let init = argmin_labels(&e);
            let parts = SmoothParts::find(&e);
            assert!(parts.active_pixels > 0 && 2 * parts.active_pixels <= w * h);
            let a = optimize_parts(&e, op, 6, &init, &parts).unwrap();
            let b = optimize_whole(&e, op, 6, &init).unwrap();
            assert_eq!(a.labels, b.labels, "trial {trial} wrap {wrap} {op:?}");
            assert!(close(a.energy, b.energy), "{} vs {}", a.energy, b.energy);
            assert!(close(*a.history.last().unwrap(), a.energy));
            assert!(a.history.windows(2).all(|x| x[1] <= x[0] + 1e-9));
        }
    }
}

fn total(e: &GridEnergy, labels: &[u8]) -> f64 {
    let (d, s) = energy(e, labels).unwrap();
    d + s
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0)
}

/// Every labelling of a tiny grid, as base-`l` digits.
fn all_labellings(n: usize, l: usize) -> impl Iterator<Item = Vec<u8>> {
    (0..l.pow(n as u32)).map(move |mut k| {
        (0..n)
            .map(|_| {
                let d = (k % l) as u8;
                k /= l;
                d
            })
            .collect()
    })
}

#[test]
fn expansion_and_swap_never_increase_the_energy() {
    let mut rng = SplitMix64::new(77);
    for trial in 0..40 {
        let w = 3 + rng.below(20) as usize;
        let h = 1 + rng.below(12) as usize;
        let l = 2 + rng.below(5) as usize;
        let c = rng.below(4) as usize;
        let p = Problem::random(&mut rng, w, h, l, c);
        let lambda = rng.range_f32(0.0, 3.0);
        let e = p.energy(lambda, trial % 3 == 0);
        let init: Vec<u8> = (0..w * h).map(|_| rng.below(l as u64) as u8).collect();
        let e0 = total(&e, &init);
        for opt in [Optimizer::Expansion, Optimizer::Swap] {
            for start in [Some(&init[..]), None] {
                let r = optimize(&e, opt, 50, start).unwrap();
                let before = start.map_or_else(|| total(&e, &argmin_labels(&e)), |_| e0);
                assert!(!r.history.is_empty());
                assert!(r.history[0] <= before, "trial {trial} {opt:?}");
                assert!(
                    r.history.windows(2).all(|w| w[1] <= w[0]),
                    "{:?}",
                    r.history
                );
                assert_eq!(r.history.len(), r.cycles);
                assert_eq!(*r.history.last().unwrap(), r.energy);
                let (d, s) = energy(&e, &r.labels).unwrap();
                assert!(close(d, r.data_energy), "{d} vs {}", r.data_energy);
                assert!(close(s, r.smooth_energy), "{s} vs {}", r.smooth_energy);
                assert!(close(d + s, r.energy));
                assert!(r.energy <= before);
                assert!(r.cycles < 50, "trial {trial} {opt:?} did not converge");
            }
        }
    }
}

#[test]
fn swap_is_exact_for_two_labels() {
    let mut rng = SplitMix64::new(5);
    for trial in 0..30 {
        let (w, h) = (4, 3);
        let p = Problem::random(&mut rng, w, h, 2, 3);
        let e = p.energy(rng.range_f32(0.1, 2.0), trial % 2 == 1);
        let best = all_labellings(w * h, 2)
            .map(|f| total(&e, &f))
            .fold(f64::INFINITY, f64::min);
        let r = optimize(&e, Optimizer::Swap, 10, None).unwrap();
        assert!(
            close(r.energy, best),
            "trial {trial}: {} vs {best}",
            r.energy
        );
    }
}

#[test]
fn expansion_is_within_factor_two_of_the_optimum_for_potts() {
    let mut rng = SplitMix64::new(2001);
    for trial in 0..25 {
        let p = Problem::potts(&mut rng, 3, 3, 3);
        let e = p.energy(rng.range_f32(0.2, 1.5), trial % 2 == 0);
        let best = all_labellings(9, 3)
            .map(|f| total(&e, &f))
            .fold(f64::INFINITY, f64::min);
        for opt in [Optimizer::Expansion, Optimizer::Swap] {
            let r = optimize(&e, opt, 20, None).unwrap();
            assert!(r.energy >= best - 1e-9);
            if opt == Optimizer::Expansion {
                assert!(r.energy <= 2.0 * best + 1e-9, "{} vs {best}", r.energy);
            }
        }
    }
}

#[test]
fn converged_labellings_admit_no_improving_move() {
    // Brute force over every expansion (swap) move from the returned labelling.
    let mut rng = SplitMix64::new(31);
    for trial in 0..15 {
        let (w, h, l) = (3, 3, 3);
        let p = Problem::random(&mut rng, w, h, l, 3);
        let e = p.energy(rng.range_f32(0.2, 2.0), trial % 2 == 0);
        for opt in [Optimizer::Expansion, Optimizer::Swap] {
            let r = optimize(&e, opt, 100, None).unwrap();
            let tol = 1e-9 * r.energy.max(1.0);
            for mask in 0u32..(1 << (w * h)) {
                for a in 0..l as u8 {
                    for b in 0..l as u8 {
                        let mut f = r.labels.clone();
                        let mut legal = true;
                        for (i, fi) in f.iter_mut().enumerate() {
                            if mask >> i & 1 == 0 {
                                continue;
                            }
                            match opt {
                                Optimizer::Expansion => *fi = a,
                                Optimizer::Swap if *fi == a => *fi = b,
                                Optimizer::Swap if *fi == b => *fi = a,
                                Optimizer::Swap => legal = false,
                            }
                        }
                        if legal {
                            let t = total(&e, &f);
                            assert!(t >= r.energy - tol, "{opt:?}: {t} < {}", r.energy);
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn converged_labellings_beat_every_single_pixel_change() {
    // Single-pixel relabellings are both expansion and swap moves.
    let mut rng = SplitMix64::new(8);
    for trial in 0..4 {
        let (w, h, l) = (48usize, 24usize, 4usize);
        let p = Problem::random(&mut rng, w, h, l, 3);
        let e = p.energy(rng.range_f32(0.5, 3.0), trial % 2 == 0);
        for opt in [Optimizer::Expansion, Optimizer::Swap] {
            let r = optimize(&e, opt, 100, None).unwrap();
            assert!(r.cycles < 100);
            let tol = 1e-9 * r.energy.max(1.0);
            let mut f = r.labels.clone();
            for px in 0..w * h {
                for k in 0..l as u8 {
                    f[px] = k;
                    assert!(total(&e, &f) >= r.energy - tol, "{opt:?} pixel {px}");
                }
                f[px] = r.labels[px];
            }
        }
    }
}

#[test]
fn strong_smoothness_gives_the_straight_boundary() {
    // Label 0 left of x = 16, label 1 right of it, plus isolated wrong pixels.
    let (w, h) = (32usize, 16usize);
    let mut data = vec![0.0f32; w * h * 2];
    for y in 0..h {
        for x in 0..w {
            let right = x >= 16;
            let noise = (x % 7 == 3 && y % 5 == 2) && !(13..19).contains(&x);
            let prefers_one = right != noise;
            let p = y * w + x;
            data[2 * p] = if prefers_one { 1.0 } else { 0.0 };
            data[2 * p + 1] = if prefers_one { 0.0 } else { 1.0 };
        }
    }
    // Feature 0 for label 0, 1 for label 1: a seam costs 2 per neighbour pair.
    let feat: Vec<f32> = (0..w * h * 2).map(|i| (i % 2) as f32).collect();
    let e = two_labels(w, h, &data, &feat);
    let truth: Vec<u8> = (0..w * h).map(|p| (p % w >= 16) as u8).collect();
    assert_ne!(argmin_labels(&e), truth, "the ablation keeps the noise");
    for opt in [Optimizer::Expansion, Optimizer::Swap] {
        let r = optimize(&e, opt, 20, None).unwrap();
        assert_eq!(r.labels, truth, "{opt:?}");
        assert!(close(r.energy, total(&e, &truth)));
        assert!(close(r.smooth_energy, 2.0 * h as f64));
    }
}

#[test]
fn infeasible_labels_are_not_chosen_when_a_feasible_one_exists() {
    let mut rng = SplitMix64::new(404);
    for trial in 0..10 {
        let (w, h, l) = (24usize, 16usize, 4usize);
        let mut p = Problem::random(&mut rng, w, h, l, 3);
        for px in 0..w * h {
            let keep = rng.below(l as u64) as usize;
            for k in 0..l {
                if k != keep && rng.below(2) == 0 {
                    p.data[px * l + k] = INFEASIBLE;
                }
            }
        }
        // One pixel where nothing is feasible still gets a label.
        p.data[..l].fill(INFEASIBLE);
        let e = p.energy(2.0, trial % 2 == 0);
        for opt in [Optimizer::Expansion, Optimizer::Swap] {
            let r = optimize(&e, opt, 50, None).unwrap();
            for px in 1..w * h {
                let d = p.data[px * l + r.labels[px] as usize];
                assert!(
                    d < INFEASIBLE,
                    "{opt:?}: pixel {px} took an infeasible label"
                );
            }
        }
    }
}

#[test]
fn wrap_x_joins_the_seam() {
    let (w, h) = (16usize, 8usize);
    // Label 0 inside, label 1 strongly at the right edge, weakly at the left edge.
    let mut data = vec![0.0f32; w * h * 2];
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let (d0, d1) = match x {
                0 | 1 => (0.5, 0.0),
                14 | 15 => (10.0, 0.0),
                _ => (0.0, 10.0),
            };
            data[2 * p] = d0;
            data[2 * p + 1] = d1;
        }
    }
    let feat: Vec<f32> = (0..w * h * 2).map(|i| (i % 2) as f32).collect();
    let mk = |wrap_x| GridEnergy {
        width: w,
        height: h,
        labels: 2,
        data: &data,
        features: &feat,
        channels: 1,
        lambda: 1.0,
        wrap_x,
    };
    // The energy counts the wrap seam: 2 per row.
    let f: Vec<u8> = (0..w * h).map(|p| (p % w >= 14) as u8).collect();
    let (d0, s0) = energy(&mk(false), &f).unwrap();
    let (d1, s1) = energy(&mk(true), &f).unwrap();
    assert_eq!(d0, d1);
    assert!(close(s1 - s0, 2.0 * h as f64), "{s0} {s1}");
    // Without wrap the weak left strip is not worth a seam; with wrap it extends
    // the right strip across the border at no extra seam cost.
    let zeros = vec![0u8; w * h];
    for (opt, init) in [
        (Optimizer::Expansion, None),
        (Optimizer::Expansion, Some(&zeros[..])),
        (Optimizer::Swap, None),
        (Optimizer::Swap, Some(&zeros[..])),
    ] {
        let open = optimize(&mk(false), opt, 20, init).unwrap();
        let wrapped = optimize(&mk(true), opt, 20, init).unwrap();
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                assert_eq!(open.labels[p], (x >= 14) as u8, "{opt:?} open ({x}, {y})");
                let want = !(2..14).contains(&x) as u8;
                assert_eq!(wrapped.labels[p], want, "{opt:?} wrapped ({x}, {y})");
            }
        }
    }
}

#[test]
fn non_finite_features_cost_the_cap() {
    let (w, h) = (4usize, 1usize);
    let data = vec![0.0f32; w * h * 2];
    let mut feat = vec![0.0f32; w * h * 2];
    feat[2] = f32::NAN; // pixel 1, label 0
    feat[5] = f32::INFINITY; // pixel 2, label 1
    let e = two_labels(w, h, &data, &feat);
    // Seam between pixels 1 and 2: cap + cap.
    let (_, s) = energy(&e, &[0, 0, 1, 1]).unwrap();
    assert_eq!(s, 2.0 * SEAM_CAP);
    // Seam between pixels 0 and 1: 0 + cap.
    let (_, s) = energy(&e, &[0, 1, 1, 1]).unwrap();
    assert_eq!(s, SEAM_CAP);
    for opt in [Optimizer::Expansion, Optimizer::Swap] {
        let r = optimize(&e, opt, 10, Some(&[0, 0, 1, 1])).unwrap();
        assert!(r.energy.is_finite());
        assert_eq!(r.energy, 0.0, "{opt:?}: a single label needs no seam");
    }
}

#[test]
fn zero_cycles_and_single_labels_are_fine() {
    let mut rng = SplitMix64::new(1);
    let p = Problem::random(&mut rng, 5, 4, 3, 2);
    let e = p.energy(1.0, false);
    let init = vec![2u8; 20];
    let r = optimize(&e, Optimizer::Expansion, 0, Some(&init)).unwrap();
    assert_eq!(r.labels, init);
    assert_eq!((r.cycles, r.history.len()), (0, 0));
    assert!(close(r.energy, total(&e, &init)));
    let one = Problem::random(&mut rng, 5, 4, 1, 2);
    let r = optimize(&one.energy(1.0, true), Optimizer::Swap, 5, None).unwrap();
    assert_eq!(r.labels, vec![0u8; 20]);
}

#[test]
fn bad_input_is_an_error() {
    let mut rng = SplitMix64::new(3);
    let mut p = Problem::random(&mut rng, 5, 4, 3, 2);
    let good = p.energy(1.0, false);
    assert!(optimize(&good, Optimizer::Expansion, 5, None).is_ok());

    // NaN data cost: the message names the pixel.
    let at = (5 + 2) * 3 + 1; // pixel (2, 1) of a 5-wide grid, label 1
    p.data[at] = f32::NAN;
    let err = optimize(&p.energy(1.0, false), Optimizer::Expansion, 5, None).unwrap_err();
    assert!(err.to_string().contains("pixel (2, 1)"), "{err}");
    assert!(energy(&p.energy(1.0, false), &[0u8; 20]).is_err());
    p.data[at] = -1.0;
    assert!(optimize(&p.energy(1.0, false), Optimizer::Swap, 5, None).is_err());
    p.data[at] = f32::INFINITY;
    assert!(optimize(&p.energy(1.0, false), Optimizer::Swap, 5, None).is_err());
    p.data[at] = 0.5;

    let e = p.energy(1.0, false);
    let sized = |w, h, l, c| GridEnergy {
        width: w,
        height: h,
        labels: l,
        channels: c,
        ..e
    };
    assert!(optimize(&sized(6, 4, 3, 2), Optimizer::Expansion, 5, None).is_err());
    assert!(optimize(&sized(5, 4, 3, 3), Optimizer::Expansion, 5, None).is_err());
    assert!(optimize(&sized(0, 4, 3, 2), Optimizer::Expansion, 5, None).is_err());
    assert!(optimize(&sized(5, 4, 0, 2), Optimizer::Expansion, 5, None).is_err());
    let many = vec![0.0f32; 256];
    let e256 = GridEnergy {
        width: 1,
        height: 1,
        labels: 256,
        data: &many,
        features: &[],
        channels: 0,
        lambda: 1.0,
        wrap_x: false,
    };
    assert!(optimize(&e256, Optimizer::Expansion, 5, None).is_err());
    for lambda in [f32::NAN, -1.0, f32::INFINITY] {
        let bad = GridEnergy { lambda, ..e };
        assert!(optimize(&bad, Optimizer::Expansion, 5, None).is_err());
    }
    assert!(optimize(&e, Optimizer::Expansion, 5, Some(&[0u8; 19])).is_err());
    let mut init = vec![0u8; 20];
    init[7] = 3;
    let err = optimize(&e, Optimizer::Swap, 5, Some(&init)).unwrap_err();
    assert!(err.to_string().contains("pixel (2, 1)"), "{err}");
    assert!(energy(&e, &init).is_err());
    assert!(energy(&e, &[0u8; 3]).is_err());

    // The C++ layer validates on its own too.
    let params = cv::GcGridParams {
        width: 5,
        height: 4,
        labels: 3,
        channels: 2,
        lambda: 1.0,
        seam_cap: SEAM_CAP,
        wrap_x: false,
        swap: false,
        max_cycles: 5,
        check: true,
    };
    let zeros = [0u8; 20];
    assert!(cv::gc_optimize_grid(&params, &p.data, &p.feat, &zeros).is_ok());
    let mut nan = p.data.clone();
    nan[at] = f32::NAN;
    let err = cv::gc_optimize_grid(&params, &nan, &p.feat, &zeros).unwrap_err();
    assert!(err.to_string().contains("pixel (2, 1)"), "{err}");
    assert!(cv::gc_optimize_grid(&params, &p.data[1..], &p.feat, &zeros).is_err());
    assert!(cv::gc_optimize_grid(&params, &p.data, &p.feat[1..], &zeros).is_err());
    assert!(cv::gc_optimize_grid(&params, &p.data, &p.feat, &zeros[1..]).is_err());
    assert!(cv::gc_optimize_grid(&params, &p.data, &p.feat, &[9u8; 20]).is_err());
    let bad = cv::GcGridParams {
        lambda: f64::NAN,
        ..params
    };
    assert!(cv::gc_optimize_grid(&bad, &p.data, &p.feat, &zeros).is_err());
}
