//! Tone mapping (HDR -> display values in [0, 1]) and camera response curves
//! (8-bit codes <-> linear exposure).

pub mod response;

pub use response::{EncodeLut, Response};

use crate::image::{luminance, HdrImage};

/// Parameters of the photoreceptor operator of Reinhard & Devlin 2005, "Dynamic range
/// reduction inspired by photoreceptor physiology" (IEEE TVCG 11(1)). The thesis used
/// it with its defaults to turn probes into SDR images for feature matching.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct Reinhard05 {
    /// Overall intensity `f` in [-8, 8]; the paper's default is 0.
    pub intensity: f32,
    /// Contrast `m` in [0.3, 1); `None` derives it from the image's log-luminance
    /// range as the paper suggests: `m = 0.3 + 0.7 k^1.4`.
    pub contrast: Option<f32>,
    /// Light adaptation `a` in [0, 1]: 1 adapts to each pixel, 0 to the image mean.
    pub light_adapt: f32,
    /// Chromatic adaptation `c` in [0, 1]: 0 adapts to luminance, 1 per channel.
    pub color_adapt: f32,
    /// Display gamma applied after the operator and min/max normalisation.
    pub gamma: f32,
}

impl Default for Reinhard05 {
    fn default() -> Self {
        Reinhard05 {
            intensity: 0.0,
            contrast: None,
            light_adapt: 1.0,
            color_adapt: 0.0,
            gamma: 2.2,
        }
    }
}

/// Clean copy of a sample for tone mapping: NaN and negatives become 0, +inf the
/// largest finite float, so no operator ever sees a non-finite value.
#[inline]
fn sane(v: f32) -> f32 {
    if v.is_nan() || v <= 0.0 {
        0.0
    } else if v.is_infinite() {
        f32::MAX
    } else {
        v
    }
}

/// What [`Reinhard05`] maps every pixel with: the image's statistics and the
/// operator's settings.
struct Reinhard05Map {
    m: f64,
    f: f64,
    a: f64,
    c: f64,
    lum_mean: f64,
    chan_mean: [f64; 3],
}

impl Reinhard05Map {
    /// The operator's value of each channel of pixel `p`, before normalisation.
    #[inline]
    fn values(&self, p: [f32; 3]) -> [f64; 3] {
        let p = [sane(p[0]), sane(p[1]), sane(p[2])];
        let l = luminance(p) as f64;
        let (a, c) = (self.a, self.c);
        std::array::from_fn(|k| {
            let ch = p[k] as f64;
            let local = c * ch + (1.0 - c) * l;
            let global = c * self.chan_mean[k] + (1.0 - c) * self.lum_mean;
            let adapt = a * local + (1.0 - a) * global;
            let sigma = (self.f * adapt).max(0.0).powf(self.m);
            let v = if ch + sigma > 0.0 {
                ch / (ch + sigma)
            } else {
                0.0
            };
            if v.is_finite() {
                v
            } else {
                1.0
            }
        })
    }
}

impl Reinhard05 {
    /// The per-pixel map for `img` (`None` for an empty image): log statistics
    /// of luminance, in f64 so a 1e6 sun does not lose the rest.
    fn map_for(&self, img: &HdrImage) -> Option<Reinhard05Map> {
        let eps = 1e-6f64;
        let n = img.width() * img.height();
        if n == 0 {
            return None;
        }
        let mut log_sum = 0.0f64;
        let mut log_min = f64::INFINITY;
        let mut log_max = f64::NEG_INFINITY;
        let mut chan_sum = [0.0f64; 3];
        let mut lum_sum = 0.0f64;
        for p in img.pixels() {
            let p = [sane(p[0]), sane(p[1]), sane(p[2])];
            let l = luminance(p) as f64;
            let ll = (l + eps).ln();
            log_sum += ll;
            log_min = log_min.min(ll);
            log_max = log_max.max(ll);
            lum_sum += l;
            for k in 0..3 {
                chan_sum[k] += p[k] as f64;
            }
        }
        let log_mean = log_sum / n as f64;
        let m = match self.contrast {
            Some(m) => m as f64,
            None => {
                let range = log_max - log_min;
                let k = if range > 1e-9 {
                    ((log_max - log_mean) / range).clamp(0.0, 1.0)
                } else {
                    0.5
                };
                0.3 + 0.7 * k.powf(1.4)
            }
        };
        Some(Reinhard05Map {
            m,
            f: (-self.intensity as f64).exp(),
            a: self.light_adapt as f64,
            c: self.color_adapt as f64,
            lum_mean: lum_sum / n as f64,
            chan_mean: chan_sum.map(|s| s / n as f64),
        })
    }

