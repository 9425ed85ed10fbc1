//! The one bridge to the C++/OpenCV layer in `cpp/`. All `unsafe` FFI of the crate
//! lives here; callers get safe functions and [`crate::Error::External`] for any C++
//! exception.

use crate::error::{Error, Result};

#[cxx::bridge(namespace = "lumiprobe")]
mod ffi {
    /// Keypoints and descriptors of one image.
    #[derive(Clone, Debug, Default)]
    struct Features {
        /// Keypoint positions, `x0, y0, x1, y1, …` (pixel centres at integers).
        xy: Vec<f32>,
        /// Float descriptors (SIFT), row-major `count x dim`.
        desc_f32: Vec<f32>,
        /// Binary descriptors (ORB, AKAZE), row-major `count x dim` bytes.
        desc_u8: Vec<u8>,
        /// Descriptor length.
        dim: i32,
        /// Number of keypoints.
        count: i32,
        /// True for binary descriptors (Hamming distance).
        binary: bool,
    }

    /// A fitted homography and its RANSAC inlier mask.
    #[derive(Clone, Debug, Default)]
    struct Homography {
        /// Row-major 3x3 matrix mapping source to destination points.
        h: [f64; 9],
        /// 1 for each inlier correspondence.
        inliers: Vec<u8>,
        /// False when no model could be fitted.
        ok: bool,
    }

    /// Settings of OpenCV's DIS optical flow (negative or zero = the preset's value).
    #[derive(Clone, Copy, Debug, PartialEq)]
    struct DisParams {
        /// 0 ultrafast, 1 fast, 2 medium.
        preset: i32,
        /// Finest pyramid level used (0 = full resolution; -1 = preset).
        finest_scale: i32,
        /// Patch size in pixels.
        patch_size: i32,
        /// Patch stride in pixels.
        patch_stride: i32,
        /// Gradient-descent iterations per patch.
        gradient_descent_iterations: i32,
        /// Variational refinement iterations (-1 = preset).
        variational_refinement_iterations: i32,
        /// Normalise patch means (robust to brightness differences).
        use_mean_normalization: bool,
        /// Spatial propagation of good patch flows.
        use_spatial_propagation: bool,
    }

    // ---- graph cut (cpp/maxflow.h): Boykov-Kolmogorov max-flow, expansion, swap ----

    /// One arc pair of a max-flow graph: `from -> to` with `cap`, `to -> from` with `rev_cap`.
    #[derive(Clone, Copy, Debug, PartialEq)]
    struct GcEdge {
        /// Tail node.
        from: u32,
        /// Head node.
        to: u32,
        /// Capacity `from -> to` (finite, >= 0).
        cap: f64,
        /// Capacity `to -> from` (finite, >= 0).
        rev_cap: f64,
    }

    /// Result of a max-flow computation.
    #[derive(Clone, Debug, Default)]
    struct GcFlow {
        /// Maximum flow value (= minimum cut capacity).
        flow: f64,
        /// Per node: 1 in the final source tree (reachable from s in the residual
        /// graph), 2 in the final sink tree (reaches t), 0 in neither.
        side: Vec<u8>,
    }

    /// Settings of a grid energy minimisation (see `crate::flow::graphcut`).
    #[derive(Clone, Copy, Debug, PartialEq)]
    struct GcGridParams {
        /// Grid width.
        width: u32,
        /// Grid height.
        height: u32,
        /// Number of labels (1..=255).
        labels: u32,
        /// Feature channels per pixel and label.
        channels: u32,
        /// Weight of the smoothness term.
        lambda: f64,
        /// Cap of one feature distance (also used for non-finite features).
        seam_cap: f64,
        /// Column 0 and column `width - 1` are neighbours (when `width >= 3`).
        wrap_x: bool,
        /// Alpha-beta swap instead of alpha-expansion.
        swap: bool,
        /// Maximum number of cycles over all moves.
        max_cycles: u32,
        /// Throw if a move's graph would raise the energy (construction bug).
        check: bool,
    }

    /// Result of a grid energy minimisation.
    #[derive(Clone, Debug, Default)]
    struct GcGridResult {
        /// Final label per pixel, row-major.
        labels: Vec<u8>,
        /// Sum of data costs.
        data_energy: f64,
        /// `lambda` times the sum of seam costs.
        smooth_energy: f64,
        /// Cycles run.
        cycles: u32,
        /// Total energy after each cycle.
        history: Vec<f64>,
    }

