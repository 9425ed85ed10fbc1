//! In-memory images: linear float HDR and 8-bit SDR, plus their file formats.

pub mod censor;
pub mod io;

use crate::error::{Error, Result};

/// A linear, scene-referred RGB image stored as interleaved `f32`.
///
/// Values are never clamped: radiance may be anywhere in `[0, inf)`. Rows run top
/// to bottom, so pixel `(x, y)` sits at `data[3 * (y * width + x)]`.
#[derive(Clone, Debug, PartialEq)]
pub struct HdrImage {
    width: usize,
    height: usize,
    data: Vec<f32>,
}

impl HdrImage {
    /// A black image of the given size.
    pub fn new(width: usize, height: usize) -> Self {
        HdrImage {
            width,
            height,
            data: vec![0.0; width * height * 3],
        }
    }

    /// Wraps interleaved RGB data; fails when the length does not match the size.
    pub fn from_vec(width: usize, height: usize, data: Vec<f32>) -> Result<Self> {
        if data.len() != width * height * 3 {
            return Err(Error::Invalid(format!(
                "HDR buffer of {} floats does not hold {}x{} RGB pixels",
                data.len(),
                width,
                height
            )));
        }
        Ok(HdrImage {
            width,
            height,
            data,
        })
    }

    /// An image filled by calling `f(x, y)` for every pixel.
    pub fn from_fn(
        width: usize,
        height: usize,
        mut f: impl FnMut(usize, usize) -> [f32; 3],
    ) -> Self {
        let mut img = HdrImage::new(width, height);
        for y in 0..height {
            for x in 0..width {
                img.set(x, y, f(x, y));
            }
        }
        img
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }
    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }
    /// Interleaved RGB samples.
    pub fn data(&self) -> &[f32] {
        &self.data
    }
    /// Mutable interleaved RGB samples.
    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }
    /// Consumes the image, returning its samples.
    pub fn into_vec(self) -> Vec<f32> {
        self.data
    }
    /// The pixel at `(x, y)`.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> [f32; 3] {
        let i = 3 * (y * self.width + x);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }
    /// Sets the pixel at `(x, y)`.
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, v: [f32; 3]) {
        let i = 3 * (y * self.width + x);
        self.data[i..i + 3].copy_from_slice(&v);
    }
    /// Iterates over pixels as `[r, g, b]`.
    pub fn pixels(&self) -> impl Iterator<Item = [f32; 3]> + '_ {
        self.data.chunks_exact(3).map(|c| [c[0], c[1], c[2]])
    }
    /// Mutable rows, each `3 * width` floats, for parallel fills.
    pub fn rows_mut(&mut self) -> std::slice::ChunksExactMut<'_, f32> {
        let w = 3 * self.width.max(1);
        self.data.chunks_exact_mut(w)
    }
    /// Number of samples that are NaN, infinite or negative.
    pub fn count_invalid(&self) -> usize {
        self.data
            .iter()
            .filter(|v| !v.is_finite() || **v < 0.0)
            .count()
    }
    /// Replaces NaN, infinite and negative samples by zero (+inf by the largest
    /// finite sample) and returns how many were changed, so callers can report it.
    pub fn repair_invalid(&mut self) -> usize {
        let max_finite = self
            .data
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(0.0f32, f32::max);
        let mut n = 0;
        for v in &mut self.data {
            if v.is_nan() || *v < 0.0 {
                *v = 0.0;
                n += 1;
            } else if v.is_infinite() {
                *v = max_finite;
                n += 1;
            }
        }
        n
    }
}

/// Rec. 709 / sRGB luminance of a linear RGB triple.
#[inline]
pub fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// An 8-bit RGB image as a camera stores it (display-referred, clipped).
#[derive(Clone, Debug, PartialEq)]
pub struct SdrImage {
    width: usize,
    height: usize,
    data: Vec<u8>,
}

impl SdrImage {
    /// A black image of the given size.
    pub fn new(width: usize, height: usize) -> Self {
        SdrImage {
            width,
            height,
            data: vec![0; width * height * 3],
        }
    }
    /// Wraps interleaved RGB bytes; fails when the length does not match the size.
    pub fn from_vec(width: usize, height: usize, data: Vec<u8>) -> Result<Self> {
        if data.len() != width * height * 3 {
            return Err(Error::Invalid(format!(
                "SDR buffer of {} bytes does not hold {}x{} RGB pixels",
                data.len(),
                width,
                height
            )));
        }
        Ok(SdrImage {
            width,
            height,
            data,
        })
    }
    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }
    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }
    /// Interleaved RGB bytes.
    pub fn data(&self) -> &[u8] {
        &self.data
    }
    /// Mutable interleaved RGB bytes.
    pub fn data_mut(&mut self) -> &mut [u8] {
        &mut self.data
    }
    /// The pixel at `(x, y)`.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> [u8; 3] {
        let i = 3 * (y * self.width + x);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }
}
