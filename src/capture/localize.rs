//! Localization of panoramas with COLMAP (Debian's `colmap`, CPU only): where each
//! frame and probe was taken and how it was turned, when no poses are given.
//!
//! **Method.** Each equirect panorama (SDR frames as recorded, probes as an 8-bit
//! image) is cut into `views` pinhole views around the horizon (90° field of view
//! by default, so neighbouring views overlap), all with one known pinhole camera.
//! COLMAP extracts SIFT features, matches a bounded list of view pairs (views of
//! frames close in the walk, and of every probe with every `probe_stride`-th frame;
//! matching all pairs costs half an hour on two cores), and maps. A panorama's
//! pose follows from each of its registered views: its centre is the median of
//! the views' centres, its rotation the chordal mean of the rotations the views
//! imply (view `k` is the panorama turned by a known yaw). COLMAP's frame of
//! reference is arbitrary up to a similarity (scale included); [`align_similarity`]
//! aligns it to reference poses for evaluation.
//!
//! **Failures.** A frame none of whose views registered takes a pose from its
//! neighbours in walk order (position interpolated, rotation of the nearer one)
//! and is marked `interpolated`; a probe that did not register is reported and
//! left without a pose. Nothing is silently wrong: every pose says where it came
//! from.

use crate::error::{Error, Result};
use crate::image::{io, HdrImage, SdrImage};
use crate::scene::Pose;
use crate::sphere::{orthonormalize, sample_dir};
use glam::{Mat3, Quat, Vec3};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Settings of [`localize`].
#[derive(Clone, Debug)]
pub struct LocalizeOptions {
    /// Pinhole views per panorama, evenly spaced in yaw.
    pub views: usize,
    /// Side of each square view in pixels.
    pub view_size: usize,
    /// Horizontal (and vertical) field of view of a view, degrees.
    pub fov_deg: f32,
    /// Most SIFT features per view.
    pub max_features: usize,
    /// Frames `i + 1 ..= i + frame_window` are matched with frame `i`.
    pub frame_window: usize,
    /// Every probe is matched with every `probe_stride`-th frame.
    pub probe_stride: usize,
    /// The COLMAP executable.
    pub colmap: PathBuf,
    /// Read the model already in the working folder instead of running COLMAP
    /// (to re-derive poses with other settings).
    pub reuse_model: bool,
}

impl Default for LocalizeOptions {
    fn default() -> Self {
        LocalizeOptions {
            views: 8,
            view_size: 256,
            fov_deg: 120.0,
            max_features: 2048,
            frame_window: 2,
            probe_stride: 2,
            colmap: PathBuf::from("colmap"),
            reuse_model: false,
        }
    }
}

/// A panorama to localize.
pub struct Panorama {
    /// Identifier (frame or probe id); used in view file names.
    pub id: String,
    /// Whether it is a probe (otherwise a frame of the walk, in walk order).
    pub is_probe: bool,
    /// The 8-bit equirect image.
    pub image: SdrImage,
}

/// The bracket to show the feature matcher for a probe: the one whose mean code is
/// nearest mid-grey (110), so that the probe looks most like the walk's frames.
/// `None` for an empty list.
pub fn mid_grey_bracket(files: &[&Path]) -> Result<Option<SdrImage>> {
    let mut best: Option<(f64, SdrImage)> = None;
    for f in files {
        let img = crate::image::io::read_sdr(f)?;
        let n = img.data().len().max(1) as f64;
        let mean = img.data().iter().map(|&c| c as f64).sum::<f64>() / n;
        let d = (mean - 110.0).abs();
        if best.as_ref().is_none_or(|(bd, _)| d < *bd) {
            best = Some((d, img));
        }
    }
    Ok(best.map(|(_, img)| img))
}

/// Where a pose came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PoseSource {
    /// From its registered views.
    Registered,
    /// Interpolated from its neighbours in the walk (no view registered).
    Interpolated,
    /// Not localized.
    Missing,
}

/// The localization of one panorama, in COLMAP's frame of reference.
#[derive(Clone, Debug)]
pub struct Localized {
    /// Panorama id.
    pub id: String,
    /// Whether it is a probe.
    pub is_probe: bool,
    /// The pose, unless missing.
    pub pose: Option<Pose>,
    /// Views of it that COLMAP registered.
    pub views_registered: usize,
    /// Where the pose came from.
    pub source: PoseSource,
}

