//! Cube-map faces of a panorama: which direction each face pixel looks along.
//!
//! A face is the plane one unit in front of the camera along its normal `N`, with
//! image axes `R` (right) and `D` (down): face coordinates `(a, b)` in `[-1, 1]`
//! look along `N + a R + b D`. The four side faces share the panorama's up axis
//! and the top face's bottom edge joins the front face's top edge, the bottom
//! face's top edge joins the front face's bottom edge.

use super::{dir_to_uv, pixel_to_dir, sample_dir};
use crate::image::HdrImage;
use glam::{Mat3, Vec3};

/// One of the six faces of a cube map, in camera axes.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum CubeFace {
    /// Looks along -z (the panorama centre).
    Front,
    /// Looks along +x.
    Right,
    /// Looks along +z.
    Back,
    /// Looks along -x.
    Left,
    /// Looks along +y.
    Top,
    /// Looks along -y.
    Bottom,
}

/// All faces in a fixed order (sides first, then top and bottom).
pub const FACES: [CubeFace; 6] = [
    CubeFace::Front,
    CubeFace::Right,
    CubeFace::Back,
    CubeFace::Left,
    CubeFace::Top,
    CubeFace::Bottom,
];

impl CubeFace {
    /// Normal, right and down axes of the face.
    #[inline]
    pub fn basis(self) -> (Vec3, Vec3, Vec3) {
        match self {
            CubeFace::Front => (Vec3::NEG_Z, Vec3::X, Vec3::NEG_Y),
            CubeFace::Right => (Vec3::X, Vec3::Z, Vec3::NEG_Y),
            CubeFace::Back => (Vec3::Z, Vec3::NEG_X, Vec3::NEG_Y),
            CubeFace::Left => (Vec3::NEG_X, Vec3::NEG_Z, Vec3::NEG_Y),
            CubeFace::Top => (Vec3::Y, Vec3::X, Vec3::NEG_Z),
            CubeFace::Bottom => (Vec3::NEG_Y, Vec3::X, Vec3::Z),
        }
    }

    /// Index in [`FACES`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// True for the four faces around the horizon.
    pub fn is_side(self) -> bool {
        !matches!(self, CubeFace::Top | CubeFace::Bottom)
    }

    /// Lower-case name, as used in reports and file names.
    pub fn name(self) -> &'static str {
        match self {
            CubeFace::Front => "front",
            CubeFace::Right => "right",
            CubeFace::Back => "back",
            CubeFace::Left => "left",
            CubeFace::Top => "top",
            CubeFace::Bottom => "bottom",
        }
    }

    /// Direction (not normalised) of face coordinates `(a, b)`.
    #[inline]
    pub fn dir(self, a: f32, b: f32) -> Vec3 {
        let (n, r, d) = self.basis();
        n + r * a + d * b
    }

    /// Face coordinates `(a, b)` where the ray along `d` meets this face's plane, or
    /// `None` when `d` points away from it. `(a, b)` may lie outside `[-1, 1]`.
    #[inline]
    pub fn project(self, d: Vec3) -> Option<(f32, f32)> {
        let (n, r, dn) = self.basis();
        let s = d.dot(n);
        if s <= 1e-9 {
            return None;
        }
        Some((d.dot(r) / s, d.dot(dn) / s))
    }

    /// The face a direction falls on (largest axis) and its coordinates there.
    #[inline]
    pub fn of_dir(d: Vec3) -> (CubeFace, f32, f32) {
        let (ax, ay, az) = (d.x.abs(), d.y.abs(), d.z.abs());
        let face = if ax >= ay && ax >= az {
            if d.x > 0.0 {
                CubeFace::Right
            } else {
                CubeFace::Left
            }
        } else if ay >= az {
            if d.y > 0.0 {
                CubeFace::Top
            } else {
                CubeFace::Bottom
            }
        } else if d.z < 0.0 {
            CubeFace::Front
        } else {
            CubeFace::Back
        };
        let (a, b) = face.project(d).unwrap_or((0.0, 0.0));
        (face, a, b)
    }
}

