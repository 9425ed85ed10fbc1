//! A small, bounded reader for the exposure tags of a JPEG's Exif block.
//!
//! Merging brackets needs each frame's exposure time; cameras store it in the
//! Exif sub-IFD of the APP1 segment (`Exif\0\0` + a TIFF structure). This reader
//! walks the JPEG segments up to the first scan, finds that APP1 block, reads the
//! TIFF header in either byte order (`II` or `MM`), scans IFD0 and follows its
//! ExifIFD pointer (tag `0x8769`) to read `ExposureTime` (`0x829A`), `FNumber`
//! (`0x829D`) and ISO (`0x8827`). Every offset is bounds-checked, IFD entry counts
//! are capped and each IFD is visited once, so malformed or hostile data yields an
//! [`Error::Format`] naming the file, never a panic or a long loop.

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

/// Largest number of entries accepted in one IFD (real files have a few dozen).
const MAX_IFD_ENTRIES: usize = 1024;

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

/// Reads the exposure tags of the JPEG at `path` (see [`parse_jpeg`]).
pub fn read_exposure(path: &Path) -> Result<ExifExposure> {
    let bytes = crate::fsutil::read(path)?;
    parse_jpeg(&bytes, path)
}

/// Reads the exposure tags of a JPEG held in memory; `name` is used in errors.
///
/// A JPEG without an Exif block gives all fields `None`; a file that is not a
/// JPEG, or whose Exif block is inconsistent, is an error naming `name`.
pub fn parse_jpeg(bytes: &[u8], name: &Path) -> Result<ExifExposure> {
    let fail = |m: String| Error::format(name, format!("Exif: {m}"));
    if !bytes.starts_with(&[0xff, 0xd8]) {
        return Err(fail("not a JPEG file (no SOI marker)".into()));
    }
    let mut pos = 2usize;
    loop {
        // Markers may be preceded by fill bytes 0xff.
        while bytes.get(pos) == Some(&0xff) && bytes.get(pos + 1) == Some(&0xff) {
            pos += 1;
        }
        let (Some(&m0), Some(&marker)) = (bytes.get(pos), bytes.get(pos + 1)) else {
            // Ran out of data before a scan: no Exif block.
            return Ok(ExifExposure::default());
        };
        if m0 != 0xff {
            return Err(fail(format!("expected a marker at byte {pos}")));
        }
        pos += 2;
        match marker {
            // Start of scan or end of image: the metadata segments are over.
            0xda | 0xd9 => return Ok(ExifExposure::default()),
            // Standalone markers without a length.
            0x01 | 0xd0..=0xd7 => continue,
            _ => {}
        }
        let len = read_u16_be(bytes, pos).ok_or_else(|| {
            fail(format!(
                "truncated segment header for marker {marker:#04x} at byte {pos}"
            ))
        })? as usize;
        if len < 2 {
            return Err(fail(format!(
                "segment length {len} at byte {pos} is invalid"
            )));
        }
        let body = bytes.get(pos + 2..pos + len).ok_or_else(|| {
            fail(format!(
                "segment {marker:#04x} at byte {pos} runs past the end of the file"
            ))
        })?;
        if marker == 0xe1 && body.starts_with(b"Exif\0\0") {
            return parse_tiff(&body[6..]).map_err(fail);
        }
        pos += len;
    }
}

/// Byte order of a TIFF structure.
#[derive(Clone, Copy)]
enum Order {
    Little,
    Big,
}

fn read_u16_be(b: &[u8], at: usize) -> Option<u16> {
    let s = b.get(at..at.checked_add(2)?)?;
    Some(u16::from_be_bytes([s[0], s[1]]))
}

impl Order {
    fn u16(self, b: &[u8], at: usize) -> Option<u16> {
        let s = b.get(at..at.checked_add(2)?)?;
        let a = [s[0], s[1]];
        Some(match self {
            Order::Little => u16::from_le_bytes(a),
            Order::Big => u16::from_be_bytes(a),
        })
    }
    fn u32(self, b: &[u8], at: usize) -> Option<u32> {
        let s = b.get(at..at.checked_add(4)?)?;
        let a = [s[0], s[1], s[2], s[3]];
        Some(match self {
            Order::Little => u32::from_le_bytes(a),
            Order::Big => u32::from_be_bytes(a),
        })
    }
}

/// One 12-byte IFD entry.
struct Entry {
    tag: u16,
    kind: u16,
    count: u32,
    /// Offset of the 4-byte value/offset field inside the TIFF block.
    field: usize,
}

/// Reads the exposure tags from a TIFF structure (the Exif payload).
fn parse_tiff(t: &[u8]) -> std::result::Result<ExifExposure, String> {
    let order = match t.get(0..2) {
        Some(b"II") => Order::Little,
        Some(b"MM") => Order::Big,
        _ => return Err("bad TIFF byte-order mark (expected II or MM)".into()),
    };
    if order.u16(t, 2) != Some(42) {
        return Err("bad TIFF magic number (expected 42)".into());
    }
    let ifd0 = order.u32(t, 4).ok_or("truncated TIFF header")? as usize;
    let mut out = ExifExposure::default();
    let mut exif_ifd = None;
    for e in read_ifd(t, order, ifd0, "IFD0")? {
        if e.tag == TAG_EXIF_IFD {
            exif_ifd = Some(order.u32(t, e.field).ok_or("truncated ExifIFD pointer")? as usize);
        } else {
            // Some writers put the exposure tags in IFD0; accept them there too.
            read_tag(t, order, &e, &mut out)?;
        }
    }
    if let Some(off) = exif_ifd {
        if off == ifd0 {
            return Err("ExifIFD pointer points back at IFD0".into());
        }
        for e in read_ifd(t, order, off, "ExifIFD")? {
            read_tag(t, order, &e, &mut out)?;
        }
    }
    Ok(out)
}

