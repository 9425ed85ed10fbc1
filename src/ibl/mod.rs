//! Image-based lighting from HDR probes: order-2 spherical harmonics for diffuse
//! irradiance ([`sh`]), the prefiltering stage that turns a probe into what a
//! renderer samples (irradiance cube [`irradiance`], GGX specular cube
//! [`prefilter`], split-sum BRDF table [`mod@brdf_lut`]), and small helpers shared with
//! the evaluation.

pub mod brdf_lut;
pub mod export;
pub mod irradiance;
pub mod ktx2;
pub mod lights;
pub mod prefilter;
pub mod sh;

pub use brdf_lut::{brdf_lookup, brdf_lut};
pub use export::{
    load_prefiltered, prefilter_to_dir, FaceLayout, PrefilterOptions, PrefilterReport, Prefiltered,
};
pub use irradiance::irradiance_cube;
pub use prefilter::{prefilter_specular, CubeMip, SpecularCube, SpecularOptions};
pub use sh::{sh_basis, Sh9, ShWindow, SH_COUNT};

use glam::Vec3;

/// `n` nearly uniform unit directions on the sphere (Fibonacci / golden-angle
/// spiral), deterministic for a given `n`. Used as a fixed set of surface normals
/// where irradiance is compared, so results are reproducible across runs.
///
/// Point `i` has height `y = 1 - (2 i + 1) / n` (y is up) and longitude
/// `i * pi (3 - sqrt 5)`.
pub fn fibonacci_directions(n: usize) -> Vec<Vec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let y = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let r = (1.0 - y * y).max(0.0).sqrt();
            let (s, c) = (golden * i as f64).sin_cos();
            Vec3::new((r * c) as f32, y as f32, (r * s) as f32)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fibonacci_directions_are_unit_and_balanced() {
        let d = fibonacci_directions(256);
        assert_eq!(d.len(), 256);
        assert!(d.iter().all(|v| (v.length() - 1.0).abs() < 1e-5));
        let mean: Vec3 = d.iter().copied().sum::<Vec3>() / 256.0;
        assert!(mean.length() < 0.01, "{mean}");
    }
}
