//! Portable float map (PFM): `PF` (RGB) or `Pf` (gray), width and height, a scale
//! whose sign gives the byte order (negative = little endian), then raw `f32`
//! rows stored bottom-up. The scale's magnitude is ignored, as most tools do.

use super::{check_dims, check_finite, check_nonempty, Limits};
use crate::error::{Error, Result};
use crate::image::HdrImage;
use std::path::Path;

/// Byte order of the samples in a PFM file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Endian {
    /// Little endian (scale written as `-1`), what lumiprobe writes.
    Little,
    /// Big endian (positive scale).
    Big,
}

/// Decodes a PFM file held in memory; gray (`Pf`) files are replicated to RGB.
pub fn decode(bytes: &[u8], name: &Path, limits: &Limits) -> Result<HdrImage> {
    let channels = match bytes.get(..2) {
        Some(b"PF") => 3usize,
        Some(b"Pf") => 1usize,
        Some(m) => {
            return Err(Error::format(
                name,
                format!(
                    "not a PFM file: magic {:?}, expected \"PF\" or \"Pf\"",
                    String::from_utf8_lossy(m)
                ),
            ))
        }
        None => {
            return Err(Error::format(
                name,
                "truncated PFM: file ends inside the magic",
            ))
        }
    };
    let mut pos = 2;
    // The magic must be followed by whitespace.
    if !bytes.get(pos).is_some_and(|b| b.is_ascii_whitespace()) {
        return Err(Error::format(
            name,
            if pos >= bytes.len() {
                "truncated PFM: file ends after the magic".to_string()
            } else {
                "not a PFM file: no whitespace after the magic".to_string()
            },
        ));
    }
    let width = token(bytes, &mut pos, name, "width")?;
    let height = token(bytes, &mut pos, name, "height")?;
    let scale_tok = token(bytes, &mut pos, name, "scale")?;
    let parse_dim = |t: &str, what: &str| {
        t.parse::<u64>()
            .map_err(|_| Error::format(name, format!("bad PFM {what} {t:?}")))
    };
    let (w, h) = (parse_dim(&width, "width")?, parse_dim(&height, "height")?);
    let scale: f64 = scale_tok
        .parse()
        .map_err(|_| Error::format(name, format!("bad PFM scale {scale_tok:?}")))?;
    if !scale.is_finite() || scale == 0.0 {
        return Err(Error::format(
            name,
            format!("bad PFM scale {scale_tok:?}: must be a finite non-zero number"),
        ));
    }
    let endian = if scale < 0.0 {
        Endian::Little
    } else {
        Endian::Big
    };
    let (w, h) = check_dims(name, w, h, limits)?;
    // Exactly one whitespace byte separates the scale from the samples.
    pos += 1;
    let need = w
        .checked_mul(h)
        .and_then(|p| p.checked_mul(channels * 4))
        .ok_or_else(|| Error::format(name, "PFM size overflows"))?;
    let data = bytes.get(pos..).unwrap_or(&[]);
    if data.len() < need {
        return Err(Error::format(
            name,
            format!(
                "truncated PFM: {w}x{h}x{channels} samples need {need} bytes of data, file has {}",
                data.len()
            ),
        ));
    }
    let mut img = HdrImage::new(w, h);
    let row_bytes = w * channels * 4;
    for (file_row, src) in data[..need].chunks_exact(row_bytes).enumerate() {
        let y = h - 1 - file_row;
        let dst = &mut img.data_mut()[3 * w * y..3 * w * (y + 1)];
        let mut samples = src.chunks_exact(4).map(|c| {
            let b = [c[0], c[1], c[2], c[3]];
            match endian {
                Endian::Little => f32::from_le_bytes(b),
                Endian::Big => f32::from_be_bytes(b),
            }
        });
        if channels == 3 {
            for (d, s) in dst.iter_mut().zip(samples) {
                *d = s;
            }
        } else {
            for px in dst.chunks_exact_mut(3) {
                let v = samples.next().unwrap_or(0.0);
                px.copy_from_slice(&[v, v, v]);
            }
        }
    }
    Ok(img)
}

