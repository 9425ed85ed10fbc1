//! Graph cuts for the flow method: per-pixel fusion of several candidate probes
//! (two warped HDR probes and the SDR frame, after Gupta et al. 2009) by minimising
//!
//! ```text
//! E(f) = sum_p D_p(f_p) + lambda * sum_{p~q} V_pq(f_p, f_q)
//! V_pq(a, b) = |F_a(p) - F_b(p)| + |F_a(q) - F_b(q)|   (a != b; 0 for a == b)
//! ```
//!
//! over a 4-connected grid, optionally wrapped horizontally for equirectangular
//! panoramas. `V` is the seam cost of Kwatra et al. 2003 / Gupta et al. 2009: cutting
//! between labels `a` and `b` is cheap where their features (e.g. tone-mapped RGB)
//! agree. It is a metric in the labels, so alpha-expansion moves are submodular.
//!
//! The work happens in C++ (`cpp/maxflow.cc`): the Boykov–Kolmogorov max-flow
//! algorithm (Boykov & Kolmogorov 2004, "An experimental comparison of
//! min-cut/max-flow algorithms for energy minimization in vision"), driven by
//! alpha-expansion and alpha-beta swap moves (Boykov, Veksler & Zabih 2001, "Fast
//! approximate energy minimization via graph cuts"), each move's pairwise terms
//! built with the construction of Kolmogorov & Zabih 2004 ("What energy functions
//! can be minimized via graph cuts?"). All sums are in `f64`. This module validates
//! inputs, so bad data is an [`Error::Invalid`], never a panic or NaN capacity.

use crate::cv;
use crate::error::{Error, Result};

/// Data cost marking a label as unusable at a pixel (e.g. no warped probe there).
///
/// Infeasibility is just a large finite cost, so capacities stay finite. A converged
/// optimisation never keeps an infeasible label where a feasible one exists as long
/// as `INFEASIBLE` exceeds that pixel's feasible data cost plus
/// `8 * lambda * SEAM_CAP` (the most its four seams can save), e.g. any
/// `lambda < 100` with data costs below `2e5`.
pub const INFEASIBLE: f32 = 1e6;

/// Cap of one feature distance `|F_a(p) - F_b(p)|`. Non-finite features count as
/// infinitely different and are charged this cap, so no NaN or infinity ever reaches
/// the graph; capping keeps `V` a metric.
pub const SEAM_CAP: f64 = 1e3;

/// Largest grid accepted (pixels), keeping node and arc indices in `i32`.
const MAX_PIXELS: usize = 1 << 28;

/// A labelling problem on a `width x height` grid with `labels` candidates per pixel.
#[derive(Clone, Copy, Debug)]
pub struct GridEnergy<'a> {
    /// Grid width (pixels per row).
    pub width: usize,
    /// Grid height (rows).
    pub height: usize,
    /// Number of labels, `1..=255`.
    pub labels: usize,
    /// Data costs `D_p(l)` at `(y * width + x) * labels + l`: finite, `>= 0`;
    /// [`INFEASIBLE`] (or more) for unusable labels.
    pub data: &'a [f32],
    /// Features `F_l(p)` at `((y * width + x) * labels + l) * channels + c`;
    /// non-finite values are allowed (see [`SEAM_CAP`]).
    pub features: &'a [f32],
    /// Feature channels per pixel and label (may be 0: no smoothness).
    pub channels: usize,
    /// Weight of the seam term, finite and `>= 0`.
    pub lambda: f32,
    /// Treat columns `0` and `width - 1` as neighbours (equirectangular panoramas;
    /// only when `width >= 3`, so no pair is joined twice).
    pub wrap_x: bool,
}

/// Move-making algorithm of Boykov, Veksler & Zabih 2001.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Optimizer {
    /// Alpha-expansion: each move lets any pixel switch to one label `alpha`; within
    /// a factor `2 max V / min V` of the optimum for metric `V` (default).
    Expansion,
    /// Alpha-beta swap: each move relabels the pixels of two labels among
    /// themselves; needs only a semimetric, exact for two labels.
    Swap,
}

/// Outcome of [`optimize`].
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CutResult {
    /// Label per pixel, row-major.
    pub labels: Vec<u8>,
    /// Total energy `data_energy + smooth_energy`.
    pub energy: f64,
    /// Sum of the chosen data costs.
    pub data_energy: f64,
    /// `lambda` times the summed seam costs.
    pub smooth_energy: f64,
    /// Cycles run (one cycle = one move per label, or per label pair for swap).
    pub cycles: usize,
    /// Total energy after each cycle; non-increasing.
    pub history: Vec<f64>,
}

