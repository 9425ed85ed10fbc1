//! Diffuse irradiance cube maps from order-2 spherical harmonics.
//!
//! Each texel stores the irradiance `E(n) = int L(d) max(0, n.d) dOmega` for the
//! normal `n` through its centre, evaluated from nine SH coefficients with the
//! clamped-cosine band factors of Ramamoorthi & Hanrahan 2001 ("An efficient
//! representation for irradiance environment maps") and clamped at zero
//! ([`Sh9::irradiance_clamped`]).
//!
//! The cube stores `E` itself, **not** `E / pi`: a Lambertian surface of albedo
//! `rho` reflects radiance `rho E / pi`, so shaders must divide by `pi` (a constant
//! environment of radiance `L` gives `E = pi L`). Face order and orientation are
//! those of [`crate::sphere::cube`] ([`crate::sphere::FACES`]).

use super::sh::Sh9;
use crate::image::HdrImage;
use crate::sphere::cube::pixel_to_face_coord;
use crate::sphere::FACES;
use rayon::prelude::*;

/// Default face size of the irradiance cube: irradiance is so smooth (bands
/// `l <= 2` only) that 32 texels per face interpolate it to well below 1%.
pub const DEFAULT_IRRADIANCE_FACE_SIZE: usize = 32;

/// Irradiance cube map of `sh` (six `face_size x face_size` faces in
/// [`crate::sphere::FACES`] order), storing `E` (not `E / pi`; see the module
/// docs) at each texel centre via [`Sh9::irradiance_clamped`], so no texel is
/// negative even for a peaky environment. A `face_size` of 0 is treated as 1.
pub fn irradiance_cube(sh: &Sh9, face_size: usize) -> [HdrImage; 6] {
    let n = face_size.max(1);
    let faces: Vec<HdrImage> = FACES
        .par_iter()
        .map(|&face| {
            HdrImage::from_fn(n, n, |x, y| {
                let a = pixel_to_face_coord(x as f32, n);
                let b = pixel_to_face_coord(y as f32, n);
                sh.irradiance_clamped(face.dir(a, b))
            })
        })
        .collect();
    faces.try_into().expect("six faces")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ibl::fibonacci_directions;
    use crate::ibl::prefilter::sample_cube;
    use std::f32::consts::PI;

    #[test]
    fn constant_radiance_gives_pi_l() {
        let img = HdrImage::from_fn(64, 32, |_, _| [0.5, 1.0, 2.0]);
        let cube = irradiance_cube(&Sh9::project(&img), 8);
        for face in &cube {
            assert_eq!((face.width(), face.height()), (8, 8));
            for px in face.pixels() {
                for (k, want) in [0.5f32, 1.0, 2.0].iter().enumerate() {
                    assert!((px[k] - PI * want).abs() < 2e-3 * PI * want, "{px:?}");
                }
            }
        }
    }

    #[test]
    fn cube_matches_sh_between_texels() {
        let mut sh = Sh9::zero();
        sh.coeffs[0] = [3.0; 3];
        sh.coeffs[2] = [1.0, 0.5, -0.5];
        sh.coeffs[8] = [0.3; 3];
        let cube = irradiance_cube(&sh, 32);
        for n in fibonacci_directions(200) {
            let a = sample_cube(&cube, n);
            let b = sh.irradiance_clamped(n);
            for k in 0..3 {
                assert!(
                    (a[k] - b[k]).abs() < 0.01 * b[k].max(1.0),
                    "{n}: {a:?} {b:?}"
                );
            }
        }
        assert_eq!(irradiance_cube(&sh, 0)[0].width(), 1);
    }
}