/// Rotation taking view `k`'s camera axes (x right, y up, -z forward) to the
/// panorama's: a turn to the right by `k * 360° / views` about y.
pub fn view_rotation(k: usize, views: usize) -> Mat3 {
    let psi = (k as f32) * std::f32::consts::TAU / views.max(1) as f32;
    Mat3::from_rotation_y(-psi)
}

/// Cuts pinhole view `k` out of a panorama (bilinear on the codes).
pub fn cut_view(pano: &SdrImage, k: usize, opts: &LocalizeOptions) -> SdrImage {
    let n = opts.view_size.max(8);
    let f = focal_px(opts);
    let codes = HdrImage::from_fn(pano.width(), pano.height(), |x, y| {
        pano.get(x, y).map(|c| c as f32)
    });
    let r = view_rotation(k, opts.views);
    let c = n as f32 / 2.0;
    let mut data = vec![0u8; n * n * 3];
    for j in 0..n {
        for i in 0..n {
            let d = Vec3::new((i as f32 + 0.5 - c) / f, -(j as f32 + 0.5 - c) / f, -1.0);
            let v = sample_dir(&codes, r * d);
            for ch in 0..3 {
                data[3 * (j * n + i) + ch] = v[ch].round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    SdrImage::from_vec(n, n, data).expect("size matches")
}

/// Focal length of the views in pixels.
pub fn focal_px(opts: &LocalizeOptions) -> f32 {
    opts.view_size.max(8) as f32 / 2.0 / (opts.fov_deg.to_radians() / 2.0).tan()
}

fn view_name(id: &str, k: usize) -> String {
    format!("{id}__v{k}.png")
}

/// The view pairs COLMAP matches (see the module docs).
pub fn match_pairs(panos: &[Panorama], opts: &LocalizeOptions) -> Vec<(String, String)> {
    let frames: Vec<&Panorama> = panos.iter().filter(|p| !p.is_probe).collect();
    let probes: Vec<&Panorama> = panos.iter().filter(|p| p.is_probe).collect();
    let mut pairs = Vec::new();
    let all = |a: &Panorama, b: &Panorama, pairs: &mut Vec<(String, String)>| {
        for i in 0..opts.views {
            for j in 0..opts.views {
                pairs.push((view_name(&a.id, i), view_name(&b.id, j)));
            }
        }
    };
    // Neighbouring views of one panorama share a centre: no triangulation, but
    // their common features let COLMAP register the rest of a panorama once one
    // view is in.
    for p in panos {
        for k in 0..opts.views {
            pairs.push((view_name(&p.id, k), view_name(&p.id, (k + 1) % opts.views)));
        }
    }
    for (i, a) in frames.iter().enumerate() {
        for b in frames.iter().skip(i + 1).take(opts.frame_window) {
            all(a, b, &mut pairs);
        }
    }
    for p in &probes {
        for f in frames.iter().step_by(opts.probe_stride.max(1)) {
            all(p, f, &mut pairs);
        }
    }
    pairs
}

fn run(cmd: &mut Command, what: &str, log: &Path) -> Result<()> {
    let out = cmd.output().map_err(|e| {
        Error::External {
            tool: "COLMAP",
            msg: format!(
                "could not start it for {what} ({e}); install it (apt-get install colmap) or give poses"
            ),
        }
    })?;
    let mut text = out.stdout.clone();
    text.extend_from_slice(&out.stderr);
    crate::fsutil::write_atomic(log, &text)?;
    if !out.status.success() {
        return Err(Error::External {
            tool: "COLMAP",
            msg: format!("{what} failed ({}); see {}", out.status, log.display()),
        });
    }
    Ok(())
}

/// One registered image of a COLMAP text model: world-to-camera rotation and
/// translation (COLMAP camera axes: x right, y down, z forward) and its name.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    /// Rotation world -> camera.
    pub r_cw: Mat3,
    /// Translation world -> camera.
    pub t_cw: Vec3,
    /// Image file name.
    pub name: String,
}

/// Parses COLMAP's `images.txt` (every other line is a list of 2-D points).
pub fn parse_images_txt(text: &str, file: &Path) -> Result<Vec<ColmapImage>> {
    let mut out = Vec::new();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    while let Some(l) = lines.next() {
        if l.trim().is_empty() {
            continue;
        }
        let t: Vec<&str> = l.split_whitespace().collect();
        if t.len() < 10 {
            return Err(Error::format(file, format!("bad image line {l:?}")));
        }
        let num = |i: usize| -> Result<f32> {
            t[i].parse::<f32>()
                .map_err(|_| Error::format(file, format!("bad number {:?} in {l:?}", t[i])))
        };
        let q = Quat::from_xyzw(num(2)?, num(3)?, num(4)?, num(1)?);
        if !q.is_finite() || q.length() < 1e-6 {
            return Err(Error::format(file, format!("bad rotation in {l:?}")));
        }
        out.push(ColmapImage {
            r_cw: Mat3::from_quat(q.normalize()),
            t_cw: Vec3::new(num(5)?, num(6)?, num(7)?),
            name: t[9..].join(" "),
        });
        let _points = lines.next();
    }
    Ok(out)
}

/// Largest disagreement, in degrees, between the rotations two views of one
/// panorama imply for it, for both to count.
pub const CONSENSUS_DEG: f32 = 5.0;

/// Panorama poses from registered views (see the module docs): `views[i]` is the
/// index of the view and its COLMAP image.
pub fn pano_pose(views: &[(usize, &ColmapImage)], n_views: usize) -> Option<Pose> {
    if views.is_empty() {
        return None;
    }
    // COLMAP camera axes to ours: y and z flip.
    let s = Mat3::from_diagonal(Vec3::new(1.0, -1.0, -1.0));
    let rots: Vec<Mat3> = views
        .iter()
        .map(|&(k, im)| im.r_cw.transpose() * s * view_rotation(k, n_views).transpose())
        .collect();
    // Views registered wrongly (a repeated texture, a weak match) disagree with
    // the others; keep the largest group that agrees within CONSENSUS_DEG.
    let angle = |a: &Mat3, b: &Mat3| {
        let m = a.transpose() * *b;
        ((m.x_axis.x + m.y_axis.y + m.z_axis.z - 1.0) / 2.0)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees()
    };
    let support = |i: usize| {
        rots.iter()
            .filter(|r| angle(&rots[i], r) <= CONSENSUS_DEG)
            .count()
    };
    let best = (0..rots.len()).max_by_key(|&i| support(i))?;
    let mut sum = Mat3::ZERO;
    let mut centres: [Vec<f32>; 3] = Default::default();
    for (i, &(_, im)) in views.iter().enumerate() {
        if angle(&rots[best], &rots[i]) > CONSENSUS_DEG {
            continue;
        }
        sum += rots[i];
        let c = -(im.r_cw.transpose() * im.t_cw);
        for a in 0..3 {
            centres[a].push(c[a]);
        }
    }
    let med = |v: &mut Vec<f32>| {
        v.sort_by(f32::total_cmp);
        v[v.len() / 2]
    };
    let pos = Vec3::new(
        med(&mut centres[0]),
        med(&mut centres[1]),
        med(&mut centres[2]),
    );
    Some(Pose {
        position: pos,
        world_from_camera: orthonormalize(sum)?,
    })
}

/// Localizes `panos` with COLMAP in the working folder `work` (views, database,
/// model and logs are kept there). Frames must be given in walk order.
pub fn localize(panos: &[Panorama], work: &Path, opts: &LocalizeOptions) -> Result<Vec<Localized>> {
    if opts.views < 3 || opts.view_size < 32 || !(30.0..=150.0).contains(&opts.fov_deg) {
        return Err(Error::Invalid(
            "localization needs at least 3 views of at least 32 px, field of view 30..150 degrees"
                .into(),
        ));
    }
    let images = work.join("images");
    std::fs::create_dir_all(&images).map_err(|e| Error::io(&images, e))?;
    {
        use rayon::prelude::*;
        panos
            .par_iter()
            .map(|p| -> Result<()> {
                for k in 0..opts.views {
                    let path = images.join(view_name(&p.id, k));
                    if !path.exists() {
                        io::write_sdr(&path, &cut_view(&p.image, k, opts))?;
                    }
                }
                Ok(())
            })
            .collect::<Result<Vec<()>>>()?;
    }
    let existing = work.join("model").join("images.txt");
    if opts.reuse_model && existing.exists() {
        let text = std::fs::read_to_string(&existing).map_err(|e| Error::io(&existing, e))?;
        return Ok(assemble(
            panos,
            &parse_images_txt(&text, &existing)?,
            opts.views,
        ));
    }
    let db = work.join("database.db");
    if db.exists() {
        std::fs::remove_file(&db).map_err(|e| Error::io(&db, e))?;
    }
    let f = focal_px(opts);
    let c = opts.view_size as f32 / 2.0;
    let colmap = || Command::new(&opts.colmap);
    run(
        colmap()
            .arg("feature_extractor")
            .arg("--database_path")
            .arg(&db)
            .arg("--image_path")
            .arg(&images)
            .args(["--ImageReader.single_camera", "1"])
            .args(["--ImageReader.camera_model", "PINHOLE"])
            .arg("--ImageReader.camera_params")
            .arg(format!("{f},{f},{c},{c}"))
            .args(["--SiftExtraction.use_gpu", "0"])
            .arg("--SiftExtraction.max_num_features")
            .arg(opts.max_features.to_string())
            // Domain-size pooling: descriptors that survive the blur and noise
            // of views cut from low-resolution panoramas.
            .args(["--SiftExtraction.domain_size_pooling", "1"]),
        "feature extraction",
        &work.join("features.log"),
    )?;
    let pairs = match_pairs(panos, opts);
    let list: String = pairs.iter().map(|(a, b)| format!("{a} {b}\n")).collect();
    let pairs_file = work.join("pairs.txt");
    crate::fsutil::write_atomic(&pairs_file, list.as_bytes())?;
    run(
        colmap()
            .arg("matches_importer")
            .arg("--database_path")
            .arg(&db)
            .arg("--match_list_path")
            .arg(&pairs_file)
            .args(["--match_type", "pairs"])
            .args(["--SiftMatching.use_gpu", "0"])
            .args(["--SiftMatching.guided_matching", "1"]),
        "matching",
        &work.join("matching.log"),
    )?;
    let sparse = work.join("sparse");
    if sparse.exists() {
        std::fs::remove_dir_all(&sparse).map_err(|e| Error::io(&sparse, e))?;
    }
    std::fs::create_dir_all(&sparse).map_err(|e| Error::io(&sparse, e))?;
    run(
        colmap()
            .arg("mapper")
            .arg("--database_path")
            .arg(&db)
            .arg("--image_path")
            .arg(&images)
            .arg("--output_path")
            .arg(&sparse)
            .args(["--Mapper.ba_refine_focal_length", "0"])
            .args(["--Mapper.ba_refine_extra_params", "0"])
            .args(["--Mapper.multiple_models", "0"])
            // Panoramas of a walk are close together and low in resolution: allow
            // weaker initial pairs and registrations than COLMAP's defaults.
            .args(["--Mapper.init_min_num_inliers", "30"])
            .args(["--Mapper.init_min_tri_angle", "2"])
            .args(["--Mapper.abs_pose_min_num_inliers", "10"])
            .args(["--Mapper.abs_pose_min_inlier_ratio", "0.1"])
            .args(["--Mapper.min_num_matches", "10"]),
        "mapping",
        &work.join("mapper.log"),
    )?;
    let model = sparse.join("0");
    if !model.is_dir() {
        return Err(Error::External {
            tool: "COLMAP",
            msg: format!(
                "built no model (too few matches between the views); see {}",
                work.join("mapper.log").display()
            ),
        });
    }
    let txt = work.join("model");
    std::fs::create_dir_all(&txt).map_err(|e| Error::io(&txt, e))?;
    run(
        colmap()
            .arg("model_converter")
            .arg("--input_path")
            .arg(&model)
            .arg("--output_path")
            .arg(&txt)
            .args(["--output_type", "TXT"]),
        "model conversion",
        &work.join("convert.log"),
    )?;
    let file = txt.join("images.txt");
    let text = std::fs::read_to_string(&file).map_err(|e| Error::io(&file, e))?;
    let registered = parse_images_txt(&text, &file)?;
    Ok(assemble(panos, &registered, opts.views))
}

/// Panorama poses from registered views, with frames that did not register
/// interpolated from their neighbours in walk order.
pub fn assemble(panos: &[Panorama], registered: &[ColmapImage], n_views: usize) -> Vec<Localized> {
    let mut out: Vec<Localized> = panos
        .iter()
        .map(|p| {
            let views: Vec<(usize, &ColmapImage)> = (0..n_views)
                .filter_map(|k| {
                    let name = view_name(&p.id, k);
                    registered
                        .iter()
                        .find(|im| im.name == name)
                        .map(|im| (k, im))
                })
                .collect();
            let pose = pano_pose(&views, n_views);
            Localized {
                id: p.id.clone(),
                is_probe: p.is_probe,
                views_registered: views.len(),
                source: if pose.is_some() {
                    PoseSource::Registered
                } else {
                    PoseSource::Missing
                },
                pose,
            }
        })
        .collect();
    let frames: Vec<usize> = (0..out.len()).filter(|&i| !out[i].is_probe).collect();
    for (n, &i) in frames.iter().enumerate() {
        if out[i].pose.is_some() {
            continue;
        }
        let before = frames[..n]
            .iter()
            .rev()
            .find(|&&j| out[j].source == PoseSource::Registered)
            .copied();
        let after = frames[n + 1..]
            .iter()
            .find(|&&j| out[j].source == PoseSource::Registered)
            .copied();
        let pose = match (before, after) {
            (Some(a), Some(b)) => {
                let (pa, pb) = (
                    out[a].pose.expect("registered"),
                    out[b].pose.expect("registered"),
                );
                let ia = frames.iter().position(|&x| x == a).unwrap_or(0) as f32;
                let ib = frames.iter().position(|&x| x == b).unwrap_or(0) as f32;
                let t = (n as f32 - ia) / (ib - ia).max(1.0);
                Some(Pose {
                    position: pa.position.lerp(pb.position, t),
                    world_from_camera: if t < 0.5 {
                        pa.world_from_camera
                    } else {
                        pb.world_from_camera
                    },
                })
            }
            (Some(a), None) => out[a].pose,
            (None, Some(b)) => out[b].pose,
            (None, None) => None,
        };
        if pose.is_some() {
            out[i].pose = pose;
            out[i].source = PoseSource::Interpolated;
        }
    }
    out
}

/// The similarity `x -> s R x + t` that best maps `from` onto `to` in least squares
/// (rotation by Horn 1987, scale and translation as in Umeyama 1991). Needs at
/// least three points not on a line.
pub fn align_similarity(from: &[Vec3], to: &[Vec3]) -> Option<(f32, Mat3, Vec3)> {
    let n = from.len();
    if n < 3 || to.len() != n {
        return None;
    }
    let mu_a = from.iter().copied().sum::<Vec3>() / n as f32;
    let mu_b = to.iter().copied().sum::<Vec3>() / n as f32;
    // Horn's quaternion method: the rotation is the eigenvector of the largest
    // eigenvalue of a symmetric 4x4 matrix built from the cross-covariance. Unlike
    // a polar decomposition it copes with coplanar points (a walk at one height).
    let mut m = [[0.0f64; 3]; 3];
    let mut var_a = 0.0f64;
    for (a, b) in from.iter().zip(to) {
        let (da, db) = ((*a - mu_a).as_dvec3(), (*b - mu_b).as_dvec3());
        let (da, db) = (da.to_array(), db.to_array());
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += da[i] * db[j];
            }
        }
        var_a += da.iter().map(|v| v * v).sum::<f64>();
    }
    if var_a <= 0.0 || !var_a.is_finite() {
        return None;
    }
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = m;
    let nm = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let q = top_eigenvector(nm);
    let rot = Mat3::from_quat(
        Quat::from_xyzw(q[1] as f32, q[2] as f32, q[3] as f32, q[0] as f32).normalize(),
    );
    // Scale: sum of b . (R a) over sum of |a|^2.
    let mut num = 0.0f64;
    for (a, b) in from.iter().zip(to) {
        num += ((*b - mu_b).dot(rot * (*a - mu_a))) as f64;
    }
    let s = (num / var_a) as f32;
    if !(s.is_finite() && s > 0.0) {
        return None;
    }
    let t = mu_b - s * (rot * mu_a);
    Some((s, rot, t))
}

