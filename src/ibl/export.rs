//! The prefiltered IBL set on disk and in memory: SH coefficients, irradiance cube,
//! GGX specular cube and split-sum BRDF table, everything a renderer needs to light
//! with one probe.
//!
//! [`prefilter_to_dir`] reads a probe and writes, atomically, one file per item:
//!
//! | file | content |
//! |------|---------|
//! | `sh.json` | nine RGB SH coefficients (window applied), window, basis order |
//! | `irradiance_{face}.exr` or `irradiance_strip.exr` | irradiance `E` (not `E / pi`) |
//! | `specular_mip{i}_{face}.exr` or `specular_mip{i}.exr` | GGX-prefiltered radiance, roughness `i / (mips - 1)` |
//! | `brdf_lut.exr` | split-sum scale (R) and bias (G), x = `N.V`, y = roughness |
//! | `prefilter.json` | manifest describing all of the above, written last |
//!
//! `{face}` is the face's lower-case name
//! ([`CubeFace::name`](crate::sphere::CubeFace::name)); a strip holds the six faces
//! side by side in [`FACES`] order (face `i` at columns `i n .. (i + 1) n`). Faces
//! are oriented as in [`crate::sphere::cube`]: face coordinates `(a, b)` look along
//! `N + a R + b D` with `(N, R, D)` from
//! [`CubeFace::basis`](crate::sphere::CubeFace::basis), `a` growing with the column
//! and `b` with the row; axes are the camera's (x right, y up, -z forward). Because
//! the manifest is written after every image, a directory with a `prefilter.json` is
//! complete.
//!
//! These files are lumiprobe's own layout. For engines, `lumiprobe export`
//! ([`crate::pipeline::export`]) writes the same cubes as KTX 2.0 files
//! ([`super::ktx2`]), world-aligned.

use super::brdf_lut::{brdf_lookup, brdf_lut, DEFAULT_LUT_SAMPLES, DEFAULT_LUT_SIZE};
use super::irradiance::{irradiance_cube, DEFAULT_IRRADIANCE_FACE_SIZE};
use super::prefilter::{prefilter_specular, CubeMip, SpecularCube, SpecularOptions, LOD_BIAS};
use super::sh::{Sh9, ShWindow, SH_COUNT};
use crate::error::{Error, Result};
use crate::image::HdrImage;
use crate::sphere::FACES;
use glam::Vec3;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

/// Name of the manifest file in an output directory.
pub const MANIFEST_FILE: &str = "prefilter.json";
/// Name of the SH coefficients file in an output directory.
pub const SH_FILE: &str = "sh.json";
/// Name of the BRDF table in an output directory.
pub const LUT_FILE: &str = "brdf_lut.exr";
/// Value of [`PrefilterManifest::format`], so readers can recognise the file.
pub const MANIFEST_FORMAT: &str = "lumiprobe-prefilter";
/// Version of the directory layout described by [`PrefilterManifest`].
pub const MANIFEST_VERSION: u32 = 1;

/// How cube faces are stored on disk.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FaceLayout {
    /// One file per face, named with [`CubeFace::name`](crate::sphere::CubeFace::name).
    #[default]
    Faces,
    /// One `6n x n` file per cube: the faces side by side in [`FACES`] order.
    Strip,
}

/// Everything that controls prefiltering (see [`prefilter_to_dir`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PrefilterOptions {
    /// Specular cube: face size, mip count, samples per texel.
    pub specular: SpecularOptions,
    /// Face size of the irradiance cube (default 32: irradiance is very smooth).
    pub irradiance_face_size: usize,
    /// Size of the square BRDF table (default 128).
    pub lut_size: usize,
    /// GGX samples per BRDF-table texel (default 512).
    pub lut_samples: usize,
    /// Ringing window applied to the SH before computing irradiance (default: the
    /// same as [`ShWindow::default`], i.e. none).
    pub sh_window: ShWindow,
    /// Files per face or one strip per cube (default: per face).
    pub layout: FaceLayout,
}