/// Face coordinate `a` (or `b`) of the centre of pixel `i` in a face `n` pixels wide.
#[inline]
pub fn pixel_to_face_coord(i: f32, n: usize) -> f32 {
    2.0 * (i + 0.5) / n as f32 - 1.0
}

/// Continuous pixel position (centre of pixel `i` at `i`) of face coordinate `a`.
#[inline]
pub fn face_coord_to_pixel(a: f32, n: usize) -> f32 {
    (a + 1.0) * 0.5 * n as f32 - 0.5
}

/// Renders one `n x n` face of a panorama whose camera is rotated by `r`: face pixel
/// direction `d` shows the panorama at `r * d` (identity for the panorama's own axes).
pub fn face_from_equirect(img: &HdrImage, face: CubeFace, n: usize, r: Mat3) -> HdrImage {
    let mut out = HdrImage::new(n, n);
    for j in 0..n {
        let b = pixel_to_face_coord(j as f32, n);
        for i in 0..n {
            let a = pixel_to_face_coord(i as f32, n);
            out.set(i, j, sample_dir(img, r * face.dir(a, b)));
        }
    }
    out
}

/// All six faces of a panorama, in [`FACES`] order.
pub fn equirect_to_cube(img: &HdrImage, n: usize) -> Vec<HdrImage> {
    use rayon::prelude::*;
    FACES
        .par_iter()
        .map(|&f| face_from_equirect(img, f, n, Mat3::IDENTITY))
        .collect()
}

/// Bilinear sample of a face image at continuous pixel coordinates (centre of pixel
/// `i` at `i`), clamped at the borders.
#[inline]
pub fn sample_face(face: &HdrImage, x: f32, y: f32) -> [f32; 3] {
    let n = face.width() as i64;
    let m = face.height() as i64;
    let x = x.clamp(0.0, (n - 1) as f32);
    let y = y.clamp(0.0, (m - 1) as f32);
    let x0 = x.floor() as i64;
    let y0 = y.floor() as i64;
    let fx = x - x0 as f32;
    let fy = y - y0 as f32;
    let x1 = (x0 + 1).min(n - 1);
    let y1 = (y0 + 1).min(m - 1);
    let a = face.get(x0 as usize, y0 as usize);
    let b = face.get(x1 as usize, y0 as usize);
    let c = face.get(x0 as usize, y1 as usize);
    let d = face.get(x1 as usize, y1 as usize);
    let mut o = [0.0; 3];
    for k in 0..3 {
        let t = a[k] + (b[k] - a[k]) * fx;
        let u = c[k] + (d[k] - c[k]) * fx;
        o[k] = t + (u - t) * fy;
    }
    o
}

/// Reassembles a `w x h` panorama from six faces in [`FACES`] order.
pub fn cube_to_equirect(faces: &[HdrImage], w: usize, h: usize) -> HdrImage {
    use rayon::prelude::*;
    assert_eq!(faces.len(), 6, "a cube map has six faces");
    let mut out = HdrImage::new(w, h);
    out.rows_mut()
        .enumerate()
        .par_bridge()
        .for_each(|(row, line)| {
            for col in 0..w {
                let (f, a, b) = CubeFace::of_dir(pixel_to_dir(col, row, w, h));
                let face = &faces[f.index()];
                let n = face.width();
                let c = sample_face(face, face_coord_to_pixel(a, n), face_coord_to_pixel(b, n));
                line[3 * col..3 * col + 3].copy_from_slice(&c);
            }
        });
    out
}

