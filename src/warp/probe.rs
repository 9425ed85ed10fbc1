//! A probe made ready for matching: tone-mapped once, with the features of each
//! rotation and face computed on first use and kept for every later frame.

use super::{gray_face, WarpParams};
use crate::cv::{self, Features, MatchIndex};
use crate::error::{Error, Result};
use crate::image::HdrImage;
use crate::scene::Pose;
use crate::sphere::{ypr_to_mat, CubeFace};
use crate::tonemap::{Reinhard05, Response};
use serde::{Deserialize, Serialize};
use std::sync::{Arc, Mutex, OnceLock};

/// How a probe is turned into an 8-bit image to match against SDR frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum ProbeTonemap {
    /// Reinhard & Devlin 2005 with its default parameters (the thesis's choice).
    Reinhard05,
    /// Through the SDR camera's own response and exposure, so the probe looks as the
    /// frame camera would have recorded it (needs a calibrated scene).
    Camera,
}

/// Features and their index for one probe face at one rotation.
pub struct FaceFeatures {
    /// Keypoints and descriptors.
    pub features: Features,
    /// Index over the descriptors.
    pub index: MatchIndex,
}

/// A probe ready for the warp method.
pub struct PreparedProbe {
    /// Its HDR radiance.
    pub image: Arc<HdrImage>,
    /// Its pose.
    pub pose: Pose,
    /// Display values in [0, 1] used for matching.
    display: HdrImage,
    /// Cache keyed by (yaw step, face index, face size).
    cache: Mutex<
        Vec<(
            (usize, usize, usize),
            Arc<OnceLock<std::result::Result<Arc<FaceFeatures>, String>>>,
        )>,
    >,
}

impl PreparedProbe {
    /// Tone-maps `image` for matching; `camera` gives the SDR response and gain used
    /// by [`ProbeTonemap::Camera`].
    pub fn new(
        image: Arc<HdrImage>,
        pose: Pose,
        mode: ProbeTonemap,
        camera: &Response,
        gain: f32,
    ) -> Self {
        let display = match mode {
            ProbeTonemap::Reinhard05 => {
                let v = Reinhard05::default().apply(&image);
                HdrImage::from_vec(image.width(), image.height(), v).expect("same size")
            }
            ProbeTonemap::Camera => {
                let v = image
                    .data()
                    .iter()
                    .map(|&x| camera.encode(x * gain))
                    .collect();
                HdrImage::from_vec(image.width(), image.height(), v).expect("same size")
            }
        };
        PreparedProbe {
            image,
            pose,
            display,
            cache: Mutex::new(Vec::new()),
        }
    }

    /// Display image used for matching (for inspection).
    pub fn display(&self) -> &HdrImage {
        &self.display
    }

    /// Features of `face` at rotation step `k`, computed on first use. The flag is
    /// true when this call computed them.
    pub fn face_features(
        &self,
        k: usize,
        face: CubeFace,
        n: usize,
        p: &WarpParams,
    ) -> Result<(Arc<FaceFeatures>, bool)> {
        let key = (k, face.index(), n);
        let cell = {
            let mut c = self
                .cache
                .lock()
                .map_err(|_| Error::Invalid("probe cache poisoned".into()))?;
            match c.iter().find(|(k2, _)| *k2 == key) {
                Some((_, cell)) => cell.clone(),
                None => {
                    let cell = Arc::new(OnceLock::new());
                    c.push((key, cell.clone()));
                    cell
                }
            }
        };
        let mut computed = false;
        let r = cell.get_or_init(|| {
            computed = true;
            let rot = ypr_to_mat(p.yaw_deg(k), 0.0, 0.0);
            let gray = gray_face(&self.display, face, n, p.face_extent.max(1.0), rot);
            cv::detect(&gray, n, n, &p.detect_params())
                .and_then(|f| {
                    MatchIndex::new(&f, p.flann_checks)
                        .map(|index| Arc::new(FaceFeatures { features: f, index }))
                })
                .map_err(|e| e.to_string())
        });
        match r {
            Ok(f) => Ok((f.clone(), computed)),
            Err(e) => Err(Error::OpenCv(e.clone())),
        }
    }
}