impl Default for PrefilterOptions {
    /// Defaults of each part: [`SpecularOptions::default`], 32-texel irradiance
    /// faces, a 128x128 BRDF table of 512 samples per texel, no SH window, one file
    /// per face.
    fn default() -> Self {
        PrefilterOptions {
            specular: SpecularOptions::default(),
            irradiance_face_size: DEFAULT_IRRADIANCE_FACE_SIZE,
            lut_size: DEFAULT_LUT_SIZE,
            lut_samples: DEFAULT_LUT_SAMPLES,
            sh_window: ShWindow::default(),
            layout: FaceLayout::default(),
        }
    }
}

impl PrefilterOptions {
    /// Fails with [`Error::Invalid`] when a size or count is zero (the in-memory
    /// functions would silently treat it as 1; for files that is almost certainly
    /// a mistake).
    pub fn validate(&self) -> Result<()> {
        let checks = [
            ("specular face size", self.specular.face_size),
            ("specular mip count", self.specular.mip_count),
            ("specular samples", self.specular.samples),
            ("irradiance face size", self.irradiance_face_size),
            ("BRDF table size", self.lut_size),
            ("BRDF table samples", self.lut_samples),
        ];
        for (what, v) in checks {
            if v == 0 {
                return Err(Error::Invalid(format!("{what} must be at least 1")));
            }
        }
        // Upper bounds keep a mistaken argument from allocating without limit.
        let limits = [
            ("specular face size", self.specular.face_size, 8192),
            ("specular mip count", self.specular.mip_count, 16),
            ("specular samples", self.specular.samples, 1 << 16),
            ("irradiance face size", self.irradiance_face_size, 4096),
            ("BRDF table size", self.lut_size, 4096),
            ("BRDF table samples", self.lut_samples, 1 << 16),
        ];
        for (what, v, max) in limits {
            if v > max {
                return Err(Error::Invalid(format!("{what} {v} is above {max}")));
            }
        }
        if let ShWindow::Hanning(w) | ShWindow::Lanczos(w) = self.sh_window {
            if !w.is_finite() || w <= 0.0 {
                return Err(Error::Invalid(format!(
                    "SH window width must be a positive number, not {w}"
                )));
            }
        }
        Ok(())
    }
}

/// What [`prefilter_to_dir`] did.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PrefilterReport {
    /// The probe that was read.
    pub probe: PathBuf,
    /// Its size in pixels, `[width, height]`.
    pub probe_size: [usize; 2],
    /// Every file written, the manifest last.
    pub files: Vec<PathBuf>,
    /// `(roughness, face size)` of each specular mip.
    pub mips: Vec<(f32, usize)>,
    /// Seconds spent prefiltering (without reading and writing).
    pub prefilter_seconds: f64,
    /// Seconds for the whole call.
    pub total_seconds: f64,
}

/// A prefiltered probe, ready for shading: what [`prefilter_to_dir`] writes and
/// [`load_prefiltered`] reads back, or built in memory by
/// [`Prefiltered::from_env`].
#[derive(Clone, Debug, PartialEq)]
pub struct Prefiltered {
    /// SH coefficients of the radiance with the window already applied (the ones
    /// the irradiance is computed from).
    pub sh: Sh9,
    /// Irradiance cube (`E`, not `E / pi`), faces in [`FACES`] order.
    pub irradiance: [HdrImage; 6],
    /// GGX-prefiltered radiance, roughness increasing with the mip.
    pub specular: SpecularCube,
    /// Split-sum BRDF table (see [`mod@super::brdf_lut`] for its axes).
    pub lut: HdrImage,
}

