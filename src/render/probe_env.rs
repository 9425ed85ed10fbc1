//! A prefiltered light probe as the renderer's [`Environment`].

use super::Environment;
use crate::ibl::export::Prefiltered;
use glam::Vec3;

impl Environment for Prefiltered {
    fn irradiance(&self, n: Vec3) -> [f32; 3] {
        Prefiltered::irradiance(self, n)
    }
    fn specular(&self, r: Vec3, roughness: f32) -> [f32; 3] {
        Prefiltered::specular(self, r, roughness)
    }
    fn brdf(&self, n_dot_v: f32, roughness: f32) -> [f32; 2] {
        Prefiltered::brdf(self, n_dot_v, roughness)
    }
    /// The sharpest mip (roughness 0 reproduces the source).
    fn background(&self, d: Vec3) -> [f32; 3] {
        Prefiltered::specular(self, d, 0.0)
    }
}