impl GridEnergy<'_> {
    fn pixels(&self) -> usize {
        self.width * self.height
    }

    /// Checks sizes, label count, `lambda` and every data cost.
    fn validate(&self) -> Result<()> {
        if self.width == 0 || self.height == 0 {
            return Err(Error::Invalid(format!(
                "graph cut: empty grid {}x{}",
                self.width, self.height
            )));
        }
        let n = self
            .width
            .checked_mul(self.height)
            .filter(|&n| n <= MAX_PIXELS)
            .ok_or_else(|| {
                Error::limit(
                    None,
                    format!("graph cut: grid of {}x{} pixels", self.width, self.height),
                    format!("{MAX_PIXELS} pixels"),
                )
            })?;
        if !(1..=255).contains(&self.labels) {
            return Err(Error::Invalid(format!(
                "graph cut: need 1..=255 labels, got {}",
                self.labels
            )));
        }
        if self.data.len() != n * self.labels {
            return Err(Error::Invalid(format!(
                "graph cut: {} data costs for a {}x{} grid with {} labels (expected {})",
                self.data.len(),
                self.width,
                self.height,
                self.labels,
                n * self.labels
            )));
        }
        let nf = n
            .checked_mul(self.labels)
            .and_then(|v| v.checked_mul(self.channels));
        if nf != Some(self.features.len()) {
            return Err(Error::Invalid(format!(
                "graph cut: {} feature values for a {}x{} grid with {} labels and {} channels",
                self.features.len(),
                self.width,
                self.height,
                self.labels,
                self.channels
            )));
        }
        if self.channels > u32::MAX as usize {
            return Err(Error::Invalid("graph cut: too many channels".into()));
        }
        if !(self.lambda.is_finite() && self.lambda >= 0.0) {
            return Err(Error::Invalid(format!(
                "graph cut: lambda {} must be finite and >= 0",
                self.lambda
            )));
        }
        if let Some(i) = self.data.iter().position(|d| !(d.is_finite() && *d >= 0.0)) {
            let p = i / self.labels;
            return Err(Error::Invalid(format!(
                "graph cut: data cost {} of label {} at pixel ({}, {}) must be finite and >= 0 \
                 (use INFEASIBLE = {INFEASIBLE:e} for unusable labels)",
                self.data[i],
                i % self.labels,
                p % self.width,
                p / self.width
            )));
        }
        Ok(())
    }

    fn check_labels(&self, labels: &[u8], what: &str) -> Result<()> {
        if labels.len() != self.pixels() {
            return Err(Error::Invalid(format!(
                "graph cut: {what} has {} labels for {} pixels",
                labels.len(),
                self.pixels()
            )));
        }
        if let Some(p) = labels.iter().position(|&l| l as usize >= self.labels) {
            return Err(Error::Invalid(format!(
                "graph cut: {what} has label {} at pixel ({}, {}), but only {} labels exist",
                labels[p],
                p % self.width,
                p / self.width,
                self.labels
            )));
        }
        Ok(())
    }

    /// `|F_a(p) - F_b(p)|` exactly as the C++ side computes it.
    fn dist(&self, p: usize, a: usize, b: usize) -> f64 {
        if a == b {
            return 0.0;
        }
        let c = self.channels;
        let fa = &self.features[(p * self.labels + a) * c..][..c];
        let fb = &self.features[(p * self.labels + b) * c..][..c];
        let mut s = 0.0f64;
        for (&u, &v) in fa.iter().zip(fb) {
            let (u, v) = (u as f64, v as f64);
            if !u.is_finite() || !v.is_finite() {
                return SEAM_CAP;
            }
            s += (u - v) * (u - v);
        }
        let r = s.sqrt();
        if r < SEAM_CAP {
            r
        } else {
            SEAM_CAP
        }
    }

    /// The seam cost `V_pq(a, b)`.
    fn seam(&self, p: usize, q: usize, a: usize, b: usize) -> f64 {
        if a == b {
            0.0
        } else {
            self.dist(p, a, b) + self.dist(q, a, b)
        }
    }
}