    /// Calls `put(i, display value)` for every sample `i` of `img`, in order.
    /// Three passes (statistics, range, output) and no per-pixel buffer: the
    /// operator's values are computed again rather than kept, so memory stays
    /// the image's and the caller's output.
    fn each_display_value(&self, img: &HdrImage, mut put: impl FnMut(usize, f32)) {
        let Some(map) = self.map_for(img) else {
            return;
        };
        let mut vmin = f64::INFINITY;
        let mut vmax = f64::NEG_INFINITY;
        for p in img.pixels() {
            for v in map.values(p) {
                vmin = vmin.min(v);
                vmax = vmax.max(v);
            }
        }
        let span = vmax - vmin;
        let inv_gamma = 1.0 / self.gamma.max(1e-3) as f64;
        for (i, p) in img.pixels().enumerate() {
            for (k, t) in map.values(p).into_iter().enumerate() {
                let v = if span > 1e-12 { (t - vmin) / span } else { 0.5 };
                put(3 * i + k, v.clamp(0.0, 1.0).powf(inv_gamma) as f32);
            }
        }
    }

    /// Tone-maps `img` to display values in `[0, 1]` (interleaved RGB, same size).
    /// Finite for any input, including constant, all-black and single-sun images.
    pub fn apply(&self, img: &HdrImage) -> Vec<f32> {
        let mut out = vec![0.0f32; img.width() * img.height() * 3];
        self.each_display_value(img, |i, v| out[i] = v);
        out
    }

    /// [`Self::apply`] quantised to 8 bits ([`quantize`] of it, byte for byte)
    /// without the float buffer: a quarter of the memory for a large panorama.
    pub fn apply_quantized(&self, img: &HdrImage) -> Vec<u8> {
        let mut out = vec![0u8; img.width() * img.height() * 3];
        self.each_display_value(img, |i, v| out[i] = quantize_one(v));
        out
    }
}

/// Global operator of Reinhard et al. 2002 ("Photographic tone reproduction"): scales
/// by `key / log-average luminance`, then `L (1 + L / white^2) / (1 + L)` on luminance.
/// `log_avg` overrides the image's own log-average (to tone-map two images alike).
pub fn reinhard_global(
    img: &HdrImage,
    key: f32,
    white: Option<f32>,
    log_avg: Option<f32>,
) -> Vec<f32> {
    let la = log_avg
        .unwrap_or_else(|| log_average_luminance(img))
        .max(1e-12);
    // In f64: near white, f32 rounding of `p * scale * Ld / L` made brighter
    // greys come out a few ulps darker than dimmer ones.
    let scale = key as f64 / la as f64;
    let w2 = white.map(|w| (w as f64 * w as f64).max(1e-12));
    let mut out = Vec::with_capacity(img.data().len());
    for p in img.pixels() {
        let p = [sane(p[0]), sane(p[1]), sane(p[2])];
        let l = (0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64) * scale;
        let ld = match w2 {
            Some(w2) => l * (1.0 + l / w2) / (1.0 + l),
            None => l / (1.0 + l),
        };
        let ratio = if l > 0.0 { ld / l } else { 0.0 };
        for k in 0..3 {
            let v = (p[k] as f64 * scale * ratio).clamp(0.0, 1.0) as f32;
            out.push(srgb_oetf(if v.is_finite() { v } else { 1.0 }));
        }
    }
    out
}

/// Geometric mean of luminance, `exp(mean(ln(eps + L)))`, with eps = 1e-6.
pub fn log_average_luminance(img: &HdrImage) -> f32 {
    let n = (img.width() * img.height()).max(1);
    let s: f64 = img
        .pixels()
        .map(|p| ((luminance([sane(p[0]), sane(p[1]), sane(p[2])]) as f64) + 1e-6).ln())
        .sum();
    (s / n as f64).exp() as f32
}

/// The exposure in EV that maps `img`'s log-average luminance
/// ([`log_average_luminance`]) to middle grey (0.18): what previews, renders
/// and the web viewer use unless an exposure is given. 0 for an image with no
/// light (log-average under 1e-5, the floor's own scale).
pub fn auto_exposure_ev(img: &HdrImage) -> f32 {
    let avg = log_average_luminance(img);
    if avg.is_finite() && avg > 1e-5 {
        (0.18 / avg).log2()
    } else {
        0.0
    }
}

/// Exposure by `2^ev`, clip to [0, 1], sRGB encode.
pub fn exposure_srgb(img: &HdrImage, ev: f32) -> Vec<f32> {
    let s = 2f32.powf(ev);
    img.data()
        .iter()
        .map(|&v| srgb_oetf((sane(v) * s).clamp(0.0, 1.0)))
        .collect()
}

/// sRGB opto-electronic transfer (linear [0, 1] -> encoded [0, 1]).
#[inline]
pub fn srgb_oetf(x: f32) -> f32 {
    if x <= 0.003_130_8 {
        12.92 * x.max(0.0)
    } else {
        1.055 * x.min(1.0).powf(1.0 / 2.4) - 0.055
    }
}

/// Inverse of [`srgb_oetf`].
#[inline]
pub fn srgb_eotf(y: f32) -> f32 {
    if y <= 0.040_45 {
        y.max(0.0) / 12.92
    } else {
        ((y.min(1.0) + 0.055) / 1.055).powf(2.4)
    }
}