/// Next whitespace-delimited header token; the terminating whitespace byte is left
/// at `*pos`.
fn token(bytes: &[u8], pos: &mut usize, name: &Path, what: &str) -> Result<String> {
    while bytes.get(*pos).is_some_and(|b| b.is_ascii_whitespace()) {
        *pos += 1;
    }
    let start = *pos;
    while bytes.get(*pos).is_some_and(|b| !b.is_ascii_whitespace()) {
        *pos += 1;
        if *pos - start > 64 {
            return Err(Error::format(
                name,
                format!("bad PFM header: {what} field is too long"),
            ));
        }
    }
    if *pos >= bytes.len() {
        return Err(Error::format(
            name,
            format!("truncated PFM: file ends in the header while reading the {what}"),
        ));
    }
    Ok(String::from_utf8_lossy(&bytes[start..*pos]).into_owned())
}

/// Encodes an image as PFM RGB with the given byte order.
pub fn encode(img: &HdrImage, endian: Endian) -> Vec<u8> {
    let (w, h) = (img.width(), img.height());
    let scale = match endian {
        Endian::Little => "-1.0",
        Endian::Big => "1.0",
    };
    let header = format!("PF\n{w} {h}\n{scale}\n");
    let mut out = Vec::with_capacity(header.len() + img.data().len() * 4);
    out.extend_from_slice(header.as_bytes());
    let stride = 3 * w;
    if stride > 0 {
        for row in img.data().chunks_exact(stride).rev() {
            for v in row {
                out.extend_from_slice(&match endian {
                    Endian::Little => v.to_le_bytes(),
                    Endian::Big => v.to_be_bytes(),
                });
            }
        }
    }
    out
}

/// Writes a little-endian RGB PFM atomically; NaN/Inf samples are refused.
pub fn write(path: &Path, img: &HdrImage) -> Result<()> {
    check_nonempty(path, img.width(), img.height())?;
    check_finite(path, img)?;
    crate::fsutil::write_atomic(path, &encode(img, Endian::Little))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> HdrImage {
        HdrImage::from_fn(3, 2, |x, y| {
            [x as f32, y as f32 * 1e6, -0.5 + x as f32 * 1e-7]
        })
    }

    #[test]
    fn both_byte_orders_round_trip_exactly() {
        let n = Path::new("t.pfm");
        for e in [Endian::Little, Endian::Big] {
            let back = decode(&encode(&sample(), e), n, &Limits::default()).unwrap();
            assert_eq!(back, sample());
        }
    }

    #[test]
    fn rows_are_stored_bottom_up() {
        let bytes = encode(&sample(), Endian::Little);
        let header_len = "PF\n3 2\n-1.0\n".len();
        // First stored sample is pixel (0, 1), green = 1e6 at offset 4.
        let g = f32::from_le_bytes(bytes[header_len + 4..header_len + 8].try_into().unwrap());
        assert_eq!(g, 1e6);
    }

    #[test]
    fn gray_is_replicated() {
        let mut b = b"Pf\n2 1\n-1\n".to_vec();
        b.extend_from_slice(&2.5f32.to_le_bytes());
        b.extend_from_slice(&7.0f32.to_le_bytes());
        let img = decode(&b, Path::new("g.pfm"), &Limits::default()).unwrap();
        assert_eq!(img.get(0, 0), [2.5; 3]);
        assert_eq!(img.get(1, 0), [7.0; 3]);
    }

    #[test]
    fn bad_scales_are_rejected() {
        for s in ["0", "nan", "inf", "abc", "-0.0"] {
            let b = format!("PF\n1 1\n{s}\n____________");
            let e = decode(b.as_bytes(), Path::new("s.pfm"), &Limits::default()).unwrap_err();
            assert!(
                e.to_string().contains("s.pfm") && e.to_string().contains("scale"),
                "{e}"
            );
        }
    }
}