/// Minimises the grid energy `e` with `opt`, starting from `init` (default: the
/// per-pixel argmin of the data costs), for at most `max_cycles` cycles or until a
/// cycle no longer lowers the energy. Each move is accepted only if it lowers the
/// exactly recomputed energy, so the energy never increases.
pub fn optimize(
    e: &GridEnergy,
    opt: Optimizer,
    max_cycles: usize,
    init: Option<&[u8]>,
) -> Result<CutResult> {
    e.validate()?;
    let start;
    let init = match init {
        Some(l) => {
            e.check_labels(l, "initial labelling")?;
            l
        }
        None => {
            start = argmin_labels(e);
            &start[..]
        }
    };
    if max_cycles == 0 {
        let (d, sm) = energy(e, init)?;
        return Ok(CutResult {
            labels: init.to_vec(),
            energy: d + sm,
            data_energy: d,
            smooth_energy: sm,
            cycles: 0,
            history: Vec::new(),
        });
    }
    let parts = SmoothParts::find(e);
    // When most pixels take part in some seam, one cut over the whole grid is as
    // cheap as the pieces.
    let r = if 2 * parts.active_pixels > e.pixels() {
        optimize_whole(e, opt, max_cycles, init)?
    } else {
        optimize_parts(e, opt, max_cycles, init, &parts)?
    };
    debug_assert!(
        r.history
            .windows(2)
            .all(|w| w[1] <= w[0] + 1e-9 * w[0].abs().max(1.0)),
        "graph cut energy increased: {:?}",
        r.history
    );
    Ok(r)
}

/// One cut problem over the whole grid.
fn optimize_whole(
    e: &GridEnergy,
    opt: Optimizer,
    max_cycles: usize,
    init: &[u8],
) -> Result<CutResult> {
    let params = cv::GcGridParams {
        width: e.width as u32,
        height: e.height as u32,
        labels: e.labels as u32,
        channels: e.channels as u32,
        lambda: e.lambda as f64,
        seam_cap: SEAM_CAP,
        wrap_x: e.wrap_x,
        swap: opt == Optimizer::Swap,
        max_cycles: max_cycles.min(u32::MAX as usize) as u32,
        check: cfg!(debug_assertions),
    };
    let r = cv::gc_optimize_grid(&params, e.data, e.features, init)?;
    Ok(CutResult {
        labels: r.labels,
        energy: r.data_energy + r.smooth_energy,
        data_energy: r.data_energy,
        smooth_energy: r.smooth_energy,
        cycles: r.cycles as usize,
        history: r.history,
    })
}

/// The pixels a seam can cost anything at, grouped into independent pieces.
///
/// An edge `p~q` costs nothing for every label pair when the features of all labels
/// agree at both `p` and `q`. Without such edges the energy splits: a pixel with no
/// costly edge is decided by its data cost alone, and each connected group of pixels
/// joined by costly edges is its own, much smaller, cut problem. In the flow method
/// the seam cost is typically non-zero only in and around the frame's clipped
/// regions, a few percent of the panorama, so solving only there saves most of the
/// cut's time and gives the same moves as the whole grid.
struct SmoothParts {
    /// Piece index per pixel, `u32::MAX` for pixels without a costly edge.
    piece: Vec<u32>,
    /// Per piece: bounding box `(x0, x1, y0, y1)` inclusive, and whether it needs the
    /// whole width (it crosses the `x = 0 / width - 1` seam).
    boxes: Vec<(usize, usize, usize, usize, bool)>,
    /// Pixels in some piece.
    active_pixels: usize,
}

impl SmoothParts {
    fn find(e: &GridEnergy) -> SmoothParts {
        let (w, h) = (e.width, e.height);
        let n = w * h;
        let l = e.labels;
        // A pixel "varies" when some label pair has a non-zero feature distance
        // there: when some label's features differ from label 0's (non-finite
        // features always cost the cap).
        let c = e.channels;
        let varies: Vec<bool> = if e.lambda > 0.0 && c > 0 && l > 1 {
            e.features
                .chunks_exact(l * c)
                .map(|f| {
                    let first = &f[..c];
                    f.iter().any(|v| !v.is_finite()) || f[c..].chunks_exact(c).any(|g| g != first)
                })
                .collect()
        } else {
            vec![false; n]
        };
        let wrap = e.wrap_x && w >= 3;
        let mut piece = vec![u32::MAX; n];
        let mut boxes = Vec::new();
        let mut active_pixels = 0;
        let mut stack = Vec::new();
        let neighbours = |p: usize, out: &mut Vec<(usize, bool)>| {
            let (x, y) = (p % w, p / w);
            if x + 1 < w {
                out.push((p + 1, false));
            } else if wrap {
                out.push((p + 1 - w, true));
            }
            if x > 0 {
                out.push((p - 1, false));
            } else if wrap {
                out.push((p + w - 1, true));
            }
            if y + 1 < h {
                out.push((p + w, false));
            }
            if y > 0 {
                out.push((p - w, false));
            }
        };
        let mut nb = Vec::with_capacity(4);
        for start in 0..n {
            if piece[start] != u32::MAX {
                continue;
            }
            nb.clear();
            neighbours(start, &mut nb);
            if !nb.iter().any(|&(q, _)| varies[start] || varies[q]) {
                continue;
            }
            let id = boxes.len() as u32;
            let mut bx = (start % w, start % w, start / w, start / w, false);
            piece[start] = id;
            stack.push(start);
            while let Some(p) = stack.pop() {
                active_pixels += 1;
                let (x, y) = (p % w, p / w);
                bx.0 = bx.0.min(x);
                bx.1 = bx.1.max(x);
                bx.2 = bx.2.min(y);
                bx.3 = bx.3.max(y);
                nb.clear();
                neighbours(p, &mut nb);
                for &(q, across) in &nb {
                    if varies[p] || varies[q] {
                        bx.4 |= across;
                        if piece[q] == u32::MAX {
                            piece[q] = id;
                            stack.push(q);
                        }
                    }
                }
            }
            boxes.push(bx);
        }
        SmoothParts {
            piece,
            boxes,
            active_pixels,
        }
    }
}

