//! Camera response curves: how a camera maps exposure (linear, relative) to stored
//! 8-bit codes, and back. Inverting the response is what turns an SDR frame into a
//! radiance measurement wherever it does not clip.

use super::{srgb_eotf, srgb_oetf};
use crate::error::{Error, Result};

/// A monotone camera response `f: exposure -> [0, 1]`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Response {
    /// The sRGB transfer curve.
    Srgb,
    /// `f(x) = x^(1/gamma)`.
    Gamma {
        /// Encoding gamma (2.2 typical).
        gamma: f32,
    },
    /// `f(x) = min(1, s y / (1 + k y))` with `y = x^(1/gamma)`: a gamma curve with a soft
    /// shoulder (the response documented for the evaluation data, s = 1.08, k = 0.08).
    RationalGamma {
        /// Gain `s`.
        scale: f32,
        /// Shoulder `k`.
        knee: f32,
        /// Gamma.
        gamma: f32,
    },
    /// A measured curve: linear exposure for each of the 256 codes (monotone,
    /// e.g. from Debevec–Malik recovery).
    Table {
        /// `linear[code]`, non-decreasing.
        linear: Vec<f32>,
    },
}

impl Default for Response {
    fn default() -> Self {
        Response::Srgb
    }
}

impl Response {
    /// Encoded value in [0, 1] for linear exposure `x` (clips above the white point).
    pub fn encode(&self, x: f32) -> f32 {
        let x = if x.is_nan() { 0.0 } else { x.max(0.0) };
        match self {
            Response::Srgb => srgb_oetf(x.min(1.0)),
            Response::Gamma { gamma } => x.min(1.0).powf(1.0 / gamma),
            Response::RationalGamma { scale, knee, gamma } => {
                let y = x.min(1e30).powf(1.0 / gamma);
                (scale * y / (1.0 + knee * y)).min(1.0)
            }
            Response::Table { linear } => {
                // Position of x in the table, interpolated between codes.
                let n = linear.len();
                if n < 2 || x <= linear[0] {
                    return 0.0;
                }
                if x >= linear[n - 1] {
                    return 1.0;
                }
                let i = linear.partition_point(|&v| v <= x).clamp(1, n - 1);
                let (a, b) = (linear[i - 1], linear[i]);
                let t = if b > a { (x - a) / (b - a) } else { 0.0 };
                ((i - 1) as f32 + t) / (n - 1) as f32
            }
        }
    }

    /// Linear exposure of an encoded value in [0, 1].
    pub fn decode(&self, c: f32) -> f32 {
        let c = c.clamp(0.0, 1.0);
        match self {
            Response::Srgb => srgb_eotf(c),
            Response::Gamma { gamma } => c.powf(*gamma),
            Response::RationalGamma { scale, knee, gamma } => {
                let denom = (scale - knee * c).max(1e-6);
                (c / denom).powf(*gamma)
            }
            Response::Table { linear } => {
                let n = linear.len();
                if n == 0 {
                    return c;
                }
                let p = c * (n - 1) as f32;
                let i = (p.floor() as usize).min(n - 1);
                let j = (i + 1).min(n - 1);
                let t = p - i as f32;
                linear[i] + (linear[j] - linear[i]) * t
            }
        }
    }

    /// A 256-entry lookup of [`Response::decode`] for 8-bit codes.
    pub fn decode_lut(&self) -> [f32; 256] {
        let mut lut = [0.0f32; 256];
        for (i, v) in lut.iter_mut().enumerate() {
            *v = self.decode(i as f32 / 255.0);
        }
        lut
    }

    /// Checks that the curve is usable (finite parameters, monotone table).
    pub fn validate(&self) -> Result<()> {
        let ok = match self {
            Response::Srgb => true,
            Response::Gamma { gamma } => gamma.is_finite() && *gamma > 0.0,
            Response::RationalGamma { scale, knee, gamma } => {
                scale.is_finite()
                    && knee.is_finite()
                    && gamma.is_finite()
                    && *gamma > 0.0
                    && *scale > 0.0
                    && *knee >= 0.0
                    && *scale - *knee > 0.0
            }
            Response::Table { linear } => {
                linear.len() >= 2
                    && linear.iter().all(|v| v.is_finite())
                    && linear.windows(2).all(|w| w[1] >= w[0])
            }
        };
        if ok {
            Ok(())
        } else {
            Err(Error::Invalid(format!(
                "camera response {self:?} is not a finite monotone curve"
            )))
        }
    }

