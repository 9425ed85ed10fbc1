//! A pinhole camera with square pixels, and framing of a model's bounding sphere.
//!
//! Image conventions: pixel `(x, y)` has its centre at `(x + 0.5, y + 0.5)`, `y`
//! runs down. The camera looks from `eye` towards `target`; `up` fixes the roll.

use super::model::Aabb;
use crate::error::{Error, Result};
use glam::Vec3;

/// Largest image a camera may ask for (2^27 pixels, e.g. 16384 x 8192: 2 GiB of
/// float RGBA output).
pub const MAX_PIXELS: usize = 1 << 27;

/// A perspective camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Centre of projection (world space).
    pub eye: Vec3,
    /// A point on the optical axis.
    pub target: Vec3,
    /// Approximate up direction (need not be orthogonal to the view direction).
    pub up: Vec3,
    /// Full vertical field of view in degrees, in `(0, 180)`.
    pub vfov_deg: f32,
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
}

/// Orthonormal camera frame derived from a [`Camera`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraFrame {
    /// Image right.
    pub right: Vec3,
    /// Image up.
    pub up: Vec3,
    /// Viewing direction (unit, from the eye towards the target).
    pub forward: Vec3,
    /// Focal length in pixels: `(height / 2) / tan(vfov / 2)`.
    pub focal_px: f32,
}

impl Camera {
    /// A camera looking along `view_dir` at the centre of `bounds`, just far
    /// enough away that the bounding sphere (centre, half-diagonal radius) fits
    /// inside both the vertical and the horizontal field of view:
    /// `distance = r / sin(min(vfov, hfov) / 2)`. `up` is +y unless `view_dir`
    /// is nearly vertical, then -z.
    pub fn framing(
        bounds: &Aabb,
        view_dir: Vec3,
        vfov_deg: f32,
        width: usize,
        height: usize,
    ) -> Camera {
        let (center, radius) = if bounds.is_empty() {
            (Vec3::ZERO, 1.0)
        } else {
            (bounds.center(), bounds.radius().max(1e-6))
        };
        let dir = view_dir.try_normalize().unwrap_or(Vec3::NEG_Z);
        let half_v = (vfov_deg.clamp(1e-3, 179.0)).to_radians() * 0.5;
        let aspect = width.max(1) as f32 / height.max(1) as f32;
        let half_h = (half_v.tan() * aspect).atan();
        let half = half_v.min(half_h);
        let dist = radius / half.sin();
        let up = if dir.y.abs() > 0.999 {
            Vec3::NEG_Z
        } else {
            Vec3::Y
        };
        Camera {
            eye: center - dir * dist,
            target: center,
            up,
            vfov_deg,
            width,
            height,
        }
    }

    /// Checks that the camera can form an image: non-empty size (at most
    /// 32768 per side and [`MAX_PIXELS`] in all), finite vectors, `eye != target`, `up` not parallel to
    /// the view direction, field of view in `(0, 180)` degrees.
    pub fn validate(&self) -> Result<()> {
        if self.width == 0
            || self.height == 0
            || self.width > 32768
            || self.height > 32768
            || self.width * self.height > MAX_PIXELS
        {
            return Err(Error::Invalid(format!(
                "camera image size {}x{} must be between 1 and 32768 per side and at \
                 most {MAX_PIXELS} pixels",
                self.width, self.height
            )));
        }
        if !(self.vfov_deg > 0.0 && self.vfov_deg < 180.0) {
            return Err(Error::Invalid(format!(
                "camera vertical field of view {} is not in (0, 180) degrees",
                self.vfov_deg
            )));
        }
        if !(self.eye.is_finite() && self.target.is_finite() && self.up.is_finite()) {
            return Err(Error::Invalid("camera vectors must be finite".into()));
        }
        let f = self.target - self.eye;
        if f.length_squared() <= 0.0 || f.normalize().cross(self.up).length_squared() < 1e-12 {
            return Err(Error::Invalid(
                "camera eye equals target or up is parallel to the view direction".into(),
            ));
        }
        Ok(())
    }

    /// The orthonormal frame (right, up, forward) and focal length in pixels.
    pub fn frame(&self) -> CameraFrame {
        let forward = (self.target - self.eye).normalize_or_zero();
        let right = forward.cross(self.up).normalize_or_zero();
        let up = right.cross(forward);
        let half = (self.vfov_deg.to_radians() * 0.5).tan();
        CameraFrame {
            right,
            up,
            forward,
            focal_px: 0.5 * self.height as f32 / half,
        }
    }

    /// Unit world-space direction of the ray through image position `(x, y)` in
    /// pixels (pixel centres at `+0.5`, `y` down).
    pub fn ray_dir(&self, x: f32, y: f32) -> Vec3 {
        let f = self.frame();
        let dx = x - 0.5 * self.width as f32;
        let dy = 0.5 * self.height as f32 - y;
        (f.forward * f.focal_px + f.right * dx + f.up * dy).normalize()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn framing_keeps_the_sphere_inside() {
        let b = Aabb {
            min: Vec3::splat(-1.0),
            max: Vec3::splat(1.0),
        };
        for (w, h) in [(100, 100), (200, 100), (100, 200)] {
            let c = Camera::framing(&b, Vec3::new(0.3, -0.2, -1.0), 40.0, w, h);
            c.validate().unwrap();
            let f = c.frame();
            let d = (c.target - c.eye).length();
            let r = b.radius();
            // Angular radius of the sphere vs the half fields of view.
            let ang = (r / d).asin();
            let half_v = (0.5 * h as f32 / f.focal_px).atan();
            let half_h = (0.5 * w as f32 / f.focal_px).atan();
            assert!(ang <= half_v + 1e-4 && ang <= half_h + 1e-4);
            assert!((ang - half_v.min(half_h)).abs() < 1e-3);
        }
        let c = Camera::framing(&b, Vec3::NEG_Y, 40.0, 10, 10);
        c.validate().unwrap();
    }

    #[test]
    fn centre_ray_is_forward() {
        let c = Camera {
            eye: Vec3::ZERO,
            target: Vec3::NEG_Z,
            up: Vec3::Y,
            vfov_deg: 90.0,
            width: 4,
            height: 2,
        };
        assert!((c.ray_dir(2.0, 1.0) - Vec3::NEG_Z).length() < 1e-6);
        // Top edge at 45 degrees up.
        let d = c.ray_dir(2.0, 0.0);
        assert!((d.y - d.z.abs()).abs() < 1e-6 && d.y > 0.0);
        let d = c.ray_dir(4.0, 1.0);
        assert!(d.x > 0.0);
    }
}