/// Solves each piece of `parts` as its own grid problem (its bounding box, with the
/// pixels of other pieces made indifferent and seam-free) and decides every other
/// pixel by its data cost, moving it as expansion or swap moves would: a pixel keeps
/// its label if no label is strictly cheaper, else takes the first cheapest.
fn optimize_parts(
    e: &GridEnergy,
    opt: Optimizer,
    max_cycles: usize,
    init: &[u8],
    parts: &SmoothParts,
) -> Result<CutResult> {
    let (w, l, c) = (e.width, e.labels, e.channels);
    let mut labels = init.to_vec();
    for (p, lab) in labels.iter_mut().enumerate() {
        if parts.piece[p] != u32::MAX {
            continue;
        }
        let d = &e.data[p * l..(p + 1) * l];
        let mut best = *lab as usize;
        for (k, &v) in d.iter().enumerate() {
            if v < d[best] {
                best = k;
            }
        }
        *lab = best as u8;
    }
    let mut histories = Vec::with_capacity(parts.boxes.len());
    let mut cycles = 1;
    for (id, &(x0, x1, y0, y1, across)) in parts.boxes.iter().enumerate() {
        let (x0, x1) = if across { (0, w - 1) } else { (x0, x1) };
        let (bw, bh) = (x1 - x0 + 1, y1 - y0 + 1);
        let mut data = vec![0.0f32; bw * bh * l];
        let mut feat = vec![0.0f32; bw * bh * l * c];
        let mut sub_init = vec![0u8; bw * bh];
        for yy in 0..bh {
            for xx in 0..bw {
                let p = (y0 + yy) * w + x0 + xx;
                if parts.piece[p] != id as u32 {
                    continue;
                }
                let s = yy * bw + xx;
                data[s * l..(s + 1) * l].copy_from_slice(&e.data[p * l..(p + 1) * l]);
                feat[s * l * c..(s + 1) * l * c]
                    .copy_from_slice(&e.features[p * l * c..(p + 1) * l * c]);
                sub_init[s] = init[p];
            }
        }
        let sub = GridEnergy {
            width: bw,
            height: bh,
            labels: l,
            data: &data,
            features: &feat,
            channels: c,
            lambda: e.lambda,
            wrap_x: e.wrap_x && bw == w,
        };
        let r = optimize_whole(&sub, opt, max_cycles, &sub_init)?;
        for yy in 0..bh {
            for xx in 0..bw {
                let p = (y0 + yy) * w + x0 + xx;
                if parts.piece[p] == id as u32 {
                    labels[p] = r.labels[yy * bw + xx];
                }
            }
        }
        cycles = cycles.max(r.cycles);
        histories.push(r.history);
    }
    // Energy after each cycle: the pieces' own energies (a piece that converged
    // early keeps its last), plus the data cost of the pixels decided alone.
    let alone: f64 = (0..labels.len())
        .filter(|&p| parts.piece[p] == u32::MAX)
        .map(|p| e.data[p * l + labels[p] as usize] as f64)
        .sum();
    let history = (0..cycles)
        .map(|k| {
            alone
                + histories
                    .iter()
                    .map(|h| h.get(k).or(h.last()).copied().unwrap_or(0.0))
                    .sum::<f64>()
        })
        .collect();
    let (d, sm) = energy(e, &labels)?;
    Ok(CutResult {
        labels,
        energy: d + sm,
        data_energy: d,
        smooth_energy: sm,
        cycles,
        history,
    })
}