/// Eigenvector of the largest eigenvalue of a symmetric 4x4 matrix (cyclic Jacobi
/// rotations; exact to rounding in a few sweeps).
fn top_eigenvector(mut a: [[f64; 4]; 4]) -> [f64; 4] {
    let mut v = [[0.0f64; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _ in 0..50 {
        let off: f64 = (0..4)
            .flat_map(|i| (0..4).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        if off < 1e-24 {
            break;
        }
        for p in 0..3 {
            for q in p + 1..4 {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..4 {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..4 {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    let best = (0..4)
        .max_by(|&i, &j| a[i][i].total_cmp(&a[j][j]))
        .unwrap_or(0);
    [v[0][best], v[1][best], v[2][best], v[3][best]]
}

/// Position and rotation errors of localized poses against reference poses by id,
/// after the similarity that best aligns the localized positions.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PoseErrors {
    /// Panoramas compared (those with a pose and a reference).
    pub compared: usize,
    /// Panoramas with a registered (not interpolated) pose.
    pub registered: usize,
    /// Panoramas with an interpolated pose.
    pub interpolated: usize,
    /// Panoramas without a pose.
    pub missing: usize,
    /// Median and largest position error, metres.
    pub median_pos_m: f32,
    /// Largest position error, metres.
    pub max_pos_m: f32,
    /// Median rotation error, degrees, after the rotation that best aligns the
    /// orientations (their chordal mean). The positions' similarity cannot fix
    /// the rotation well for a walk that keeps one height: a tilt about the walk's
    /// line costs no position error and would show as a rotation error of every
    /// panorama.
    pub median_rot_deg: f32,
    /// Largest rotation error, degrees (as `median_rot_deg`).
    pub max_rot_deg: f32,
    /// Median error of the relative rotation between every pair of panoramas,
    /// degrees: free of any alignment, and what the methods use (a frame's
    /// orientation relative to its probes).
    pub median_rel_rot_deg: f32,
    /// Scale of the alignment (metres per COLMAP unit).
    pub scale: f32,
}

/// Compares localized poses with reference poses (`(id, pose)`); see [`PoseErrors`].
pub fn pose_errors(
    est: &[Localized],
    reference: &[(String, Pose)],
) -> Option<(PoseErrors, (f32, Mat3, Vec3))> {
    let pairs: Vec<(&Localized, &Pose)> = est
        .iter()
        .filter_map(|e| {
            let r = reference.iter().find(|(id, _)| *id == e.id)?;
            e.pose.as_ref().map(|_| (e, &r.1))
        })
        .collect();
    let reg: Vec<&(&Localized, &Pose)> = pairs
        .iter()
        .filter(|(e, _)| e.source == PoseSource::Registered)
        .collect();
    let from: Vec<Vec3> = reg.iter().map(|(e, _)| e.pose.unwrap().position).collect();
    let to: Vec<Vec3> = reg.iter().map(|(_, r)| r.position).collect();
    let (s, rot, t) = align_similarity(&from, &to)?;
    let angle = |m: Mat3| {
        let c = ((m.x_axis.x + m.y_axis.y + m.z_axis.z - 1.0) / 2.0).clamp(-1.0, 1.0);
        c.acos().to_degrees()
    };
    // Orientation alignment: the rotation nearest the sum of ref * est^T.
    let sum = pairs.iter().fold(Mat3::ZERO, |acc, (e, r)| {
        acc + r.world_from_camera * e.pose.unwrap().world_from_camera.transpose()
    });
    let rot_align = orthonormalize(sum).unwrap_or(rot);
    let mut pos: Vec<f32> = Vec::new();
    let mut ang: Vec<f32> = Vec::new();
    for (e, r) in &pairs {
        let p = e.pose.unwrap();
        pos.push((s * (rot * p.position) + t).distance(r.position));
        ang.push(angle(
            r.world_from_camera.transpose() * rot_align * p.world_from_camera,
        ));
    }
    let mut rel: Vec<f32> = Vec::new();
    for (i, (ei, ri)) in pairs.iter().enumerate() {
        for (ej, rj) in &pairs[i + 1..] {
            let est =
                ei.pose.unwrap().world_from_camera.transpose() * ej.pose.unwrap().world_from_camera;
            let truth = ri.world_from_camera.transpose() * rj.world_from_camera;
            rel.push(angle(truth.transpose() * est));
        }
    }
    if rel.is_empty() {
        rel.push(0.0);
    }
    let med = |v: &mut Vec<f32>| {
        v.sort_by(f32::total_cmp);
        v[v.len() / 2]
    };
    let max = |v: &[f32]| v.iter().cloned().fold(0.0f32, f32::max);
    let (mp, mr) = (max(&pos), max(&ang));
    Some((
        PoseErrors {
            compared: pairs.len(),
            registered: est
                .iter()
                .filter(|e| e.source == PoseSource::Registered)
                .count(),
            interpolated: est
                .iter()
                .filter(|e| e.source == PoseSource::Interpolated)
                .count(),
            missing: est
                .iter()
                .filter(|e| e.source == PoseSource::Missing)
                .count(),
            median_pos_m: med(&mut pos),
            max_pos_m: mp,
            median_rot_deg: med(&mut ang),
            max_rot_deg: mr,
            median_rel_rot_deg: med(&mut rel),
            scale: s,
        },
        (s, rot, t),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_errors_do_not_depend_on_the_frame_of_reference() {
        // A straight walk at one height, in the world; the "estimate" is the same
        // walk seen through a similarity (scale 2.5, a turn, a shift).
        let reference: Vec<(String, Pose)> = (0..6)
            .map(|i| {
                let pose = Pose {
                    position: Vec3::new(0.5 * i as f32, 0.0, 1.5),
                    world_from_camera: Mat3::from_rotation_z(0.3 * i as f32),
                };
                (format!("p{i}"), pose)
            })
            .collect();
        let g = Mat3::from_euler(glam::EulerRot::XYZ, 0.4, -0.2, 1.1);
        let estimate = |tilt_one: f32| -> Vec<Localized> {
            let shift = Vec3::new(3.0, -1.0, 0.5);
            reference
                .iter()
                .enumerate()
                .map(|(i, (id, r))| {
                    let extra = if i == 2 {
                        Mat3::from_rotation_x(tilt_one)
                    } else {
                        Mat3::IDENTITY
                    };
                    Localized {
                        id: id.clone(),
                        is_probe: i == 0,
                        pose: Some(Pose {
                            position: g.transpose() * (r.position * 2.5) + shift,
                            world_from_camera: g.transpose() * r.world_from_camera * extra,
                        }),
                        views_registered: 8,
                        source: PoseSource::Registered,
                    }
                })
                .collect()
        };
        let (e, _) = pose_errors(&estimate(0.0), &reference).unwrap();
        assert!(e.max_pos_m < 1e-3, "{e:?}");
        assert!(e.max_rot_deg < 0.05 && e.median_rel_rot_deg < 0.05, "{e:?}");
        assert!((e.scale - 0.4).abs() < 1e-3, "{e:?}");
        // One panorama turned by 6 degrees: it shows as that panorama's error, and
        // most pairs' relative rotations stay exact.
        let (e, _) = pose_errors(&estimate(6f32.to_radians()), &reference).unwrap();
        assert!(e.max_rot_deg > 4.0 && e.max_rot_deg < 6.5, "{e:?}");
        assert!(e.median_rot_deg < 1.5, "{e:?}");
        assert!(e.median_rel_rot_deg < 0.05, "{e:?}");
    }

    #[test]
    fn view_zero_looks_forward_and_view_rotations_turn_right() {
        assert!(view_rotation(0, 6).abs_diff_eq(Mat3::IDENTITY, 1e-6));
        let r = view_rotation(1, 4);
        assert!((r * Vec3::NEG_Z).abs_diff_eq(Vec3::X, 1e-6));
    }

    #[test]
    fn similarity_alignment_recovers_a_known_transform() {
        let pts: Vec<Vec3> = (0..8)
            .map(|i| {
                Vec3::new(
                    (i as f32).sin() * 3.0,
                    (i as f32 * 0.7).cos(),
                    i as f32 * 0.3,
                )
            })
            .collect();
        let r = Mat3::from_rotation_z(0.4) * Mat3::from_rotation_x(-0.3);
        let (s, t) = (2.5, Vec3::new(1.0, -2.0, 0.5));
        let moved: Vec<Vec3> = pts.iter().map(|p| s * (r * *p) + t).collect();
        let (s2, r2, t2) = align_similarity(&pts, &moved).unwrap();
        assert!((s2 - s).abs() < 1e-3, "{s2}");
        assert!(r2.abs_diff_eq(r, 1e-3));
        assert!(t2.abs_diff_eq(t, 1e-3));
        assert!(align_similarity(&pts[..2], &moved[..2]).is_none());
        // Coplanar points (a walk at one height) align as well.
        let flat: Vec<Vec3> = pts.iter().map(|p| Vec3::new(p.x, p.y, 1.5)).collect();
        let moved: Vec<Vec3> = flat.iter().map(|p| s * (r * *p) + t).collect();
        let (s3, r3, t3) = align_similarity(&flat, &moved).unwrap();
        assert!(
            (s3 - s).abs() < 1e-3 && r3.abs_diff_eq(r, 1e-3) && t3.abs_diff_eq(t, 1e-3),
            "{s3} {r3} {r} {t3}"
        );
    }

    #[test]
    fn a_panorama_pose_follows_from_its_views() {
        // A panorama at c with world_from_camera w; its view k seen by COLMAP has
        // r_cw = S R_k^T w^T (S flips y, z) and t = -r_cw c.
        let w = Mat3::from_rotation_y(0.3) * Mat3::from_rotation_x(0.1);
        let c = Vec3::new(1.0, 2.0, -0.5);
        let s = Mat3::from_diagonal(Vec3::new(1.0, -1.0, -1.0));
        let ims: Vec<ColmapImage> = (0..6)
            .map(|k| {
                let r_cw = s * view_rotation(k, 6).transpose() * w.transpose();
                ColmapImage {
                    r_cw,
                    t_cw: -(r_cw * c),
                    name: view_name("p", k),
                }
            })
            .collect();
        let views: Vec<(usize, &ColmapImage)> = ims.iter().enumerate().skip(2).collect();
        let p = pano_pose(&views, 6).unwrap();
        assert!(p.position.abs_diff_eq(c, 1e-4));
        assert!(p.world_from_camera.abs_diff_eq(w, 1e-4));
        // A view registered 90 degrees off (and elsewhere) does not move the pose.
        let mut bad = ims[2].clone();
        bad.r_cw = bad.r_cw * Mat3::from_rotation_z(1.5);
        bad.t_cw = Vec3::new(9.0, 9.0, 9.0);
        let mut views: Vec<(usize, &ColmapImage)> = ims.iter().enumerate().skip(3).collect();
        views.push((2, &bad));
        let p = pano_pose(&views, 6).unwrap();
        assert!(p.world_from_camera.abs_diff_eq(w, 1e-4));
        assert!(p.position.abs_diff_eq(c, 1e-4));
    }

    #[test]
    fn images_txt_parses_and_bad_lines_are_errors() {
        let text = "# comment\n1 1 0 0 0 0.5 0 0 1 f__v0.png\n1 2 3\n2 0.7071068 0 0.7071068 0 0 0 1 1 f__v1.png\n\n";
        let v = parse_images_txt(text, Path::new("images.txt")).unwrap();
        assert_eq!(v.len(), 2);
        assert_eq!(v[0].name, "f__v0.png");
        assert!((v[1].r_cw * Vec3::X).abs_diff_eq(Vec3::NEG_Z, 1e-5));
        assert!(parse_images_txt("1 x 0 0 0 0 0 0 1 a.png\n", Path::new("i.txt")).is_err());
    }

    #[test]
    fn frames_without_views_are_interpolated_and_probes_reported() {
        let img = SdrImage::new(16, 8);
        let panos: Vec<Panorama> = ["f0", "f1", "f2", "p0"]
            .iter()
            .map(|id| Panorama {
                id: id.to_string(),
                is_probe: id.starts_with('p'),
                image: img.clone(),
            })
            .collect();
        let s = Mat3::from_diagonal(Vec3::new(1.0, -1.0, -1.0));
        let at = |c: Vec3, name: &str| ColmapImage {
            r_cw: s,
            t_cw: -(s * c),
            name: name.to_string(),
        };
        let reg = vec![
            at(Vec3::ZERO, &view_name("f0", 0)),
            at(Vec3::new(2.0, 0.0, 0.0), &view_name("f2", 0)),
        ];
        let out = assemble(&panos, &reg, 6);
        assert_eq!(out[1].source, PoseSource::Interpolated);
        assert!(out[1]
            .pose
            .unwrap()
            .position
            .abs_diff_eq(Vec3::new(1.0, 0.0, 0.0), 1e-5));
        assert_eq!(out[3].source, PoseSource::Missing);
        assert!(out[3].pose.is_none());
    }
}
