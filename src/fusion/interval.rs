//! The frame's irradiance as an interval: from what the frame alone shows (every
//! clipped channel at its clip value: the linearised frame) to the most its
//! clipped regions can hold by any one source of evidence (the lights placed in
//! 3-D, the estimate's light near the region, or the fill itself), widened by how
//! far that evidence missed on the corpus. Summarised as
//! the irradiance averaged over all orientations of a surface, which is a quarter
//! of the sphere's luminance power (the mean of a clamped cosine over the sphere
//! is 1/4).

use super::regions::{Pixels, Region};
use crate::image::{luminance, HdrImage};
use serde::{Deserialize, Serialize};

/// How many times the light the evidence adds to the frame (its most, above what
/// the frame alone shows) the upper end allows. Chosen on the corpus's
/// development scenes as the 95th percentile over their 416 frames of the true
/// added light over the evidence's (median 1.03, 90% 1.53, 95% 2.19); the
/// validation scenes' 95th percentile is 2.11.
const EVIDENCE_SPREAD: f64 = 2.2;

/// Irradiance luminance averaged over all surface orientations.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct IrradianceInterval {
    /// What the frame shows with every clipped channel at its clip value.
    pub lower: f64,
    /// The fused prediction's.
    pub estimate: f64,
    /// With each clipped region holding the most power any one source of
    /// evidence gives it, that added light widened by its spread on the corpus
    /// ([`EVIDENCE_SPREAD`]). Light no probe saw is not bounded by it.
    pub upper: f64,
    /// The ledger's upper end ([`super::ledger`]): each clipped region holding
    /// the most any one source the probes measured gives it, with no spread
    /// (0 when no probe evidence was given).
    #[serde(default)]
    pub booked_upper: f64,
}

/// A quarter of the luminance power of `img` (a `w` x `h` panorama with per-row
/// solid angles `sa`).
fn mean_irradiance(img: &HdrImage, sa: &[f32]) -> f64 {
    let w = img.width();
    img.data()
        .chunks_exact(3)
        .enumerate()
        .map(|(i, c)| luminance([c[0], c[1], c[2]]) as f64 * sa[i / w] as f64)
        .sum::<f64>()
        / 4.0
}

/// The interval of a fused frame `out` of the linearised frame `linear`.
pub(super) fn irradiance_interval(
    out: &HdrImage,
    linear: &HdrImage,
    px: &Pixels,
    regions: &[Region],
    ledger: &[super::LedgerEntry],
) -> IrradianceInterval {
    let estimate = mean_irradiance(out, &px.sa);
    let lower = mean_irradiance(linear, &px.sa);
    let more: f64 = regions
        .iter()
        .map(|r| {
            let most = r.placed.power.max(r.estimate.power).max(r.fill.filled);
            (most - r.fill.filled).max(0.0)
        })
        .sum();
    // The region's added light where the evidence gives it less (the partially
    // clipped pixels' measured channels) counts as it is.
    let booked: f64 = ledger.iter().map(|e| (e.most - e.added).max(0.0)).sum();
    IrradianceInterval {
        lower,
        estimate,
        upper: lower + EVIDENCE_SPREAD * (estimate + more / 4.0 - lower),
        booked_upper: if ledger.is_empty() {
            0.0
        } else {
            estimate + booked / 4.0
        },
    }
}
