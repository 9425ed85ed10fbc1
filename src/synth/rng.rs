//! Tiny deterministic randomness for the synthesizer: a SplitMix64 generator for
//! sequential draws (poses, layout, sensor noise) and stateless integer hashing plus
//! value noise for procedural textures, so any pixel can be evaluated independently
//! (and therefore in parallel) with bit-identical results on every run.

/// SplitMix64 (Steele, Lea & Flood 2014): 64-bit state, one add and a mix per draw.
/// Good enough statistically for synthetic scenes and trivially reproducible.
#[derive(Clone, Debug)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// A generator whose whole sequence is determined by `seed`.
    pub fn new(seed: u64) -> Self {
        SplitMix64 { state: seed }
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix64(self.state)
    }

    /// Uniform in `[0, 1)` with 53 bits of precision.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next_f64()
    }

    /// Uniform in `[lo, hi)` as `f32`.
    pub fn range_f32(&mut self, lo: f32, hi: f32) -> f32 {
        self.range(lo as f64, hi as f64) as f32
    }

    /// Uniform integer in `0..n` (`n > 0`).
    pub fn below(&mut self, n: u64) -> u64 {
        ((self.next_u64() as u128 * n as u128) >> 64) as u64
    }

    /// A standard normal sample (Box–Muller, one of the pair).
    pub fn gaussian(&mut self) -> f64 {
        // 1 - u keeps the logarithm's argument in (0, 1].
        let u1 = 1.0 - self.next_f64();
        let u2 = self.next_f64();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// A fresh 32-bit seed for a texture or sub-generator.
    pub fn seed32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }
}

/// The SplitMix64 finaliser: a bijective 64-bit mix.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Derives an independent 64-bit seed from a base seed and a stream label.
#[inline]
pub fn derive(seed: u64, label: u64) -> u64 {
    mix64(seed ^ mix64(label.wrapping_add(0x632B_E59B_D9B4_E019)))
}

/// MurmurHash3's 32-bit finaliser.
#[inline]
fn fmix32(mut h: u32) -> u32 {
    h ^= h >> 16;
    h = h.wrapping_mul(0x85EB_CA6B);
    h ^= h >> 13;
    h = h.wrapping_mul(0xC2B2_AE35);
    h ^= h >> 16;
    h
}

/// Hash of three integers (lattice cell and seed) to 32 well-mixed bits.
#[inline]
pub fn hash3(a: u32, b: u32, c: u32) -> u32 {
    let h = fmix32(a.wrapping_mul(0x9E37_79B1) ^ c);
    fmix32(h ^ b.wrapping_mul(0x85EB_CA77).rotate_left(13))
}

/// Hash of three integers mapped to `[0, 1)`.
#[inline]
pub fn hash_unit(a: u32, b: u32, c: u32) -> f32 {
    (hash3(a, b, c) >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Hash of a signed 2-D lattice cell and a seed, in `[0, 1)`.
#[inline]
pub fn cell_unit(ix: i32, iy: i32, seed: u32) -> f32 {
    hash_unit(ix as u32, iy as u32, seed)
}

#[inline]
fn smooth(t: f32) -> f32 {
    t * t * (3.0 - 2.0 * t)
}

/// 2-D value noise in `[0, 1)`: random values on the integer lattice, smoothly
/// interpolated. Cheap and isotropic enough for blotches, grain and clouds.
#[inline]
pub fn value_noise(x: f32, y: f32, seed: u32) -> f32 {
    let fx = x.floor();
    let fy = y.floor();
    let (ix, iy) = (fx as i32, fy as i32);
    let tx = smooth(x - fx);
    let ty = smooth(y - fy);
    let a = cell_unit(ix, iy, seed);
    let b = cell_unit(ix + 1, iy, seed);
    let c = cell_unit(ix, iy + 1, seed);
    let d = cell_unit(ix + 1, iy + 1, seed);
    let top = a + (b - a) * tx;
    let bot = c + (d - c) * tx;
    top + (bot - top) * ty
}

/// Fractal sum of `octaves` value-noise layers (each twice the frequency and half the
/// amplitude of the previous), normalised to `[0, 1)`: multi-scale texture detail.
#[inline]
pub fn fbm(x: f32, y: f32, seed: u32, octaves: u32) -> f32 {
    let mut sum = 0.0;
    let mut amp = 1.0;
    let mut norm = 0.0;
    let (mut x, mut y) = (x, y);
    for k in 0..octaves {
        sum += amp * value_noise(x, y, seed.wrapping_add(k.wrapping_mul(0x68E3_1DA4)));
        norm += amp;
        amp *= 0.5;
        // Rotate a little between octaves so lattice axes do not line up.
        let (nx, ny) = (1.6 * x + 1.2 * y, -1.2 * x + 1.6 * y);
        x = nx + 17.3;
        y = ny - 9.1;
    }
    sum / norm
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generator_is_reproducible_and_uniformish() {
        let mut a = SplitMix64::new(7);
        let mut b = SplitMix64::new(7);
        let xs: Vec<f64> = (0..1000).map(|_| a.next_f64()).collect();
        let ys: Vec<f64> = (0..1000).map(|_| b.next_f64()).collect();
        assert_eq!(xs, ys);
        let mean = xs.iter().sum::<f64>() / 1000.0;
        assert!((mean - 0.5).abs() < 0.05, "{mean}");
        let mut g = SplitMix64::new(1);
        let n = 20000;
        let s: Vec<f64> = (0..n).map(|_| g.gaussian()).collect();
        let m = s.iter().sum::<f64>() / n as f64;
        let v = s.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n as f64;
        assert!(m.abs() < 0.03 && (v - 1.0).abs() < 0.05, "{m} {v}");
    }

    #[test]
    fn noise_is_bounded() {
        for i in 0..500 {
            let x = i as f32 * 0.37 - 50.0;
            let y = i as f32 * 0.11 + 3.0;
            let n = value_noise(x, y, 3);
            let f = fbm(x, y, 9, 5);
            assert!((0.0..1.0).contains(&n) && (0.0..1.0).contains(&f));
        }
    }
}
