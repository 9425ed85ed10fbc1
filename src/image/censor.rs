//! What an 8-bit code says about the radiance it recorded: the one definition of
//! "clipped" that bracket merging, the warp, the flow and the fusion share.
//!
//! A channel's code is a *censored measurement*. Below the clip code it measured
//! the radiance (to within noise and quantisation). At or above it the sensor
//! saturated: the radiance is at least what the code decodes to, with no upper
//! bound. JPEG (and video) compression codes the channels jointly — luma and
//! chroma, the chroma shared by 2x2 pixels, in 8x8 blocks — so next to a clipped
//! sample a saturated channel can decode several codes lower: from the bleed code
//! on, a channel within one pixel of a clipped sample is bounded below only, too.
//! Decoding a code to radiance (the camera response) is not this module's
//! concern; [`Censor::interval`] takes the decoded value.

use serde::{Deserialize, Serialize};

/// Default code from which a channel is clipped: the sensor saturates at 255 and
/// JPEG ringing spreads a clipped 255 down by a few codes.
pub const CLIP_CODE: u8 = 250;

/// Default code from which a channel next to a clipped sample is not trusted as a
/// measurement (JPEG bleeding). Measured (kitchen, flat): 220, 230 and 240 within
/// 0.0005 in fusion's irradiance error.
pub const BLEED_CODE: u8 = 230;

/// What one channel's code tells about its radiance.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reading {
    /// Below the bleed code, or below the clip code away from clipped samples:
    /// a measurement.
    Measured,
    /// At or above the clip code: a lower bound.
    Clipped,
    /// From the bleed code up to the clip code, next to a clipped sample: a lower
    /// bound.
    Bled,
}

/// The codes from which channels are censored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Censor {
    /// Code from which a channel is clipped.
    pub clip_code: u8,
    /// Code from which a channel within one pixel of a clipped sample is bled.
    pub bleed_code: u8,
}

impl Default for Censor {
    fn default() -> Self {
        Censor {
            clip_code: CLIP_CODE,
            bleed_code: BLEED_CODE,
        }
    }
}

/// A radiance interval `[lo, hi]` (`hi` infinite where the code bounds the
/// radiance from below only).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Interval {
    /// Least radiance the code allows.
    pub lo: f32,
    /// Most radiance the code allows (infinite when censored).
    pub hi: f32,
}

impl Interval {
    /// True when the code bounds the radiance from below only.
    pub fn censored(&self) -> bool {
        self.hi == f32::INFINITY
    }
}

impl Censor {
    /// The default codes with a chosen clip code (the bleed code never above it).
    pub fn with_clip_code(clip_code: u8) -> Censor {
        Censor {
            clip_code,
            bleed_code: BLEED_CODE.min(clip_code),
        }
    }

    /// True when a channel coded `code` saturated.
    #[inline]
    pub fn clipped(&self, code: u8) -> bool {
        code >= self.clip_code
    }

    /// True when some channel of the pixel `rgb` saturated.
    #[inline]
    pub fn any_clipped(&self, rgb: &[u8]) -> bool {
        rgb.iter().any(|&c| self.clipped(c))
    }

    /// How many channels of the pixel `rgb` saturated.
    #[inline]
    pub fn clipped_channels(&self, rgb: &[u8]) -> usize {
        rgb.iter().filter(|&&c| self.clipped(c)).count()
    }

    /// What a channel coded `code` tells, `near_clip` being true when some sample
    /// within one pixel (any channel) clipped ([`Censor::near_clipped`]).
    #[inline]
    pub fn reading(&self, code: u8, near_clip: bool) -> Reading {
        if self.clipped(code) {
            Reading::Clipped
        } else if near_clip && code >= self.bleed_code {
            Reading::Bled
        } else {
            Reading::Measured
        }
    }

    /// True when a channel coded `code` next to a clipped sample is bounded below
    /// only ([`Reading::Bled`] or [`Reading::Clipped`]).
    #[inline]
    pub fn bleeds(&self, code: u8) -> bool {
        code >= self.bleed_code.min(self.clip_code)
    }

    /// The radiance interval of a channel coded `code` that decodes to `decoded`.
    pub fn interval(&self, code: u8, near_clip: bool, decoded: f32) -> Interval {
        match self.reading(code, near_clip) {
            Reading::Measured => Interval {
                lo: decoded,
                hi: decoded,
            },
            Reading::Clipped | Reading::Bled => Interval {
                lo: decoded,
                hi: f32::INFINITY,
            },
        }
    }

    /// Per pixel of interleaved RGB codes: some channel saturated.
    pub fn clipped_pixels(&self, rgb: &[u8]) -> Vec<bool> {
        rgb.chunks_exact(3).map(|c| self.any_clipped(c)).collect()
    }

    /// Per pixel of interleaved RGB codes `w` pixels wide: some sample within one
    /// pixel (3x3, any channel, rows not wrapped) saturated.
    pub fn near_clipped(&self, rgb: &[u8], w: usize) -> Vec<bool> {
        let n = rgb.len() / 3;
        if w == 0 || n == 0 {
            return Vec::new();
        }
        let h = n / w;
        let clipped = self.clipped_pixels(&rgb[..3 * w * h]);
        // Separable 3x3 dilation: rows, then columns.
        let mut rows = vec![false; w * h];
        for y in 0..h {
            for x in 0..w {
                let lo = x.saturating_sub(1);
                let hi = (x + 1).min(w - 1);
                rows[y * w + x] = (lo..=hi).any(|xx| clipped[y * w + xx]);
            }
        }
        let mut out = vec![false; n];
        for y in 0..h {
            let lo = y.saturating_sub(1);
            let hi = (y + 1).min(h - 1);
            for x in 0..w {
                out[y * w + x] = (lo..=hi).any(|yy| rows[yy * w + x]);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_code_is_measured_clipped_or_bled() {
        let c = Censor::default();
        assert_eq!(c.reading(249, false), Reading::Measured);
        assert_eq!(c.reading(249, true), Reading::Bled);
        assert_eq!(c.reading(229, true), Reading::Measured);
        assert_eq!(c.reading(250, false), Reading::Clipped);
        let m = c.interval(100, true, 0.3);
        assert_eq!((m.lo, m.hi), (0.3, 0.3));
        assert!(!m.censored());
        let b = c.interval(240, true, 0.8);
        assert_eq!(b.lo, 0.8);
        assert!(b.censored());
        assert!(c.interval(255, false, 1.0).censored());
    }

    #[test]
    fn the_bleed_code_never_exceeds_the_clip_code() {
        let c = Censor::with_clip_code(200);
        assert_eq!(c.bleed_code, 200);
        assert_eq!(c.reading(210, true), Reading::Clipped);
        assert!(c.bleeds(200));
        assert!(!c.bleeds(199));
    }

    #[test]
    fn near_clipped_reaches_one_pixel_in_every_direction_and_no_further() {
        // 5x3 frame, one clipped sample (green channel) at (2, 1).
        let (w, h) = (5, 3);
        let mut rgb = vec![10u8; 3 * w * h];
        rgb[3 * (w + 2) + 1] = 255;
        let near = Censor::default().near_clipped(&rgb, w);
        for y in 0..h {
            for x in 0..w {
                let expect = (1..=3).contains(&x);
                assert_eq!(near[y * w + x], expect, "({x}, {y})");
            }
        }
        assert_eq!(
            Censor::default()
                .clipped_pixels(&rgb)
                .iter()
                .filter(|&&b| b)
                .count(),
            1
        );
    }
}