/// The energy of `labels` as `(data, smooth)`, with `smooth` already multiplied by
/// `lambda`. Computed here in Rust, independently of the C++ optimiser, so tests and
/// callers can cross-check it.
pub fn energy(e: &GridEnergy, labels: &[u8]) -> Result<(f64, f64)> {
    e.validate()?;
    e.check_labels(labels, "labelling")?;
    let (w, h) = (e.width, e.height);
    let data: f64 = labels
        .iter()
        .enumerate()
        .map(|(p, &l)| e.data[p * e.labels + l as usize] as f64)
        .sum();
    let wrap = e.wrap_x && w >= 3;
    let mut s = 0.0f64;
    for y in 0..h {
        let row = y * w;
        for x in 0..w {
            let p = row + x;
            let lp = labels[p] as usize;
            if x + 1 < w {
                s += e.seam(p, p + 1, lp, labels[p + 1] as usize);
            } else if wrap {
                s += e.seam(p, row, lp, labels[row] as usize);
            }
            if y + 1 < h {
                s += e.seam(p, p + w, lp, labels[p + w] as usize);
            }
        }
    }
    Ok((data, e.lambda as f64 * s))
}

/// The cheapest label per pixel ignoring smoothness (the no-seam-cost ablation and
/// the default start of [`optimize`]). Ties and NaN costs resolve to the lowest
/// label; pixels beyond `e.data` get label 0.
pub fn argmin_labels(e: &GridEnergy) -> Vec<u8> {
    let l = e.labels.max(1);
    let mut out = vec![0u8; e.width * e.height];
    for (p, costs) in e.data.chunks_exact(l).take(out.len()).enumerate() {
        out[p] = cheapest_label(costs) as u8;
    }
    out
}

/// The first of the (at most 256) labels with the lowest data cost in `costs`
/// (0 when none is below infinity).
pub(crate) fn cheapest_label(costs: &[f32]) -> usize {
    let mut best = (0usize, f32::INFINITY);
    for (k, &d) in costs.iter().enumerate().take(256) {
        if d < best.1 {
            best = (k, d);
        }
    }
    best.0
}

/// Maximum flow / minimum cut (Boykov & Kolmogorov 2004) on a general graph with
/// `nodes` nodes, arc pairs `(u, v, cap u->v, cap v->u)` and per-node terminal
/// capacities `(source -> node, node -> sink)`. Returns the flow value and, per node,
/// whether it lies on the source side of a minimum cut (the nodes reachable from the
/// source in the residual graph). Capacities must be finite and `>= 0`.
pub fn max_flow(
    nodes: usize,
    edges: &[(u32, u32, f64, f64)],
    terminals: &[(f64, f64)],
) -> Result<(f64, Vec<bool>)> {
    if nodes > i32::MAX as usize {
        return Err(Error::limit(
            None,
            format!("max flow: {nodes} nodes"),
            format!("{} nodes", i32::MAX),
        ));
    }
    if terminals.len() != nodes {
        return Err(Error::Invalid(format!(
            "max flow: {} terminal pairs for {nodes} nodes",
            terminals.len()
        )));
    }
    let ok = |c: f64| c.is_finite() && c >= 0.0;
    let mut ge = Vec::with_capacity(edges.len());
    for (i, &(u, v, c, r)) in edges.iter().enumerate() {
        if u as usize >= nodes || v as usize >= nodes {
            return Err(Error::Invalid(format!(
                "max flow: edge {i} ({u}, {v}) names a node outside 0..{nodes}"
            )));
        }
        if !ok(c) || !ok(r) {
            return Err(Error::Invalid(format!(
                "max flow: edge {i} ({u}, {v}) has capacities {c} / {r}; need finite >= 0"
            )));
        }
        ge.push(cv::GcEdge {
            from: u,
            to: v,
            cap: c,
            rev_cap: r,
        });
    }
    let mut t = Vec::with_capacity(2 * nodes);
    for (i, &(s, k)) in terminals.iter().enumerate() {
        if !ok(s) || !ok(k) {
            return Err(Error::Invalid(format!(
                "max flow: node {i} has terminal capacities {s} / {k}; need finite >= 0"
            )));
        }
        t.push(s);
        t.push(k);
    }
    let r = cv::gc_max_flow(nodes as u32, &ge, &t)?;
    Ok((r.flow, r.side.iter().map(|&s| s == 1).collect()))
}

#[cfg(test)]
mod tests;