    unsafe extern "C++" {
        include!("lumiprobe/cpp/cv_bridge.h");

        type MatchIndex;

        fn set_num_threads(n: i32);
        fn detect_features(
            gray: &[u8],
            width: i32,
            height: i32,
            detector: i32,
            max_features: i32,
            threshold: f64,
            blur_sigma: f32,
        ) -> Result<Features>;
        fn build_index(train: &Features, flann_checks: i32) -> Result<UniquePtr<MatchIndex>>;
        fn keep_freed_memory(bytes: usize);
        fn match_ratio(index: &MatchIndex, query: &Features, ratio: f32) -> Result<Vec<i32>>;
        fn dis_flow(
            a: &[u8],
            b: &[u8],
            width: i32,
            height: i32,
            params: &DisParams,
            out: &mut [f32],
        ) -> Result<()>;
        fn find_homography(
            src: &[f32],
            dst: &[f32],
            threshold: f64,
            max_iters: i32,
            confidence: f64,
            method: i32,
        ) -> Result<Homography>;
    }

    // ---- graph cut ----
    unsafe extern "C++" {
        include!("lumiprobe/cpp/maxflow.h");

        fn gc_max_flow(nodes: u32, edges: &[GcEdge], terminals: &[f64]) -> Result<GcFlow>;
        fn gc_optimize_grid(
            params: &GcGridParams,
            data: &[f32],
            features: &[f32],
            init: &[u8],
        ) -> Result<GcGridResult>;
    }
}

pub use ffi::{DisParams, Features, Homography};

// SAFETY: MatchIndex is immutable after construction; its only mutable state (the
// FLANN search) is guarded by a mutex on the C++ side.
unsafe impl Send for ffi::MatchIndex {}
unsafe impl Sync for ffi::MatchIndex {}

fn cv_err(e: cxx::Exception) -> Error {
    Error::opencv(e.what())
}

/// Feature detectors available in Debian's OpenCV (no SURF: xfeatures2d is absent).
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Detector {
    /// Lowe's SIFT, float descriptors matched with a FLANN k-d forest (default).
    Sift,
    /// AKAZE, binary descriptors matched by brute-force Hamming distance.
    Akaze,
    /// ORB, binary descriptors matched by brute-force Hamming distance.
    Orb,
}

impl Detector {
    fn id(self) -> i32 {
        match self {
            Detector::Sift => 0,
            Detector::Akaze => 1,
            Detector::Orb => 2,
        }
    }
}

/// Robust estimators for [`find_homography`].
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Estimator {
    /// Classic RANSAC (deterministic in OpenCV: fixed RNG seed).
    Ransac,
    /// USAC with MAGSAC++ scoring.
    Magsac,
    /// Least median of squares.
    Lmeds,
}

/// Limits OpenCV's own thread pool (lumiprobe parallelises with rayon instead).
pub fn set_num_threads(n: i32) {
    ffi::set_num_threads(n);
}

impl Features {
    /// Keypoint `i` as `(x, y)`.
    pub fn point(&self, i: usize) -> (f32, f32) {
        (self.xy[2 * i], self.xy[2 * i + 1])
    }
    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.count.max(0) as usize
    }
    /// True when nothing was detected.
    pub fn is_empty(&self) -> bool {
        self.count <= 0
    }
}

/// How features are detected.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DetectParams {
    /// The detector.
    pub detector: Detector,
    /// Keep at most this many features (0 = no limit).
    pub max_features: i32,
    /// Detector response threshold (SIFT contrast, AKAZE threshold; 0 = OpenCV's default).
    pub threshold: f64,
    /// Gaussian pre-blur in pixels against sensor noise (0 = none).
    pub blur_sigma: f32,
}

/// Detects keypoints and computes descriptors on an 8-bit gray image.
pub fn detect(gray: &[u8], width: usize, height: usize, p: &DetectParams) -> Result<Features> {
    if width == 0 || height == 0 || gray.len() != width * height {
        return Err(Error::Invalid(format!(
            "gray image of {} bytes is not {width}x{height}",
            gray.len()
        )));
    }
    ffi::detect_features(
        gray,
        width as i32,
        height as i32,
        p.detector.id(),
        p.max_features,
        p.threshold,
        p.blur_sigma,
    )
    .map_err(cv_err)
}

/// A descriptor index over one image's features, for repeated queries.
pub struct MatchIndex(cxx::UniquePtr<ffi::MatchIndex>);

impl MatchIndex {
    /// Indexes `train`'s descriptors: float descriptors in a FLANN k-d forest searched
    /// with `flann_checks` leaf checks, or by exact brute force when `flann_checks` is 0;
    /// binary descriptors always by brute-force Hamming distance.
    pub fn new(train: &Features, flann_checks: i32) -> Result<Self> {
        let p = ffi::build_index(train, flann_checks.max(0)).map_err(cv_err)?;
        if p.is_null() {
            return Err(Error::opencv("index construction returned null"));
        }
        Ok(MatchIndex(p))
    }

