//! 8-bit PNG and JPEG via the `image` crate, plus the bridge between 8-bit codes
//! and linear radiance through a camera response.
//!
//! Before decoding, the file's structure is walked (PNG chunks up to `IEND`,
//! JPEG segments up to `EOI`) so truncated files fail instead of decoding
//! partially, and the declared size is checked against [`Limits`].

use super::{check_dims, check_nonempty, guard_panic, Format, Limits};
use crate::error::{Error, Result};
use crate::image::{HdrImage, SdrImage};
use crate::tonemap::Response;
use image::ImageEncoder;
use std::io::Cursor;
use std::path::Path;

/// JPEG quality used by [`super::write_sdr`].
pub const DEFAULT_JPEG_QUALITY: u8 = 95;

/// Decodes a PNG or JPEG held in memory to 8-bit RGB (gray is replicated, alpha
/// dropped, 16-bit reduced to 8-bit).
pub fn decode(bytes: &[u8], name: &Path, format: Format, limits: &Limits) -> Result<SdrImage> {
    let image_format = match format {
        Format::Png => {
            check_png_structure(bytes).map_err(|m| Error::format(name, m))?;
            image::ImageFormat::Png
        }
        Format::Jpeg => {
            check_jpeg_structure(bytes).map_err(|m| Error::format(name, m))?;
            image::ImageFormat::Jpeg
        }
        other => {
            return Err(Error::format(
                name,
                format!("{} is not an 8-bit format", other.name()),
            ))
        }
    };
    let what = format.name();
    guard_panic(name, what, || {
        let fail = |e: image::ImageError| Error::format(name, format!("cannot decode {what}: {e}"));
        let (w, h) = image::ImageReader::with_format(Cursor::new(bytes), image_format)
            .into_dimensions()
            .map_err(fail)?;
        check_dims(name, w as u64, h as u64, limits)?;
        let mut reader = image::ImageReader::with_format(Cursor::new(bytes), image_format);
        let mut lim = image::Limits::default();
        lim.max_image_width = Some(w);
        lim.max_image_height = Some(h);
        // Room for the decoded buffer at 16-bit RGBA plus decoder scratch.
        lim.max_alloc = Some((w as u64 * h as u64).saturating_mul(16).max(64 << 20));
        reader.limits(lim);
        let img = reader.decode().map_err(fail)?.into_rgb8();
        let (w, h) = img.dimensions();
        SdrImage::from_vec(w as usize, h as usize, img.into_raw())
    })
}

/// Walks PNG chunks from the signature to `IEND`; any chunk running past the
/// end of the data means the file is truncated.
fn check_png_structure(b: &[u8]) -> std::result::Result<(), String> {
    if !b.starts_with(b"\x89PNG\r\n\x1a\n") {
        return Err("not a PNG file: bad signature".into());
    }
    let mut pos = 8usize;
    let mut first = true;
    loop {
        let head = b
            .get(pos..pos + 8)
            .ok_or_else(|| format!("truncated PNG: file ends at byte {} before IEND", b.len()))?;
        let len = u32::from_be_bytes([head[0], head[1], head[2], head[3]]) as usize;
        let kind = &head[4..8];
        let kind_s = String::from_utf8_lossy(kind).into_owned();
        if len > 0x7fff_ffff {
            return Err(format!(
                "bad PNG chunk {kind_s:?}: length {len} out of range"
            ));
        }
        if first && kind != b"IHDR" {
            return Err(format!("bad PNG: first chunk is {kind_s:?}, expected IHDR"));
        }
        first = false;
        let end = pos + 12 + len;
        if end > b.len() {
            return Err(format!(
                "truncated PNG: chunk {kind_s:?} at byte {pos} needs {} bytes, file has {}",
                12 + len,
                b.len() - pos
            ));
        }
        if kind == b"IEND" {
            return Ok(());
        }
        pos = end;
    }
}

/// Walks JPEG marker segments and entropy-coded data from `SOI` to `EOI`.
fn check_jpeg_structure(b: &[u8]) -> std::result::Result<(), String> {
    if !b.starts_with(&[0xff, 0xd8]) {
        return Err("not a JPEG file: missing SOI marker".into());
    }
    let truncated = || {
        format!(
            "truncated JPEG: no end-of-image marker in {} bytes",
            b.len()
        )
    };
    let mut pos = 2usize;
    loop {
        match b.get(pos) {
            None => return Err(truncated()),
            Some(0xff) => {}
            Some(x) => {
                return Err(format!(
                    "bad JPEG: expected a marker at byte {pos}, found {x:#04x}"
                ))
            }
        }
        // Skip fill bytes.
        while b.get(pos + 1) == Some(&0xff) {
            pos += 1;
        }
        let marker = *b.get(pos + 1).ok_or_else(truncated)?;
        match marker {
            0xd9 => return Ok(()),
            0x01 | 0xd0..=0xd7 => pos += 2,
            0x00 => return Err(format!("bad JPEG: stray 0xff00 at byte {pos}")),
            _ => {
                let l = b.get(pos + 2..pos + 4).ok_or_else(truncated)?;
                let len = u16::from_be_bytes([l[0], l[1]]) as usize;
                if len < 2 {
                    return Err(format!("bad JPEG: segment length {len} at byte {pos}"));
                }
                let end = pos + 2 + len;
                if end > b.len() {
                    return Err(truncated());
                }
                pos = end;
                if marker == 0xda {
                    // Entropy-coded data: 0xff is followed by 0x00 (stuffing), RSTn,
                    // or fill bytes; anything else is the next marker.
                    loop {
                        let off = b.get(pos..).and_then(|r| r.iter().position(|&x| x == 0xff));
                        let Some(off) = off else {
                            return Err(truncated());
                        };
                        pos += off;
                        match b.get(pos + 1) {
                            None => return Err(truncated()),
                            Some(0x00) | Some(0xd0..=0xd7) => pos += 2,
                            Some(0xff) => pos += 1,
                            Some(_) => break,
                        }
                    }
                }
            }
        }
    }
}