/// Display values in [0, 1] to 8-bit codes (rounded).
pub fn quantize(v: &[f32]) -> Vec<u8> {
    v.iter().map(|&x| quantize_one(x)).collect()
}

/// One display value in `[0, 1]` to its 8-bit code (rounded).
#[inline]
pub fn quantize_one(x: f32) -> u8 {
    (x.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

/// 8-bit gray (luma of display values) for feature detection.
pub fn to_gray8(display_rgb: &[f32]) -> Vec<u8> {
    display_rgb
        .chunks_exact(3)
        .map(|c| ((0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]).clamp(0.0, 1.0) * 255.0 + 0.5) as u8)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all_finite_in_unit(v: &[f32]) -> bool {
        v.iter().all(|x| x.is_finite() && (0.0..=1.0).contains(x))
    }

    #[test]
    fn auto_exposure_maps_the_log_average_to_middle_grey() {
        let img = HdrImage::from_fn(16, 8, |_, _| [2.0, 2.0, 2.0]);
        assert!((auto_exposure_ev(&img) - (0.09f32).log2()).abs() < 1e-4);
        assert_eq!(auto_exposure_ev(&HdrImage::new(16, 8)), 0.0);
        // A sun a million times the rest moves a log-average little: the
        // exposure stays within a stop and a half of the room's.
        let sun = HdrImage::from_fn(
            16,
            8,
            |x, y| if (x, y) == (3, 3) { [1e6; 3] } else { [1.0; 3] },
        );
        let ev = auto_exposure_ev(&sun);
        assert!(ev < (0.18f32).log2() && ev > (0.18f32).log2() - 1.5, "{ev}");
        // Scale-free: ten times the light, log2(10) EV less.
        let bright = HdrImage::from_fn(16, 8, |_, _| [20.0; 3]);
        assert!((auto_exposure_ev(&img) - auto_exposure_ev(&bright) - 10f32.log2()).abs() < 1e-4);
    }

    #[test]
    fn extreme_images_give_finite_output() {
        let black = HdrImage::new(16, 8);
        let constant = HdrImage::from_fn(16, 8, |_, _| [3.0, 3.0, 3.0]);
        let sun = HdrImage::from_fn(16, 8, |x, y| {
            if x == 3 && y == 2 {
                [1e6, 1e6, 9e5]
            } else {
                [0.5, 0.4, 0.3]
            }
        });
        let mut bad = HdrImage::from_fn(16, 8, |_, _| [1.0, 1.0, 1.0]);
        bad.data_mut()[0] = f32::NAN;
        bad.data_mut()[4] = f32::INFINITY;
        bad.data_mut()[7] = -2.0;
        for img in [&black, &constant, &sun, &bad] {
            assert!(all_finite_in_unit(&Reinhard05::default().apply(img)));
            assert!(all_finite_in_unit(&reinhard_global(img, 0.18, None, None)));
            assert!(all_finite_in_unit(&reinhard_global(
                img,
                0.18,
                Some(4.0),
                None
            )));
            assert!(all_finite_in_unit(&exposure_srgb(img, 0.0)));
        }
        // The sun does not wash the rest of the image to black.
        let t = Reinhard05::default().apply(&sun);
        assert!(t[3 * 20] > 0.05, "{}", t[3 * 20]);
    }

    #[test]
    fn reinhard05_straight_to_8_bits_is_its_float_output_quantised() {
        let sun = HdrImage::from_fn(32, 16, |x, y| {
            if x == 3 && y == 2 {
                [1e6, 1e6, 9e5]
            } else {
                [0.01 * x as f32, 0.3 + 0.01 * y as f32, 0.2]
            }
        });
        let mut bad = sun.clone();
        bad.data_mut()[5] = f32::NAN;
        bad.data_mut()[9] = -1.0;
        let ops = [
            Reinhard05::default(),
            Reinhard05 {
                intensity: 1.0,
                contrast: Some(0.6),
                light_adapt: 0.5,
                color_adapt: 0.3,
                gamma: 1.8,
            },
        ];
        for img in [&sun, &bad, &HdrImage::new(4, 2)] {
            for op in &ops {
                assert_eq!(op.apply_quantized(img), quantize(&op.apply(img)));
            }
        }
    }

    #[test]
    fn reinhard05_is_monotone_in_luminance() {
        let img = HdrImage::from_fn(64, 1, |x, _| {
            let v = 10f32.powf(x as f32 / 8.0 - 3.0);
            [v, v, v]
        });
        let t = Reinhard05::default().apply(&img);
        for x in 1..64 {
            assert!(t[3 * x] >= t[3 * (x - 1)], "not monotone at {x}");
        }
    }

    #[test]
    fn srgb_round_trip() {
        for i in 0..=100 {
            let x = i as f32 / 100.0;
            assert!((srgb_eotf(srgb_oetf(x)) - x).abs() < 1e-5);
        }
    }
}