impl Prefiltered {
    /// Prefilters an equirect, linear-radiance environment in memory (what the
    /// renderer uses): SH projection (then `opts.sh_window`), irradiance cube,
    /// specular cube and BRDF table. Fails with [`Error::Invalid`] for an image
    /// smaller than [`MIN_PROBE_SIZE`], zero sizes in `opts` or any NaN, infinite
    /// or negative sample (repair
    /// those first with [`HdrImage::repair_invalid`] if that is acceptable). The
    /// BRDF table is computed once per process per size and sample count.
    pub fn from_env(env: &HdrImage, opts: &PrefilterOptions) -> Result<Self> {
        opts.validate()?;
        if let Some(why) = too_small(env) {
            return Err(Error::Invalid(format!("environment {why}")));
        }
        let bad = env.count_invalid();
        if bad > 0 {
            return Err(Error::Invalid(format!(
                "environment has {bad} NaN, infinite or negative samples"
            )));
        }
        Ok(build(env, opts).0)
    }

    /// Diffuse irradiance `E` (not `E / pi`) for the surface normal `n`, from the
    /// clamped SH (exact and continuous; the irradiance cube holds the same function
    /// at its texel centres). Lambertian radiance is `albedo * E / pi`.
    pub fn irradiance(&self, n: Vec3) -> [f32; 3] {
        self.sh.irradiance_clamped(n)
    }

    /// Prefiltered specular radiance around the reflection direction `r` for
    /// `roughness` (see [`SpecularCube::sample`]). Multiply by `F0 A + B` from
    /// [`Prefiltered::brdf`] for the split-sum specular term.
    pub fn specular(&self, r: Vec3, roughness: f32) -> [f32; 3] {
        self.specular.sample(r, roughness)
    }

    /// Split-sum `[A, B]` (scale and bias of `F0`) for `N.V` and roughness,
    /// bilinear in the table.
    pub fn brdf(&self, n_dot_v: f32, roughness: f32) -> [f32; 2] {
        brdf_lookup(&self.lut, n_dot_v, roughness)
    }
}

/// Smallest probe (width, height) that [`Prefiltered::from_env`] and
/// [`prefilter_to_dir`] accept: with fewer pixels the SH projection (one sample
/// per pixel) misses even a constant environment's irradiance by more than 5%
/// (by 60% for a 2x1 probe).
pub const MIN_PROBE_SIZE: (usize, usize) = (8, 4);

/// Why `env` is too small to prefilter, if it is.
fn too_small(env: &HdrImage) -> Option<String> {
    let (w, h) = (env.width(), env.height());
    (w < MIN_PROBE_SIZE.0 || h < MIN_PROBE_SIZE.1).then(|| {
        format!(
            "of {w}x{h} pixels is too small to prefilter (at least {}x{})",
            MIN_PROBE_SIZE.0, MIN_PROBE_SIZE.1
        )
    })
}

/// [`brdf_lut`], computed once per process for each `(size, samples)`: the table
/// does not depend on the environment, and computing it costs about as much as
/// prefiltering a probe. Up to four tables are kept.
fn cached_brdf_lut(size: usize, samples: usize) -> HdrImage {
    type Cache = Mutex<Vec<((usize, usize), HdrImage)>>;
    static CACHE: OnceLock<Cache> = OnceLock::new();
    let cache = CACHE.get_or_init(|| Mutex::new(Vec::new()));
    let key = (size, samples);
    if let Ok(c) = cache.lock() {
        if let Some((_, lut)) = c.iter().find(|(k, _)| *k == key) {
            return lut.clone();
        }
    }
    let lut = brdf_lut(size, samples);
    if let Ok(mut c) = cache.lock() {
        if c.len() < 4 && !c.iter().any(|(k, _)| *k == key) {
            c.push((key, lut.clone()));
        }
    }
    lut
}

/// Prefilters a valid environment; also returns the unwindowed SH.
fn build(env: &HdrImage, opts: &PrefilterOptions) -> (Prefiltered, Sh9) {
    let raw = Sh9::project(env);
    let sh = raw.windowed(opts.sh_window);
    let (specular, (irradiance, lut)) = rayon::join(
        || prefilter_specular(env, &opts.specular),
        || {
            (
                irradiance_cube(&sh, opts.irradiance_face_size),
                cached_brdf_lut(opts.lut_size, opts.lut_samples),
            )
        },
    );
    (
        Prefiltered {
            sh,
            irradiance,
            specular,
            lut,
        },
        raw,
    )
}

