//! Capturing a light probe: exposure brackets (8-bit, Exif-timed) merged into one
//! HDR panorama, with the camera response recovered from the brackets themselves
//! (Debevec & Malik 1997, "Recovering High Dynamic Range Radiance Maps from
//! Photographs").
//!
//! * [`exif`] reads each frame's exposure time from its JPEG Exif block.
//! * [`debevec`] recovers the per-channel response curve `g = ln f⁻¹` and stores it
//!   ([`ResponseCurve`], JSON) so other SDR frames of the camera can be linearised.
//! * [`merge`](mod@merge) merges the bracket and reports what clipped even in the darkest
//!   frame ([`MergeReport`]): a merge under-estimates those sources, and the user
//!   should be told by how much of the sphere and of the light.
//! * [`cli`] is the `lumiprobe merge` command.
//! * [`localize`] finds every panorama's pose with COLMAP when none is given.
//! * [`calibrate`] recovers the SDR frames' exposure gain against the probes, so
//!   linearised frames and probes share one radiance scale.
//! * [`fisheye`] turns a side-by-side dual-fisheye image (what two-lens cameras
//!   such as the Gear 360 store) into an equirect panorama
//!   ([`fisheye::dual_fisheye_to_equirect`]).
//! * [`vignetting`] fits a two-lens camera's falloff towards its lenses' rims
//!   from the walk, for the per-frame exposure.

pub mod calibrate;
pub mod cli;
pub mod debevec;
pub mod exif;
pub mod exposure;
pub mod fisheye;
pub mod localize;
pub mod merge;
pub mod vignetting;

pub use cli::{run_merge, MergeArgs};
pub use debevec::{recover, RecoverOptions, Recovery, ResponseCurve};
pub use exif::{read_exposure, ExifExposure};
pub use merge::{merge, Exposure, MergeOptions, MergeReport, Merged};

/// The median of `v` (the mean of the two middle values for an even count;
/// NaN when empty), sorting `v`.
fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}