/// The `u, v` of each face corner, for drawing face outlines on a panorama.
pub fn face_corner_uv(face: CubeFace) -> [(f32, f32); 4] {
    [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].map(|(a, b)| dir_to_uv(face.dir(a, b)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sphere::pixel_to_dir;

    #[test]
    fn faces_are_orthonormal_and_right_handed_views() {
        for f in FACES {
            let (n, r, d) = f.basis();
            assert!(n.dot(r).abs() < 1e-6 && n.dot(d).abs() < 1e-6 && r.dot(d).abs() < 1e-6);
            // Looking along n with right r, down d: r x d = n (image axes right-handed).
            assert!((r.cross(d) - n).length() < 1e-6, "{f:?}");
        }
    }

    #[test]
    fn top_face_meets_front_face() {
        let edge_top = CubeFace::Top.dir(0.3, 1.0);
        let edge_front = CubeFace::Front.dir(0.3, -1.0);
        assert!((edge_top - edge_front).length() < 1e-6);
        let edge_bot = CubeFace::Bottom.dir(-0.2, -1.0);
        let edge_front2 = CubeFace::Front.dir(-0.2, 1.0);
        assert!((edge_bot - edge_front2).length() < 1e-6);
    }

    #[test]
    fn of_dir_inverts_dir() {
        for f in FACES {
            for &(a, b) in &[(0.1f32, -0.4f32), (-0.9, 0.9), (0.0, 0.0)] {
                let (g, a2, b2) = CubeFace::of_dir(f.dir(a, b) * 3.0);
                assert_eq!(f, g);
                assert!((a - a2).abs() < 1e-5 && (b - b2).abs() < 1e-5);
            }
        }
    }

    /// Marker image: a bright spot straight right (u = 0.75, v = 0.5) and a dimmer
    /// one straight up; they must land at the centres of the right and top faces, and
    /// a yaw of +90° must bring the right marker to the panorama's centre.
    #[test]
    fn markers_pin_the_orientation() {
        let (w, h) = (64, 32);
        let img = HdrImage::from_fn(w, h, |x, y| {
            let d = pixel_to_dir(x, y, w, h);
            if d.dot(Vec3::X) > 0.99 {
                [100.0, 0.0, 0.0]
            } else if d.dot(Vec3::Y) > 0.99 {
                [0.0, 100.0, 0.0]
            } else {
                [0.0, 0.0, 0.0]
            }
        });
        let faces = equirect_to_cube(&img, 16);
        let argmax = |f: &HdrImage, k: usize| {
            let mut best = (0, 0, f32::MIN);
            for y in 0..f.height() {
                for x in 0..f.width() {
                    if f.get(x, y)[k] > best.2 {
                        best = (x, y, f.get(x, y)[k]);
                    }
                }
            }
            (best.0, best.1)
        };
        let (x, y) = argmax(&faces[CubeFace::Right.index()], 0);
        assert!(
            (7..=8).contains(&x) && (7..=8).contains(&y),
            "right marker at {x},{y}"
        );
        assert!(faces[CubeFace::Left.index()]
            .data()
            .iter()
            .all(|&v| v == 0.0));
        let (x, y) = argmax(&faces[CubeFace::Top.index()], 1);
        assert!(
            (7..=8).contains(&x) && (7..=8).contains(&y),
            "top marker at {x},{y}"
        );
        let turned = crate::sphere::rotate(&img, crate::sphere::ypr_to_mat(90.0, 0.0, 0.0), w, h);
        let (x, y) = argmax(&turned, 0);
        assert!(
            (31..=32).contains(&x) && (15..=16).contains(&y),
            "after yaw 90 at {x},{y}"
        );
    }

    #[test]
    fn equirect_cube_equirect_round_trip() {
        let (w, h) = (256, 128);
        let img = HdrImage::from_fn(w, h, |x, y| {
            let d = pixel_to_dir(x, y, w, h);
            [
                1.0 + 0.5 * d.x,
                1.0 + 0.5 * (3.0 * d.z).sin(),
                (2.0 * d.y).exp(),
            ]
        });
        let faces = equirect_to_cube(&img, 96);
        let back = cube_to_equirect(&faces, w, h);
        let mut worst = 0.0f32;
        for y in 16..112 {
            for x in 0..w {
                let a = img.get(x, y);
                let b = back.get(x, y);
                for k in 0..3 {
                    worst = worst.max((a[k] - b[k]).abs() / a[k].abs().max(0.1));
                }
            }
        }
        assert!(worst < 0.03, "worst relative error {worst}");
    }
}