/// Six faces side by side (`6n x n`), face `i` (in [`FACES`] order) at columns
/// `i n .. (i + 1) n`: the [`FaceLayout::Strip`] file layout.
pub fn faces_to_strip(faces: &[HdrImage; 6]) -> HdrImage {
    let n = faces[0].width();
    let mut out = HdrImage::new(6 * n, n);
    for (i, face) in faces.iter().enumerate() {
        for y in 0..n.min(face.height()) {
            for x in 0..n.min(face.width()) {
                out.set(i * n + x, y, face.get(x, y));
            }
        }
    }
    out
}

/// Splits a `6n x n` strip into its six faces ([`faces_to_strip`] reversed);
/// `None` if the image is not six squares wide.
pub fn strip_to_faces(strip: &HdrImage) -> Option<[HdrImage; 6]> {
    let n = strip.height();
    if n == 0 || strip.width() != 6 * n {
        return None;
    }
    Some(std::array::from_fn(|i| {
        HdrImage::from_fn(n, n, |x, y| strip.get(i * n + x, y))
    }))
}

/// One face of the cube as described in the manifest.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ManifestFace {
    /// Position in [`FACES`] (and in a strip).
    pub index: usize,
    /// [`CubeFace::name`](crate::sphere::CubeFace::name).
    pub name: String,
    /// Direction the face looks along (`N` of
    /// [`CubeFace::basis`](crate::sphere::CubeFace::basis)).
    pub normal: [f32; 3],
    /// Direction of increasing column (`R`).
    pub right: [f32; 3],
    /// Direction of increasing row (`D`).
    pub down: [f32; 3],
}

/// The SH part of the manifest.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ManifestSh {
    /// File with the coefficients ([`ShFile`]).
    pub file: String,
    /// Window applied to the stored coefficients.
    pub window: ShWindow,
}

/// The irradiance part of the manifest.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ManifestIrradiance {
    /// What the texels hold (irradiance `E`, not `E / pi`).
    pub quantity: String,
    /// Face size in texels.
    pub face_size: usize,
    /// Files, one per face in [`FACES`] order or a single strip.
    pub files: Vec<String>,
}

/// One specular mip in the manifest.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ManifestMip {
    /// GGX perceptual roughness (`alpha = roughness^2`).
    pub roughness: f32,
    /// Face size in texels.
    pub size: usize,
    /// Files, one per face in [`FACES`] order or a single strip.
    pub files: Vec<String>,
}

/// The specular part of the manifest.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ManifestSpecular {
    /// What the texels hold and how they were computed.
    pub quantity: String,
    /// GGX samples per texel.
    pub samples: usize,
    /// Bias added to each sample's source level ([`LOD_BIAS`]).
    pub lod_bias: f32,
    /// The mips, roughness increasing.
    pub mips: Vec<ManifestMip>,
}

/// The BRDF-table part of the manifest.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ManifestLut {
    /// File name.
    pub file: String,
    /// Texels per side.
    pub size: usize,
    /// GGX samples per texel.
    pub samples: usize,
    /// Meaning of the x axis.
    pub x_axis: String,
    /// Meaning of the y axis.
    pub y_axis: String,
    /// Meaning of the channels.
    pub channels: String,
    /// Masking-shadowing term used.
    pub geometry: String,
}

/// Contents of `prefilter.json`: a self-contained description of the directory, so
/// a consumer in any language can use the files without reading this crate.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PrefilterManifest {
    /// Always [`MANIFEST_FORMAT`].
    pub format: String,
    /// Layout version ([`MANIFEST_VERSION`]).
    pub version: u32,
    /// The probe the set was computed from.
    pub source: String,
    /// Its size in pixels, `[width, height]`.
    pub source_size: [usize; 2],
    /// How cube faces are stored.
    pub layout: FaceLayout,
    /// Axes and face orientation convention, in words.
    pub orientation: String,
    /// The six faces in storage order.
    pub faces: Vec<ManifestFace>,
    /// SH coefficients.
    pub sh: ManifestSh,
    /// Irradiance cube.
    pub irradiance: ManifestIrradiance,
    /// Specular cube.
    pub specular: ManifestSpecular,
    /// BRDF table.
    pub brdf_lut: ManifestLut,
}