    /// Matches `query` against the index with Lowe's ratio test: pairs
    /// `(query index, train index)` whose best distance is below `ratio` times the second best.
    pub fn match_ratio(&self, query: &Features, ratio: f32) -> Result<Vec<(usize, usize)>> {
        let idx = self.0.as_ref().ok_or_else(|| Error::opencv("null index"))?;
        let flat = ffi::match_ratio(idx, query, ratio).map_err(cv_err)?;
        Ok(flat
            .chunks_exact(2)
            .map(|p| (p[0] as usize, p[1] as usize))
            .collect())
    }
}

impl Default for DisParams {
    fn default() -> Self {
        DisParams {
            preset: 1,
            finest_scale: -1,
            patch_size: 0,
            patch_stride: 0,
            gradient_descent_iterations: 0,
            variational_refinement_iterations: -1,
            use_mean_normalization: true,
            use_spatial_propagation: true,
        }
    }
}

/// Asks the C library's allocator to serve blocks up to `bytes` from its heap
/// and to keep up to twice that freed instead of returning it to the system.
/// Each frame allocates and frees buffers of a few MB; by default every one is
/// a fresh mapping whose pages the kernel faults in and zeroes again (13% of
/// the fusion's time at 512x256 on one thread, by `perf`). Called once by the
/// command-line program; the library leaves its host's allocator alone.
pub fn keep_freed_memory(bytes: usize) {
    ffi::keep_freed_memory(bytes);
}

/// Dense optical flow from `a` to `b` (8-bit gray, same size): for each pixel `x`,
/// `a(x) ≈ b(x + flow(x))`. Returns interleaved `(dx, dy)` in pixels.
pub fn dis_flow(
    a: &[u8],
    b: &[u8],
    width: usize,
    height: usize,
    params: &DisParams,
) -> Result<Vec<f32>> {
    if width == 0 || height == 0 || a.len() != width * height || b.len() != a.len() {
        return Err(Error::Invalid(format!(
            "flow needs two gray images of {width}x{height}; got {} and {} bytes",
            a.len(),
            b.len()
        )));
    }
    let mut out = vec![0.0f32; 2 * a.len()];
    ffi::dis_flow(a, b, width as i32, height as i32, params, &mut out).map_err(cv_err)?;
    Ok(out)
}

/// Fits a homography `dst ~ H src` robustly. Returns `None` when fewer than four
/// correspondences are given or no model is found.
pub fn find_homography(
    src: &[(f32, f32)],
    dst: &[(f32, f32)],
    threshold: f64,
    max_iters: i32,
    confidence: f64,
    estimator: Estimator,
) -> Result<Option<Homography>> {
    if src.len() != dst.len() {
        return Err(Error::Invalid(format!(
            "{} source points but {} destination points",
            src.len(),
            dst.len()
        )));
    }
    let a: Vec<f32> = src.iter().flat_map(|p| [p.0, p.1]).collect();
    let b: Vec<f32> = dst.iter().flat_map(|p| [p.0, p.1]).collect();
    let m = match estimator {
        Estimator::Ransac => 0,
        Estimator::Magsac => 1,
        Estimator::Lmeds => 2,
    };
    let h = ffi::find_homography(&a, &b, threshold, max_iters, confidence, m).map_err(cv_err)?;
    Ok(if h.ok { Some(h) } else { None })
}

// ---- graph cut: safe wrappers (validation proper lives in crate::flow::graphcut) ----

pub use ffi::{GcEdge, GcFlow, GcGridParams, GcGridResult};

fn gc_err(e: cxx::Exception) -> Error {
    Error::Internal(format!("graph cut: {}", e.what()))
}

/// Max-flow / min-cut (Boykov & Kolmogorov 2004) on `nodes` nodes with the given arc
/// pairs and `terminals` = `(source cap, sink cap)` interleaved per node. The C++ side
/// checks indices and capacities and reports violations as [`Error::Internal`]
/// (the Rust side validated them first).
pub fn gc_max_flow(nodes: u32, edges: &[GcEdge], terminals: &[f64]) -> Result<GcFlow> {
    ffi::gc_max_flow(nodes, edges, terminals).map_err(gc_err)
}