/// The entries of the IFD at `off`, bounds-checked.
fn read_ifd(
    t: &[u8],
    order: Order,
    off: usize,
    what: &str,
) -> std::result::Result<Vec<Entry>, String> {
    let n = order
        .u16(t, off)
        .ok_or_else(|| format!("{what} offset {off} is outside the Exif block"))?
        as usize;
    if n > MAX_IFD_ENTRIES {
        return Err(format!(
            "{what} declares {n} entries (more than {MAX_IFD_ENTRIES})"
        ));
    }
    let end = off + 2 + 12 * n;
    if end > t.len() {
        return Err(format!(
            "{what} with {n} entries runs past the end of the Exif block"
        ));
    }
    Ok((0..n)
        .map(|i| {
            let at = off + 2 + 12 * i;
            Entry {
                tag: order.u16(t, at).unwrap_or(0),
                kind: order.u16(t, at + 2).unwrap_or(0),
                count: order.u32(t, at + 4).unwrap_or(0),
                field: at + 8,
            }
        })
        .collect())
}

/// Stores the value of `e` in `out` when it is one of the exposure tags.
fn read_tag(
    t: &[u8],
    order: Order,
    e: &Entry,
    out: &mut ExifExposure,
) -> std::result::Result<(), String> {
    match e.tag {
        TAG_EXPOSURE_TIME => out.exposure_time_s = Some(rational(t, order, e, "ExposureTime")?),
        TAG_F_NUMBER => out.f_number = Some(rational(t, order, e, "FNumber")?),
        TAG_ISO => {
            if e.count == 0 {
                return Err("ISO tag has no value".into());
            }
            out.iso = Some(match e.kind {
                3 => order.u16(t, e.field).ok_or("truncated ISO value")? as u32,
                4 => order.u32(t, e.field).ok_or("truncated ISO value")?,
                k => return Err(format!("ISO tag has type {k}, expected SHORT or LONG")),
            });
        }
        _ => {}
    }
    Ok(())
}

/// The first value of a RATIONAL (type 5) or SRATIONAL (type 10) entry.
fn rational(t: &[u8], order: Order, e: &Entry, what: &str) -> std::result::Result<f64, String> {
    if e.count == 0 {
        return Err(format!("{what} has no value"));
    }
    let off = order
        .u32(t, e.field)
        .ok_or_else(|| format!("truncated {what} entry"))? as usize;
    let num = order.u32(t, off);
    let den = off.checked_add(4).and_then(|o| order.u32(t, o));
    let (Some(num), Some(den)) = (num, den) else {
        return Err(format!(
            "{what} value at offset {off} is outside the Exif block"
        ));
    };
    let (num, den) = match e.kind {
        5 => (num as f64, den as f64),
        10 => (num as i32 as f64, den as i32 as f64),
        k => return Err(format!("{what} has type {k}, expected RATIONAL")),
    };
    if den == 0.0 {
        return Err(format!("{what} is {num}/0 (zero denominator)"));
    }
    Ok(num / den)
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
            let e = parse_jpeg(&jpeg_with_exif(little, false), Path::new("a.jpg")).unwrap();
            assert_eq!(e.exposure_time_s, Some(1.0 / 250.0));
            assert_eq!(e.f_number, Some(2.2));
            assert_eq!(e.iso, Some(200));
            let e = parse_jpeg(&jpeg_with_exif(little, true), Path::new("a.jpg")).unwrap();
            assert_eq!(e.exposure_time_s, Some(1.0 / 250.0));
            assert_eq!(e.f_number, None);
        }
    }

    #[test]
    fn no_exif_is_not_an_error() {
        let j = [0xff, 0xd8, 0xff, 0xe0, 0x00, 0x04, 0, 0, 0xff, 0xda, 0, 2];
        assert_eq!(
            parse_jpeg(&j, Path::new("b.jpg")).unwrap(),
            ExifExposure::default()
        );
        let e = parse_jpeg(b"GIF89a", Path::new("c.gif")).unwrap_err();
        assert!(e.to_string().contains("c.gif"), "{e}");
    }

    #[test]
    fn truncations_and_random_bytes_never_panic() {
        let good = jpeg_with_exif(false, false);
        for cut in 0..good.len() {
            if let Err(e) = parse_jpeg(&good[..cut], Path::new("cut.jpg")) {
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
                let _ = parse_jpeg(&b, Path::new("x.jpg"));
            }
        }
        for _ in 0..20_000 {
            let mut b = good.clone();
            for _ in 0..1 + next() % 6 {
                let i = (next() % b.len() as u64) as usize;
                b[i] = next() as u8;
            }
            let cut = (next() % (b.len() as u64 + 1)) as usize;
            let _ = parse_jpeg(&b[..cut], Path::new("x.jpg"));
            let junk: Vec<u8> = (0..next() % 200).map(|_| next() as u8).collect();
            let mut j = vec![0xff, 0xd8];
            j.extend_from_slice(&junk);
            let _ = parse_jpeg(&j, Path::new("x.jpg"));
        }
    }

    #[test]
    fn zero_denominator_is_an_error() {
        let mut j = jpeg_with_exif(true, true);
        // The denominator is the last 4 bytes before the scan marker.
        let n = j.len();
        j[n - 10..n - 6].copy_from_slice(&[0, 0, 0, 0]);
        let e = parse_jpeg(&j, Path::new("z.jpg")).unwrap_err();
        assert!(
            e.to_string().contains("z.jpg") && e.to_string().contains("zero"),
            "{e}"
        );
    }
}