/// Contents of `sh.json`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ShFile {
    /// The basis, in words.
    pub basis: String,
    /// The nine basis functions in coefficient order.
    pub order: Vec<String>,
    /// Window applied to `coefficients`.
    pub window: ShWindow,
    /// `coeffs[k] = [r, g, b]` after the window (used for the irradiance).
    pub coefficients: [[f32; 3]; SH_COUNT],
    /// The projection before windowing.
    pub coefficients_unwindowed: [[f32; 3]; SH_COUNT],
    /// How to evaluate irradiance from `coefficients`.
    pub irradiance: String,
}

const ORIENTATION: &str = "camera axes: x right, y up, -z forward (the equirect centre looks \
along -z). Face (a, b) in [-1, 1]^2 looks along normal + a*right + b*down; column x has \
a = 2 (x + 0.5) / n - 1, row y has b = 2 (y + 0.5) / n - 1 (row 0 at the top). \
Same as lumiprobe src/sphere/cube.rs.";

const IRRADIANCE_QUANTITY: &str = "irradiance E(n) = integral of L(d) max(0, n.d) dOmega, \
NOT divided by pi (a constant radiance L gives pi L); Lambertian exit radiance is \
albedo * E / pi. Evaluated at texel centres from the clamped order-2 SH \
(Ramamoorthi & Hanrahan 2001).";

const SPECULAR_QUANTITY: &str = "GGX-prefiltered radiance (Karis 2013 split sum, N = V = R, \
alpha = roughness^2, weighted by N.L), importance sampled on a Hammersley set with \
PDF-based source mip selection (Colbert & Krivanek, GPU Gems 3 ch. 20). Mip i has \
roughness i / (mips - 1); mip 0 is an area-weighted resample of the probe.";

fn manifest_faces() -> Vec<ManifestFace> {
    FACES
        .iter()
        .map(|&f| {
            let (n, r, d) = f.basis();
            ManifestFace {
                index: f.index(),
                name: f.name().to_string(),
                normal: n.to_array(),
                right: r.to_array(),
                down: d.to_array(),
            }
        })
        .collect()
}

