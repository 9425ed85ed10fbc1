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

/// Largest probe (in pixels) whose camera-response display copy is kept for
/// matching: 4M pixels, 48 MiB (with [`ProbeTonemap::Reinhard05`] the copy is
/// made at every size, as before). The faces of every rotation read each probe
/// pixel a dozen times (four bilinear taps, three channels, at up to twenty
/// faces), so encoding every pixel once is cheaper than encoding each sample;
/// the samples are the same either way (the same encoded values, interpolated
/// alike).
const DISPLAY_COPY_MAX_PX: usize = 1 << 22;

/// A probe ready for the warp method.
pub struct PreparedProbe {
    /// Its HDR radiance.
    pub image: Arc<HdrImage>,
    /// Its pose.
    pub pose: Pose,
    /// How it is tone-mapped for matching.
    mode: ProbeTonemap,
    /// The SDR camera's response and gain ([`ProbeTonemap::Camera`]).
    camera: Response,
    gain: f32,
    /// Display values in [0, 1], made on first use. With [`ProbeTonemap::Camera`]
    /// matching uses it only for probes of at most [`DISPLAY_COPY_MAX_PX`] pixels;
    /// for larger ones the response is applied to the samples taken (a full-size
    /// copy is as large as the probe itself, and the flow method does not match
    /// features at all).
    display: OnceLock<HdrImage>,
    /// Cache keyed by (yaw step, face index, face size).
    cache: Mutex<
        Vec<(
            (usize, usize, usize),
            Arc<OnceLock<std::result::Result<Arc<FaceFeatures>, String>>>,
        )>,
    >,
}

impl PreparedProbe {
    /// Prepares `image` for matching; `camera` gives the SDR response and gain used
    /// by [`ProbeTonemap::Camera`].
    pub fn new(
        image: Arc<HdrImage>,
        pose: Pose,
        mode: ProbeTonemap,
        camera: &Response,
        gain: f32,
    ) -> Self {
        PreparedProbe {
            image,
            pose,
            mode,
            camera: camera.clone(),
            gain,
            display: OnceLock::new(),
            cache: Mutex::new(Vec::new()),
        }
    }

    /// Display image used for matching (for inspection; made on first call).
    pub fn display(&self) -> &HdrImage {
        self.display.get_or_init(|| {
            let image = &self.image;
            let v = match self.mode {
                ProbeTonemap::Reinhard05 => Reinhard05::default().apply(image),
                ProbeTonemap::Camera => image
                    .data()
                    .iter()
                    .map(|&x| self.camera.encode(x * self.gain))
                    .collect(),
            };
            HdrImage::from_vec(image.width(), image.height(), v).expect("same size")
        })
    }

    /// 8-bit gray image of `face` (`n` pixels, extent `e`) of the display image,
    /// seen by a camera rotated by `rot`.
    fn gray(&self, face: CubeFace, n: usize, e: f32, rot: glam::Mat3) -> Vec<u8> {
        let (w, h) = (self.image.width(), self.image.height());
        if self.mode == ProbeTonemap::Camera && w * h > DISPLAY_COPY_MAX_PX {
            return self.gray_encoding_samples(face, n, e, rot);
        }
        let d = self.display().data();
        gray_face(w, h, face, n, e, rot, |i| {
            [d[3 * i], d[3 * i + 1], d[3 * i + 2]]
        })
    }

    /// [`Self::gray`] with the camera response applied to the samples taken,
    /// without a display copy.
    fn gray_encoding_samples(&self, face: CubeFace, n: usize, e: f32, rot: glam::Mat3) -> Vec<u8> {
        let (w, h) = (self.image.width(), self.image.height());
        let d = self.image.data();
        let enc = |v: f32| self.camera.encode(v * self.gain);
        gray_face(w, h, face, n, e, rot, |i| {
            [enc(d[3 * i]), enc(d[3 * i + 1]), enc(d[3 * i + 2])]
        })
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
            let gray = self.gray(face, n, p.face_extent.max(1.0), rot);
            cv::detect(&gray, n, n, &p.detect_params())
                .and_then(|f| {
                    MatchIndex::new(&f, p.flann_checks)
                        .map(|index| Arc::new(FaceFeatures { features: f, index }))
                })
                .map_err(|e| e.to_string())
        });
        match r {
            Ok(f) => Ok((f.clone(), computed)),
            Err(e) => Err(Error::opencv(e.clone())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sphere::FACES;
    use glam::{Mat3, Vec3};

    #[test]
    fn camera_faces_read_from_radiance_equal_those_of_the_display_image() {
        let (w, h) = (64, 32);
        let img = HdrImage::from_fn(w, h, |x, y| {
            let v = (x as f32 * 0.37).sin().abs() * 3.0 + (y as f32 * 0.21).cos().abs();
            [v, 0.5 * v, 0.1 * x as f32]
        });
        let pose = Pose {
            position: Vec3::ZERO,
            world_from_camera: Mat3::IDENTITY,
        };
        let resp = Response::Gamma { gamma: 2.2 };
        let pp = PreparedProbe::new(Arc::new(img), pose, ProbeTonemap::Camera, &resp, 0.7);
        let rot = ypr_to_mat(22.5, 0.0, 0.0);
        let d = pp.display().data();
        for face in FACES {
            let from_display = gray_face(w, h, face, 24, 1.2, rot, |i| {
                [d[3 * i], d[3 * i + 1], d[3 * i + 2]]
            });
            // Both paths: the display copy (a small probe) and the samples
            // encoded one by one (a probe too large for the copy).
            assert_eq!(pp.gray(face, 24, 1.2, rot), from_display);
            assert_eq!(pp.gray_encoding_samples(face, 24, 1.2, rot), from_display);
        }
    }
}