/// Alpha-expansion or alpha-beta swap on a 4-connected grid (see
/// `crate::flow::graphcut::optimize`, which validates before calling this).
pub fn gc_optimize_grid(
    params: &GcGridParams,
    data: &[f32],
    features: &[f32],
    init: &[u8],
) -> Result<GcGridResult> {
    ffi::gc_optimize_grid(params, data, features, init).map_err(gc_err)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plain(detector: Detector) -> DetectParams {
        DetectParams {
            detector,
            max_features: 0,
            threshold: 0.0,
            blur_sigma: 0.0,
        }
    }

    fn texture(w: usize, h: usize, seed: u32) -> Vec<u8> {
        // Blocky value noise plus a few rectangles: enough corners for SIFT.
        let mut s = seed.wrapping_mul(2654435761).max(1);
        let mut cells = vec![0u8; 64];
        for c in cells.iter_mut() {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            *c = (s & 0xff) as u8;
        }
        let mut img = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let c = cells[((y * 8 / h) * 8 + (x * 8 / w)) % 64] as u32;
                let fine = cells[((y / 5) * 7 + (x / 7)) % 64] as u32;
                img[y * w + x] = ((c * 3 + fine) / 4) as u8;
            }
        }
        img
    }

    #[test]
    fn textureless_image_gives_no_features_and_no_matches() {
        let flat = vec![128u8; 64 * 64];
        let f = detect(&flat, 64, 64, &plain(Detector::Sift)).unwrap();
        assert!(f.is_empty());
        let idx = MatchIndex::new(&f, 32).unwrap();
        assert!(idx.match_ratio(&f, 0.7).unwrap().is_empty());
    }

    #[test]
    fn self_matching_finds_identity_homography() {
        let (w, h) = (128, 128);
        let img = texture(w, h, 7);
        for det in [Detector::Sift, Detector::Orb, Detector::Akaze] {
            let f = detect(&img, w, h, &plain(det)).unwrap();
            assert!(f.len() > 10, "{det:?} found {}", f.len());
            let idx = MatchIndex::new(&f, 32).unwrap();
            let m = idx.match_ratio(&f, 0.99).unwrap();
            let src: Vec<_> = m.iter().map(|&(q, _)| f.point(q)).collect();
            let dst: Vec<_> = m.iter().map(|&(_, t)| f.point(t)).collect();
            let hm = find_homography(&src, &dst, 2.0, 2000, 0.995, Estimator::Ransac)
                .unwrap()
                .unwrap();
            let hn: Vec<f64> = hm.h.iter().map(|v| v / hm.h[8]).collect();
            let id = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
            for k in 0..9 {
                assert!((hn[k] - id[k]).abs() < 1e-3, "{det:?}: {hn:?}");
            }
        }
    }

    #[test]
    fn dis_recovers_a_shift_and_rejects_mismatched_sizes() {
        let (w, h) = (96, 64);
        let big = texture(w + 8, h, 11);
        // a(x) = b(x + 3): a shows what b shows three pixels further right.
        let row = w + 8;
        let a: Vec<u8> = (0..h * w).map(|i| big[(i / w) * row + i % w + 4]).collect();
        let b: Vec<u8> = (0..h * w).map(|i| big[(i / w) * row + i % w + 1]).collect();
        let f = dis_flow(&a, &b, w, h, &DisParams::default()).unwrap();
        // Median dx over the interior.
        let mut dx: Vec<f32> = (10..h - 10)
            .flat_map(|y| (10..w - 10).map(move |x| (y, x)))
            .map(|(y, x)| f[2 * (y * w + x)])
            .collect();
        dx.sort_by(f32::total_cmp);
        let med = dx[dx.len() / 2];
        assert!((med - 3.0).abs() < 0.5, "median dx {med}");
        assert!(dis_flow(&a, &b[..10], w, h, &DisParams::default()).is_err());
    }

    #[test]
    fn bad_arguments_become_errors() {
        assert!(detect(&[0u8; 10], 4, 4, &plain(Detector::Sift)).is_err());
        assert!(find_homography(&[(0.0, 0.0)], &[], 1.0, 10, 0.9, Estimator::Ransac).is_err());
        assert!(find_homography(
            &[(0.0, 0.0); 3],
            &[(0.0, 0.0); 3],
            1.0,
            10,
            0.9,
            Estimator::Ransac
        )
        .unwrap()
        .is_none());
        // Mixed descriptor kinds: a C++ exception surfaces as an Error, not an abort.
        let img = texture(96, 96, 3);
        let a = detect(&img, 96, 96, &plain(Detector::Sift)).unwrap();
        let b = detect(&img, 96, 96, &plain(Detector::Orb)).unwrap();
        let idx = MatchIndex::new(&a, 32).unwrap();
        assert!(matches!(
            idx.match_ratio(&b, 0.7),
            Err(Error::External { .. })
        ));
    }
}
