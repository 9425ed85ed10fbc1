//! The exposure tags of an image's Exif block, read with the `kamadak-exif`
//! crate from any container it knows (JPEG, TIFF, HEIF, PNG, WebP).
//!
//! Merging brackets needs each frame's exposure time: `ExposureTime`
//! (`0x829A`), with `FNumber` (`0x829D`) and ISO (`0x8827`) for the report.
//! Cameras store them in the Exif sub-IFD; a tag found in IFD0 is taken as
//! well. Malformed data is an [`Error::Format`] naming the file, never a panic.

use crate::error::{Error, Result};
use std::path::Path;

/// The Exif tag holding the exposure time in seconds (RATIONAL).
pub const TAG_EXPOSURE_TIME: u16 = 0x829A;
/// The Exif tag holding the aperture f-number (RATIONAL).
pub const TAG_F_NUMBER: u16 = 0x829D;
/// The Exif tag holding the ISO sensitivity (SHORT or LONG).
pub const TAG_ISO: u16 = 0x8827;
/// The IFD0 tag pointing to the Exif sub-IFD.
pub const TAG_EXIF_IFD: u16 = 0x8769;

/// Exposure settings found in a file's Exif block; `None` where a tag is absent.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ExifExposure {
    /// Exposure time in seconds (`ExposureTime`).
    pub exposure_time_s: Option<f64>,
    /// Aperture f-number (`FNumber`).
    pub f_number: Option<f64>,
    /// ISO sensitivity (`PhotographicSensitivity` / `ISOSpeedRatings`).
    pub iso: Option<u32>,
}

/// Reads the exposure tags of the image at `path` (see [`parse`]).
pub fn read_exposure(path: &Path) -> Result<ExifExposure> {
    let bytes = crate::fsutil::read(path)?;
    parse(&bytes, path)
}