fn sh_order() -> Vec<String> {
    [
        "k=0 (l=0,m=0): 0.282095",
        "k=1 (l=1,m=-1): 0.488603 y",
        "k=2 (l=1,m=0): 0.488603 z",
        "k=3 (l=1,m=1): 0.488603 x",
        "k=4 (l=2,m=-2): 1.092548 x y",
        "k=5 (l=2,m=-1): 1.092548 y z",
        "k=6 (l=2,m=0): 0.315392 (3 z^2 - 1)",
        "k=7 (l=2,m=1): 1.092548 x z",
        "k=8 (l=2,m=2): 0.546274 (x^2 - y^2)",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

/// File names of one cube for `prefix` (`irradiance` or `specular_mip{i}`).
fn cube_file_names(prefix: &str, layout: FaceLayout, strip_suffix: &str) -> Vec<String> {
    match layout {
        FaceLayout::Faces => FACES
            .iter()
            .map(|f| format!("{prefix}_{}.exr", f.name()))
            .collect(),
        FaceLayout::Strip => vec![format!("{prefix}{strip_suffix}.exr")],
    }
}

fn irradiance_files(layout: FaceLayout) -> Vec<String> {
    cube_file_names("irradiance", layout, "_strip")
}

fn specular_files(i: usize, layout: FaceLayout) -> Vec<String> {
    cube_file_names(&format!("specular_mip{i}"), layout, "")
}

fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<()> {
    let mut text = serde_json::to_string_pretty(value)
        .map_err(|e| Error::Invalid(format!("{}: cannot encode JSON: {e}", path.display())))?;
    text.push('\n');
    crate::fsutil::write_atomic(path, text.as_bytes())
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let bytes = crate::fsutil::read(path)?;
    serde_json::from_slice(&bytes).map_err(|e| Error::format(path, format!("invalid JSON: {e}")))
}

/// Writes one cube as per-face files or one strip; returns the paths written.
fn write_cube(dir: &Path, names: &[String], faces: &[HdrImage; 6]) -> Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    if names.len() == 1 {
        let p = dir.join(&names[0]);
        crate::image::io::write_hdr(&p, &faces_to_strip(faces))?;
        written.push(p);
    } else {
        for (name, face) in names.iter().zip(faces) {
            let p = dir.join(name);
            crate::image::io::write_hdr(&p, face)?;
            written.push(p);
        }
    }
    Ok(written)
}

/// Reads the probe at `probe` (any HDR format [`crate::image::io::read_hdr`]
/// reads: EXR, Radiance `.hdr`, PFM), prefilters it with `opts`, and writes the set
/// described in the module docs into `out_dir` (created if needed). Every file is
/// written atomically and the manifest last.
///
/// A probe with any NaN, infinite or negative sample is **rejected** with an
/// [`Error::Format`] naming the file and the count, rather than silently repaired:
/// such values mean an upstream bug, and any repair would change the lighting.
/// So is a probe smaller than [`MIN_PROBE_SIZE`]. Zero sizes in `opts` are
/// [`Error::Invalid`].
pub fn prefilter_to_dir(
    probe: &Path,
    out_dir: &Path,
    opts: &PrefilterOptions,
) -> Result<PrefilterReport> {
    let start = std::time::Instant::now();
    opts.validate()?;
    let env = crate::image::io::read_hdr(probe)?;
    prefilter_image_to_dir(&env, probe, out_dir, opts, start)
}

/// [`prefilter_to_dir`] for a probe already read from `probe` (named in the
/// report and in errors), timed from `start`.
pub fn prefilter_image_to_dir(
    env: &HdrImage,
    probe: &Path,
    out_dir: &Path,
    opts: &PrefilterOptions,
    start: std::time::Instant,
) -> Result<PrefilterReport> {
    opts.validate()?;
    if let Some(why) = too_small(&env) {
        return Err(Error::format(probe, format!("probe {why}")));
    }
    let bad = env.count_invalid();
    if bad > 0 {
        return Err(Error::format(
            probe,
            format!(
                "{bad} samples are NaN, infinite or negative; refusing to prefilter \
                 (repair the probe with `lumiprobe convert` and retry)"
            ),
        ));
    }
    let t = std::time::Instant::now();
    let (pre, raw_sh) = build(env, opts);
    let prefilter_seconds = t.elapsed().as_secs_f64();

    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    let mut files = Vec::new();

    let sh_path = out_dir.join(SH_FILE);
    write_json(
        &sh_path,
        &ShFile {
            basis: "real orthonormal spherical harmonics, bands l <= 2, coefficient \
                    k = l (l + 1) + m, c_k = integral of L(d) Y_k(d) dOmega; d in camera \
                    axes x right, y up, z backward (see lumiprobe src/ibl/sh.rs)"
                .to_string(),
            order: sh_order(),
            window: opts.sh_window,
            coefficients: pre.sh.coeffs,
            coefficients_unwindowed: raw_sh.coeffs,
            irradiance: "E(n) = sum_k A_l(k) c_k Y_k(n), A = [pi, 2 pi / 3, pi / 4] \
                         (Ramamoorthi & Hanrahan 2001); clamp at 0 for shading"
                .to_string(),
        },
    )?;
    files.push(sh_path);

    let irr_names = irradiance_files(opts.layout);
    files.extend(write_cube(out_dir, &irr_names, &pre.irradiance)?);

    let mut mips = Vec::new();
    for (i, mip) in pre.specular.mips.iter().enumerate() {
        let names = specular_files(i, opts.layout);
        files.extend(write_cube(out_dir, &names, &mip.faces)?);
        mips.push(ManifestMip {
            roughness: mip.roughness,
            size: mip.size,
            files: names,
        });
    }

    let lut_path = out_dir.join(LUT_FILE);
    crate::image::io::write_hdr(&lut_path, &pre.lut)?;
    files.push(lut_path);

    let manifest = PrefilterManifest {
        format: MANIFEST_FORMAT.to_string(),
        version: MANIFEST_VERSION,
        source: probe.display().to_string(),
        source_size: [env.width(), env.height()],
        layout: opts.layout,
        orientation: ORIENTATION.to_string(),
        faces: manifest_faces(),
        sh: ManifestSh {
            file: SH_FILE.to_string(),
            window: opts.sh_window,
        },
        irradiance: ManifestIrradiance {
            quantity: IRRADIANCE_QUANTITY.to_string(),
            face_size: pre.irradiance[0].width(),
            files: irr_names,
        },
        specular: ManifestSpecular {
            quantity: SPECULAR_QUANTITY.to_string(),
            samples: opts.specular.samples,
            lod_bias: LOD_BIAS,
            mips: mips.clone(),
        },
        brdf_lut: ManifestLut {
            file: LUT_FILE.to_string(),
            size: pre.lut.width(),
            samples: opts.lut_samples,
            x_axis: "N.V = (column + 0.5) / size".to_string(),
            y_axis: "roughness = (row + 0.5) / size, row 0 (top) smoothest".to_string(),
            channels: "R = A (scale of F0), G = B (bias); specular = prefiltered * (F0 A + B); \
                       B channel 0"
                .to_string(),
            geometry: "Smith GGX height-correlated (Heitz 2014), alpha = roughness^2".to_string(),
        },
    };
    let manifest_path = out_dir.join(MANIFEST_FILE);
    write_json(&manifest_path, &manifest)?;
    files.push(manifest_path);

    Ok(PrefilterReport {
        probe: probe.to_path_buf(),
        probe_size: [env.width(), env.height()],
        files,
        mips: mips.iter().map(|m| (m.roughness, m.size)).collect(),
        prefilter_seconds,
        total_seconds: start.elapsed().as_secs_f64(),
    })
}

/// Joins a file name from the manifest to `dir`, refusing anything that is not a
/// plain file name (no separators, no `..`), so a crafted manifest cannot make
/// the loader read outside the directory.
fn member(dir: &Path, manifest: &Path, name: &str) -> Result<PathBuf> {
    let p = Path::new(name);
    let plain = p.file_name().is_some_and(|f| f == p.as_os_str()) && name != "..";
    if !plain {
        return Err(Error::format(
            manifest,
            format!("file entry {name:?} is not a plain file name"),
        ));
    }
    Ok(dir.join(p))
}

/// Reads one cube (per-face files or a strip) and checks its faces are `n x n`.
fn read_cube(dir: &Path, manifest: &Path, names: &[String], n: usize) -> Result<[HdrImage; 6]> {
    let faces: [HdrImage; 6] = match names.len() {
        1 => {
            let p = member(dir, manifest, &names[0])?;
            let strip = crate::image::io::read_hdr(&p)?;
            strip_to_faces(&strip).ok_or_else(|| {
                Error::format(
                    &p,
                    format!(
                        "a face strip must be 6n x n, not {}x{}",
                        strip.width(),
                        strip.height()
                    ),
                )
            })?
        }
        6 => {
            let mut v = Vec::with_capacity(6);
            for name in names {
                v.push(crate::image::io::read_hdr(&member(dir, manifest, name)?)?);
            }
            v.try_into().expect("six faces")
        }
        k => {
            return Err(Error::format(
                manifest,
                format!("a cube lists {k} files; expected 6 faces or 1 strip"),
            ))
        }
    };
    for (face, name) in faces.iter().zip(FACES) {
        if face.width() != n || face.height() != n {
            return Err(Error::format(
                manifest,
                format!(
                    "{} face is {}x{}, the manifest says {n}x{n}",
                    name.name(),
                    face.width(),
                    face.height()
                ),
            ));
        }
    }
    Ok(faces)
}

/// Reads a directory written by [`prefilter_to_dir`] back into a [`Prefiltered`]
/// (SH from `sh.json`, cubes and table from the EXR files listed in
/// `prefilter.json`). Fails naming the file when the manifest is missing or of
/// another format or version, a listed file is missing, or sizes disagree with the
/// manifest.
pub fn load_prefiltered(dir: &Path) -> Result<Prefiltered> {
    let manifest_path = dir.join(MANIFEST_FILE);
    let m: PrefilterManifest = read_json(&manifest_path)?;
    if m.format != MANIFEST_FORMAT || m.version != MANIFEST_VERSION {
        return Err(Error::format(
            &manifest_path,
            format!(
                "is {:?} version {}, expected {MANIFEST_FORMAT:?} version {MANIFEST_VERSION}",
                m.format, m.version
            ),
        ));
    }
    let sh_file: ShFile = read_json(&member(dir, &manifest_path, &m.sh.file)?)?;
    let irradiance = read_cube(
        dir,
        &manifest_path,
        &m.irradiance.files,
        m.irradiance.face_size,
    )?;
    let mut mips = Vec::with_capacity(m.specular.mips.len());
    for mip in &m.specular.mips {
        let faces = read_cube(dir, &manifest_path, &mip.files, mip.size)?;
        mips.push(CubeMip {
            roughness: mip.roughness,
            size: mip.size,
            faces,
        });
    }
    if mips.is_empty() {
        return Err(Error::format(&manifest_path, "lists no specular mips"));
    }
    let lut_path = member(dir, &manifest_path, &m.brdf_lut.file)?;
    let lut = crate::image::io::read_hdr(&lut_path)?;
    Ok(Prefiltered {
        sh: Sh9 {
            coeffs: sh_file.coefficients,
        },
        irradiance,
        specular: SpecularCube { mips },
        lut,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strip_round_trip_keeps_face_order() {
        let faces: [HdrImage; 6] =
            std::array::from_fn(|i| HdrImage::from_fn(3, 3, |x, y| [i as f32, x as f32, y as f32]));
        let strip = faces_to_strip(&faces);
        assert_eq!((strip.width(), strip.height()), (18, 3));
        assert_eq!(strip.get(3 * 4 + 1, 2), [4.0, 1.0, 2.0]);
        assert_eq!(strip_to_faces(&strip).unwrap(), faces);
        assert!(strip_to_faces(&HdrImage::new(5, 1)).is_none());
    }

    #[test]
    fn file_names_follow_the_layout() {
        assert_eq!(
            irradiance_files(FaceLayout::Strip),
            ["irradiance_strip.exr"]
        );
        assert_eq!(specular_files(2, FaceLayout::Strip), ["specular_mip2.exr"]);
        let f = specular_files(0, FaceLayout::Faces);
        assert_eq!(f.len(), 6);
        assert_eq!(f[4], "specular_mip0_top.exr");
        assert_eq!(
            irradiance_files(FaceLayout::Faces)[0],
            "irradiance_front.exr"
        );
    }

    #[test]
    fn manifest_names_must_be_plain() {
        let d = Path::new("/tmp/x");
        let m = Path::new("/tmp/x/prefilter.json");
        assert!(member(d, m, "a.exr").is_ok());
        for bad in ["../a.exr", "/etc/passwd", "sub/a.exr", "..", ""] {
            assert!(member(d, m, bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn options_reject_zero_sizes() {
        assert!(PrefilterOptions::default().validate().is_ok());
        let mut o = PrefilterOptions::default();
        o.specular.samples = 0;
        assert!(o.validate().is_err());
        let o = PrefilterOptions {
            sh_window: ShWindow::Hanning(f32::NAN),
            ..Default::default()
        };
        assert!(o.validate().is_err());
    }
}