fn check_encodable(path: &Path, img: &SdrImage, max_side: usize) -> Result<(u32, u32)> {
    check_nonempty(path, img.width(), img.height())?;
    if img.width() > max_side || img.height() > max_side {
        return Err(Error::limit(
            Some(path),
            format!("an image of {}x{}", img.width(), img.height()),
            format!("the format's largest side, {max_side}"),
        ));
    }
    Ok((img.width() as u32, img.height() as u32))
}

/// Encodes an RGB image as PNG bytes.
pub fn encode_png(img: &SdrImage, name: &Path) -> Result<Vec<u8>> {
    let (w, h) = check_encodable(name, img, 0x7fff_ffff)?;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(img.data(), w, h, image::ExtendedColorType::Rgb8)
        .map_err(|e| Error::Invalid(format!("{}: cannot encode PNG: {e}", name.display())))?;
    Ok(out)
}

/// Encodes an RGB image as JPEG bytes with `quality` in 1..=100.
pub fn encode_jpeg(img: &SdrImage, name: &Path, quality: u8) -> Result<Vec<u8>> {
    let (w, h) = check_encodable(name, img, 65535)?;
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality.clamp(1, 100))
        .write_image(img.data(), w, h, image::ExtendedColorType::Rgb8)
        .map_err(|e| Error::Invalid(format!("{}: cannot encode JPEG: {e}", name.display())))?;
    Ok(out)
}

/// Writes a PNG atomically.
pub fn write_png(path: &Path, img: &SdrImage) -> Result<()> {
    crate::fsutil::write_atomic(path, &encode_png(img, path)?)
}

/// Writes a JPEG atomically with `quality` in 1..=100.
pub fn write_jpeg(path: &Path, img: &SdrImage, quality: u8) -> Result<()> {
    crate::fsutil::write_atomic(path, &encode_jpeg(img, path, quality)?)
}

/// Linear radiance of an 8-bit frame: `response.decode(code / 255) / gain`.
/// `gain` (the frame's exposure relative to the probe) must be positive.
pub fn sdr_to_linear(img: &SdrImage, response: &Response, gain: f32) -> HdrImage {
    let lut = response.decode_lut();
    let data = img.data().iter().map(|&c| lut[c as usize] / gain).collect();
    HdrImage::from_vec(img.width(), img.height(), data)
        .unwrap_or_else(|_| HdrImage::new(img.width(), img.height()))
}

/// [`sdr_to_linear`] with a gain per channel (a frame's own exposure and white
/// balance): channel `c` is `response⁻¹(code / 255) / gain[c]`.
pub fn sdr_to_linear_rgb(img: &SdrImage, response: &Response, gain: [f32; 3]) -> HdrImage {
    let lut = response.decode_lut();
    let data = img
        .data()
        .iter()
        .enumerate()
        .map(|(i, &c)| lut[c as usize] / gain[i % 3])
        .collect();
    HdrImage::from_vec(img.width(), img.height(), data)
        .unwrap_or_else(|_| HdrImage::new(img.width(), img.height()))
}

/// 8-bit frame a camera with `response` would record from linear radiance at
/// exposure `gain`: `round(255 * response.encode(v * gain))`.
pub fn linear_to_sdr(img: &HdrImage, response: &Response, gain: f32) -> SdrImage {
    let data = img
        .data()
        .iter()
        .map(|&v| {
            (response.encode(v * gain) * 255.0)
                .round()
                .clamp(0.0, 255.0) as u8
        })
        .collect();
    SdrImage::from_vec(img.width(), img.height(), data)
        .unwrap_or_else(|_| SdrImage::new(img.width(), img.height()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> SdrImage {
        let data = (0..4 * 3 * 3).map(|i| (i * 37 % 256) as u8).collect();
        SdrImage::from_vec(4, 3, data).unwrap()
    }

    #[test]
    fn png_round_trip_is_exact() {
        let n = Path::new("a.png");
        let b = encode_png(&sample(), n).unwrap();
        assert_eq!(
            decode(&b, n, Format::Png, &Limits::default()).unwrap(),
            sample()
        );
    }

    #[test]
    fn every_png_and_jpeg_prefix_fails_structure_check() {
        let n = Path::new("a");
        let png = encode_png(&sample(), n).unwrap();
        let jpg = encode_jpeg(&sample(), n, 90).unwrap();
        assert!(check_png_structure(&png).is_ok());
        assert!(check_jpeg_structure(&jpg).is_ok());
        for k in 0..png.len() {
            assert!(check_png_structure(&png[..k]).is_err(), "png prefix {k}");
        }
        for k in 0..jpg.len() {
            assert!(check_jpeg_structure(&jpg[..k]).is_err(), "jpeg prefix {k}");
        }
    }

    #[test]
    fn response_bridge_round_trips_codes() {
        let r = Response::Srgb;
        let lin = sdr_to_linear(&sample(), &r, 2.0);
        assert!((lin.data()[1] - r.decode(37.0 / 255.0) / 2.0).abs() < 1e-7);
        assert_eq!(linear_to_sdr(&lin, &r, 2.0), sample());
    }
}