    /// Parses a response written as text: `srgb`, `gamma 2.2`, or the formula form
    /// `f(x) = min(1, S * x^(1/G) / (1 + K * x^(1/G)))` used by the evaluation data.
    pub fn parse(text: &str) -> Option<Response> {
        let t: String = text
            .chars()
            .filter(|c| !c.is_whitespace())
            .collect::<String>()
            .to_lowercase();
        if t == "srgb" {
            return Some(Response::Srgb);
        }
        if let Some(g) = t.strip_prefix("gamma") {
            // Like the formula below, only a usable curve (finite gamma > 0).
            return g
                .parse::<f32>()
                .ok()
                .map(|gamma| Response::Gamma { gamma })
                .filter(|r| r.validate().is_ok());
        }
        // min(1,S*x^(1/G)/(1+K*x^(1/G)))
        let start = t.find("min(1,")? + "min(1,".len();
        let rest = &t[start..];
        let (s, rest) = rest.split_once("*x^(1/")?;
        let (g, rest) = rest.split_once(")/(1+")?;
        let (k, rest) = rest.split_once("*x^(1/")?;
        let (g2, _) = rest.split_once(')')?;
        let (scale, gamma, knee, gamma2): (f32, f32, f32, f32) = (
            s.parse().ok()?,
            g.parse().ok()?,
            k.parse().ok()?,
            g2.parse().ok()?,
        );
        if (gamma - gamma2).abs() > 1e-6 {
            return None;
        }
        let r = Response::RationalGamma { scale, knee, gamma };
        r.validate().ok().map(|_| r)
    }
}

/// A fast table of [`Response::encode`] for exposures in `[0, white]`, indexed by
/// `sqrt(x / white)` so the steep toe of gamma-like curves is sampled finely.
#[derive(Clone, Debug)]
pub struct EncodeLut {
    white: f32,
    table: Vec<f32>,
}

impl EncodeLut {
    /// Tabulates `response.encode(x * gain)` for radiance `x` with `n` entries.
    pub fn new(response: &Response, gain: f32, n: usize) -> Self {
        let n = n.max(16);
        let gain = if gain.is_finite() && gain > 0.0 {
            gain
        } else {
            1.0
        };
        // Radiance at which the curve reaches white.
        let white = (response.decode(1.0) / gain).max(1e-30);
        let table = (0..n)
            .map(|i| {
                let t = i as f32 / (n - 1) as f32;
                response.encode(t * t * white * gain)
            })
            .collect();
        EncodeLut { white, table }
    }

    /// Encoded value in [0, 1] of radiance `x` (NaN and negatives give 0).
    #[inline]
    pub fn encode(&self, x: f32) -> f32 {
        if !(x > 0.0) {
            return 0.0;
        }
        if x >= self.white {
            return *self.table.last().unwrap_or(&1.0);
        }
        let p = (x / self.white).sqrt() * (self.table.len() - 1) as f32;
        let i = (p as usize).min(self.table.len() - 2);
        let f = p - i as f32;
        self.table[i] + (self.table[i + 1] - self.table[i]) * f
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encode_lut_matches_the_curve() {
        let r = Response::RationalGamma {
            scale: 1.08,
            knee: 0.08,
            gamma: 2.2,
        };
        let lut = EncodeLut::new(&r, 0.3, 4096);
        for i in 0..2000 {
            let x = (i as f32 / 400.0).powi(2);
            assert!((lut.encode(x) - r.encode(x * 0.3)).abs() < 2e-3, "at {x}");
        }
        assert_eq!(lut.encode(f32::NAN), 0.0);
        assert_eq!(lut.encode(1e30), 1.0);
    }

    #[test]
    fn parses_the_documented_formula() {
        let r = Response::parse(
            "f(x) = min(1, 1.08 * x^(1/2.2) / (1 + 0.08 * x^(1/2.2))), x = exposure-scaled",
        )
        .unwrap();
        assert_eq!(
            r,
            Response::RationalGamma {
                scale: 1.08,
                knee: 0.08,
                gamma: 2.2
            }
        );
        assert_eq!(Response::parse("sRGB"), Some(Response::Srgb));
        assert!(Response::parse("banana").is_none());
    }

    #[test]
    fn encode_decode_round_trip() {
        let curves = [
            Response::Srgb,
            Response::Gamma { gamma: 2.2 },
            Response::RationalGamma {
                scale: 1.08,
                knee: 0.08,
                gamma: 2.2,
            },
            Response::Table {
                linear: (0..256).map(|i| (i as f32 / 255.0).powf(2.0)).collect(),
            },
        ];
        for r in &curves {
            for i in 1..100 {
                let x = i as f32 / 100.0;
                let c = r.encode(x);
                if c < 0.999 {
                    assert!((r.decode(c) - x).abs() < 2e-3 * x.max(0.05), "{r:?} at {x}");
                }
            }
        }
    }

    #[test]
    fn rational_gamma_clips_at_one() {
        let r = Response::RationalGamma {
            scale: 1.08,
            knee: 0.08,
            gamma: 2.2,
        };
        assert_eq!(r.encode(1.0), 1.0);
        assert_eq!(r.encode(1e9), 1.0);
        assert!(r.decode(1.0).is_finite());
    }
}