/// Reads the exposure tags of an image held in memory; `name` is used in
/// errors.
///
/// An image without an Exif block gives all fields `None`; a file that is no
/// image `kamadak-exif` knows, or whose Exif block is inconsistent, is an error
/// naming `name`.
pub fn parse(bytes: &[u8], name: &Path) -> Result<ExifExposure> {
    let fail = |m: String| Error::format(name, format!("Exif: {m}"));
    let exif = match exif::Reader::new().read_from_container(&mut std::io::Cursor::new(bytes)) {
        Ok(e) => e,
        Err(exif::Error::NotFound(_)) => return Ok(ExifExposure::default()),
        Err(e) => return Err(fail(e.to_string())),
    };
    let rational = |f: &exif::Field| -> Result<Option<f64>> {
        match &f.value {
            exif::Value::Rational(v) => match v.first() {
                Some(r) if r.denom == 0 => Err(fail(format!(
                    "tag {:#06x} has a zero denominator",
                    f.tag.number()
                ))),
                Some(r) => Ok(Some(r.num as f64 / r.denom as f64)),
                None => Ok(None),
            },
            _ => Err(fail(format!(
                "tag {:#06x} is not a rational number",
                f.tag.number()
            ))),
        }
    };
    let mut out = ExifExposure::default();
    for f in exif.fields().filter(|f| f.ifd_num == exif::In::PRIMARY) {
        match f.tag.number() {
            TAG_EXPOSURE_TIME => out.exposure_time_s = out.exposure_time_s.or(rational(f)?),
            TAG_F_NUMBER => out.f_number = out.f_number.or(rational(f)?),
            TAG_ISO => {
                out.iso = out.iso.or(match &f.value {
                    exif::Value::Short(v) => v.first().map(|&x| x as u32),
                    exif::Value::Long(v) => v.first().copied(),
                    _ => None,
                })
            }
            _ => {}
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal JPEG header with an Exif block in the given byte order.
    fn jpeg_with_exif(little: bool, in_ifd0: bool) -> Vec<u8> {
        let mut t: Vec<u8> = Vec::new();
        let p16 = |v: u16, t: &mut Vec<u8>| {
            t.extend_from_slice(&if little {
                v.to_le_bytes()
            } else {
                v.to_be_bytes()
            })
        };
        let p32 = |v: u32, t: &mut Vec<u8>| {
            t.extend_from_slice(&if little {
                v.to_le_bytes()
            } else {
                v.to_be_bytes()
            })
        };
        t.extend_from_slice(if little { b"II" } else { b"MM" });
        p16(42, &mut t);
        p32(8, &mut t);
        // IFD0 at 8: one entry.
        p16(1, &mut t);
        if in_ifd0 {
            // ExposureTime directly in IFD0, value at 26.
            p16(TAG_EXPOSURE_TIME, &mut t);
            p16(5, &mut t);
            p32(1, &mut t);
            p32(26, &mut t);
            p32(0, &mut t);
            p32(1, &mut t);
            p32(250, &mut t);
        } else {
            p16(TAG_EXIF_IFD, &mut t);
            p16(4, &mut t);
            p32(1, &mut t);
            p32(26, &mut t);
            p32(0, &mut t);
            // Exif IFD at 26: three entries, values after (26 + 2 + 36 + 4 = 68).
            p16(3, &mut t);
            p16(TAG_EXPOSURE_TIME, &mut t);
            p16(5, &mut t);
            p32(1, &mut t);
            p32(68, &mut t);
            p16(TAG_F_NUMBER, &mut t);
            p16(5, &mut t);
            p32(1, &mut t);
            p32(76, &mut t);
            p16(TAG_ISO, &mut t);
            p16(3, &mut t);
            p32(1, &mut t);
            p16(200, &mut t);
            p16(0, &mut t);
            p32(0, &mut t);
            p32(1, &mut t);
            p32(250, &mut t);
            p32(22, &mut t);
            p32(10, &mut t);
        }
        let mut j = vec![0xff, 0xd8, 0xff, 0xe1];
        let len = (t.len() + 8) as u16;
        j.extend_from_slice(&len.to_be_bytes());
        j.extend_from_slice(b"Exif\0\0");
        j.extend_from_slice(&t);
        j.extend_from_slice(&[0xff, 0xda, 0x00, 0x02, 0xff, 0xd9]);
        j
    }

    #[test]
    fn both_byte_orders() {
        for little in [true, false] {
            let e = parse(&jpeg_with_exif(little, false), Path::new("a.jpg")).unwrap();
            assert_eq!(e.exposure_time_s, Some(1.0 / 250.0));
            assert_eq!(e.f_number, Some(2.2));
            assert_eq!(e.iso, Some(200));
            let e = parse(&jpeg_with_exif(little, true), Path::new("a.jpg")).unwrap();
            assert_eq!(e.exposure_time_s, Some(1.0 / 250.0));
            assert_eq!(e.f_number, None);
        }
    }

    #[test]
    fn no_exif_is_not_an_error() {
        let j = [
            0xff, 0xd8, 0xff, 0xe0, 0x00, 0x04, 0, 0, 0xff, 0xda, 0, 2, 0xff, 0xd9,
        ];
        assert_eq!(
            parse(&j, Path::new("b.jpg")).unwrap(),
            ExifExposure::default()
        );
        let e = parse(b"GIF89a", Path::new("c.gif")).unwrap_err();
        assert!(e.to_string().contains("c.gif"), "{e}");
    }

    #[test]
    fn truncations_and_random_bytes_never_panic() {
        let good = jpeg_with_exif(false, false);
        for cut in 0..good.len() {
            if let Err(e) = parse(&good[..cut], Path::new("cut.jpg")) {
                assert!(e.to_string().contains("cut.jpg"), "{e}");
            }
        }
        // Flip bytes one at a time and in random groups (xorshift, fixed seed).
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        for i in 0..good.len() {
            for v in [0u8, 0xff, 0x7f, 0x80] {
                let mut b = good.clone();
                b[i] = v;
                let _ = parse(&b, Path::new("x.jpg"));
            }
        }
        for _ in 0..20_000 {
            let mut b = good.clone();
            for _ in 0..1 + next() % 6 {
                let i = (next() % b.len() as u64) as usize;
                b[i] = next() as u8;
            }
            let cut = (next() % (b.len() as u64 + 1)) as usize;
            let _ = parse(&b[..cut], Path::new("x.jpg"));
            let junk: Vec<u8> = (0..next() % 200).map(|_| next() as u8).collect();
            let mut j = vec![0xff, 0xd8];
            j.extend_from_slice(&junk);
            let _ = parse(&j, Path::new("x.jpg"));
        }
    }

    #[test]
    fn zero_denominator_is_an_error() {
        let mut j = jpeg_with_exif(true, true);
        // The denominator is the last 4 bytes before the scan marker.
        let n = j.len();
        j[n - 10..n - 6].copy_from_slice(&[0, 0, 0, 0]);
        let e = parse(&j, Path::new("z.jpg")).unwrap_err();
        assert!(
            e.to_string().contains("z.jpg") && e.to_string().contains("zero"),
            "{e}"
        );
    }
}
