//! Radiance RGBE (`.hdr`, `.pic`): a text header, a resolution line, then one
//! byte of mantissa per channel plus a shared exponent per pixel, scanlines
//! either flat, old-style run-length encoded, or new-style (per-component) RLE.
//!
//! Reading accepts all eight orientations of the resolution line and any
//! `#?PROGRAM` first line. `EXPOSURE=` lines are **ignored**: pixel
//! values are returned as stored, as stb_image, OpenCV and most tools do.
//! `FORMAT=32-bit_rle_xyze` is rejected (only RGB primaries are supported).
//!
//! Conversion: a pixel `(r, g, b, e)` with `e > 0` decodes to `m * 2^(e - 136)`;
//! encoding rounds to the nearest mantissa (error <= 0.2% of the pixel's largest
//! channel), maps pixels whose largest channel is below 1e-32 to zero, clamps
//! negatives to zero and saturates above ~1.7e38.

use super::{check_dims, check_finite, check_nonempty, Limits};
use crate::error::{Error, Result};
use crate::image::HdrImage;
use std::path::Path;

/// Decodes a Radiance RGBE file held in memory.
pub fn decode(bytes: &[u8], name: &Path, limits: &Limits) -> Result<HdrImage> {
    let err = |msg: String| Error::format(name, msg);
    let mut pos = 0usize;
    let first = next_line(bytes, &mut pos)
        .ok_or_else(|| err("truncated Radiance file: no complete first line".into()))?;
    if !first.starts_with(b"#?") {
        return Err(err(format!(
            "not a Radiance RGBE file: first line {:?} does not start with \"#?RADIANCE\"",
            String::from_utf8_lossy(&first[..first.len().min(20)])
        )));
    }
    loop {
        let line = next_line(bytes, &mut pos).ok_or_else(|| {
            err("truncated Radiance header: no blank line before the resolution line".into())
        })?;
        if line.iter().all(|b| b.is_ascii_whitespace()) {
            break;
        }
        if let Some(v) = line.strip_prefix(b"FORMAT=") {
            match v.trim_ascii() {
                b"32-bit_rle_rgbe" => {}
                b"32-bit_rle_xyze" => {
                    return Err(Error::unsupported(
                        Some(name),
                        "FORMAT=32-bit_rle_xyze (CIE XYZ) is not supported; convert it to \
                         32-bit_rle_rgbe",
                    ))
                }
                other => {
                    return Err(err(format!(
                        "unknown Radiance FORMAT {:?}; expected 32-bit_rle_rgbe",
                        String::from_utf8_lossy(other)
                    )))
                }
            }
        }
        // EXPOSURE=, PRIMARIES=, comments and other variables are ignored.
    }
    let res = next_line(bytes, &mut pos)
        .ok_or_else(|| err("truncated Radiance file: no complete resolution line".into()))?;
    let orient = parse_resolution(res).map_err(err)?;
    let (width, height) = if orient.rows_first {
        (orient.n_fast, orient.n_slow)
    } else {
        (orient.n_slow, orient.n_fast)
    };
    let (w, h) = check_dims(name, width, height, limits)?;
    let (n_slow, n_fast) = if orient.rows_first { (h, w) } else { (w, h) };

    let mut img = HdrImage::new(w, h);
    let mut line = vec![[0u8; 4]; n_fast];
    for s in 0..n_slow {
        read_scanline(bytes, &mut pos, &mut line, s).map_err(err)?;
        for (i, px) in line.iter().enumerate() {
            let (x, y) = orient.place(s, i, w, h);
            let o = 3 * (y * w + x);
            if let Some(dst) = img.data_mut().get_mut(o..o + 3) {
                dst.copy_from_slice(&from_rgbe(*px));
            }
        }
    }
    Ok(img)
}

/// The resolution line, e.g. `-Y 480 +X 640` (the standard top-down layout).
struct Orientation {
    /// Scanlines are rows (`±Y` first) rather than columns.
    rows_first: bool,
    /// Slow axis runs in the decreasing direction of its coordinate.
    slow_neg: bool,
    /// Fast axis runs in the decreasing direction of its coordinate.
    fast_neg: bool,
    n_slow: u64,
    n_fast: u64,
}

impl Orientation {
    /// Image position of pixel `i` of scanline `s`.
    fn place(&self, s: usize, i: usize, w: usize, h: usize) -> (usize, usize) {
        // Radiance's +Y points up, so "-Y" scanlines go from the top row down.
        let along = |idx: usize, neg: bool, is_y: bool, extent: usize| {
            let forward = if is_y { neg } else { !neg };
            if forward {
                idx
            } else {
                extent - 1 - idx
            }
        };
        if self.rows_first {
            (
                along(i, self.fast_neg, false, w),
                along(s, self.slow_neg, true, h),
            )
        } else {
            (
                along(s, self.slow_neg, false, w),
                along(i, self.fast_neg, true, h),
            )
        }
    }
}

fn parse_resolution(line: &[u8]) -> std::result::Result<Orientation, String> {
    let text = String::from_utf8_lossy(line);
    let bad = || {
        format!(
            "bad Radiance resolution line {:?}; expected e.g. \"-Y 480 +X 640\"",
            text.chars().take(60).collect::<String>()
        )
    };
    let toks: Vec<&str> = text.split_ascii_whitespace().collect();
    if toks.len() != 4 {
        return Err(bad());
    }
    let axis = |t: &str| match t {
        "-Y" => Some(('Y', true)),
        "+Y" => Some(('Y', false)),
        "-X" => Some(('X', true)),
        "+X" => Some(('X', false)),
        _ => None,
    };
    let (a0, neg0) = axis(toks[0]).ok_or_else(bad)?;
    let (a1, neg1) = axis(toks[2]).ok_or_else(bad)?;
    if a0 == a1 {
        return Err(bad());
    }
    let n0: u64 = toks[1].parse().map_err(|_| bad())?;
    let n1: u64 = toks[3].parse().map_err(|_| bad())?;
    Ok(Orientation {
        rows_first: a0 == 'Y',
        slow_neg: neg0,
        fast_neg: neg1,
        n_slow: n0,
        n_fast: n1,
    })
}

/// The line starting at `*pos` without its `\n` (and a trailing `\r`); `None` if
/// the data ends before a newline.
fn next_line<'a>(bytes: &'a [u8], pos: &mut usize) -> Option<&'a [u8]> {
    let rest = bytes.get(*pos..)?;
    let n = rest.iter().position(|&b| b == b'\n')?;
    *pos += n + 1;
    let line = &rest[..n];
    Some(line.strip_suffix(b"\r").unwrap_or(line))
}

fn take<'a>(
    bytes: &'a [u8],
    pos: &mut usize,
    n: usize,
    s: usize,
) -> std::result::Result<&'a [u8], String> {
    let end = pos
        .checked_add(n)
        .filter(|&e| e <= bytes.len())
        .ok_or_else(|| format!("truncated Radiance file: pixel data ends in scanline {s}"))?;
    let out = &bytes[*pos..end];
    *pos = end;
    Ok(out)
}

/// Reads one scanline of `out.len()` pixels in whichever encoding it uses.
fn read_scanline(
    bytes: &[u8],
    pos: &mut usize,
    out: &mut [[u8; 4]],
    s: usize,
) -> std::result::Result<(), String> {
    let len = out.len();
    let head = bytes.get(*pos..*pos + 4);
    if (8..=0x7fff).contains(&len) {
        if let Some(&[2, 2, hi, lo]) = head {
            if hi & 0x80 == 0 {
                let declared = (hi as usize) << 8 | lo as usize;
                if declared != len {
                    return Err(format!(
                        "RLE scanline {s} declares width {declared}, image width is {len}"
                    ));
                }
                *pos += 4;
                return read_rle_components(bytes, pos, out, s);
            }
        }
    }
    read_flat_or_old_rle(bytes, pos, out, s)
}

/// New-style RLE: the four components one after another, each as runs
/// (`128 + n`, value) and literals (`n`, n values).
fn read_rle_components(
    bytes: &[u8],
    pos: &mut usize,
    out: &mut [[u8; 4]],
    s: usize,
) -> std::result::Result<(), String> {
    let len = out.len();
    for c in 0..4 {
        let mut x = 0usize;
        while x < len {
            let code = take(bytes, pos, 1, s)?[0] as usize;
            if code > 128 {
                let run = code - 128;
                let v = take(bytes, pos, 1, s)?[0];
                if x + run > len {
                    return Err(format!(
                        "bad RLE in scanline {s}: run of {run} at pixel {x} overflows width {len}"
                    ));
                }
                for px in &mut out[x..x + run] {
                    px[c] = v;
                }
                x += run;
            } else {
                // 1..=128 literal bytes follow; 0 is an empty (invalid) run.
                if code == 0 {
                    return Err(format!(
                        "bad RLE in scanline {s}: zero-length run at pixel {x}"
                    ));
                }
                if x + code > len {
                    return Err(format!(
                        "bad RLE in scanline {s}: {code} literals at pixel {x} overflow width {len}"
                    ));
                }
                let vals = take(bytes, pos, code, s)?;
                for (px, &v) in out[x..x + code].iter_mut().zip(vals) {
                    px[c] = v;
                }
                x += code;
            }
        }
    }
    Ok(())
}

/// Flat pixels, where `(1, 1, 1, n)` repeats the previous pixel `n << shift`
/// times (old-style RLE; `shift` grows by 8 for consecutive repeat pixels).
fn read_flat_or_old_rle(
    bytes: &[u8],
    pos: &mut usize,
    out: &mut [[u8; 4]],
    s: usize,
) -> std::result::Result<(), String> {
    let len = out.len();
    let mut x = 0usize;
    let mut shift = 0u32;
    while x < len {
        let p = take(bytes, pos, 4, s)?;
        if p[0] == 1 && p[1] == 1 && p[2] == 1 {
            if x == 0 {
                return Err(format!(
                    "bad old-style RLE in scanline {s}: repeat with no previous pixel"
                ));
            }
            let count = (p[3] as u64) << shift;
            if count == 0 {
                return Err(format!(
                    "bad old-style RLE in scanline {s}: zero-length run at pixel {x}"
                ));
            }
            if count > (len - x) as u64 {
                return Err(format!(
                    "bad old-style RLE in scanline {s}: run of {count} at pixel {x} overflows width {len}"
                ));
            }
            let prev = out[x - 1];
            let count = count as usize;
            for px in &mut out[x..x + count] {
                *px = prev;
            }
            x += count;
            shift += 8;
            if shift > 24 {
                return Err(format!(
                    "bad old-style RLE in scanline {s}: run count too long"
                ));
            }
        } else {
            out[x] = [p[0], p[1], p[2], p[3]];
            x += 1;
            shift = 0;
        }
    }
    Ok(())
}

/// Linear RGB of one RGBE pixel.
#[inline]
pub fn from_rgbe(p: [u8; 4]) -> [f32; 3] {
    if p[3] == 0 {
        return [0.0; 3];
    }
    // 2^(e - 136) built directly as an f64 (always a normal number here).
    let f = f64::from_bits(((p[3] as u64) + 1023 - 136) << 52);
    [
        (p[0] as f64 * f) as f32,
        (p[1] as f64 * f) as f32,
        (p[2] as f64 * f) as f32,
    ]
}

/// RGBE pixel nearest to a linear RGB triple (see the module docs).
#[inline]
pub fn to_rgbe(c: [f32; 3]) -> [u8; 4] {
    let c = c.map(|v| if v > 0.0 && v.is_finite() { v } else { 0.0 });
    let max = c[0].max(c[1]).max(c[2]);
    if max < 1e-32 {
        return [0; 4];
    }
    // frexp: max = m * 2^e with m in [0.5, 1). max is a normal f32 here.
    let mut e = ((max.to_bits() >> 23) & 0xff) as i32 - 126;
    loop {
        if e > 127 {
            // Beyond the largest RGBE exponent: saturate at exponent byte 255.
            let f = f64::from_bits(((1023 + 8 - 127) as u64) << 52);
            let m = c.map(|v| (v as f64 * f).round().min(255.0) as u8);
            return [m[0], m[1], m[2], 255];
        }
        let f = f64::from_bits(((1023 + 8 - e) as u64) << 52); // 2^(8 - e)
        let m = c.map(|v| (v as f64 * f).round());
        if m[0].max(m[1]).max(m[2]) >= 256.0 {
            e += 1;
            continue;
        }
        return [m[0] as u8, m[1] as u8, m[2] as u8, (e + 128) as u8];
    }
}

/// Encodes an image as a Radiance file with new-style RLE scanlines (flat when
/// the width is outside 8..=32767, as the format requires).
pub fn encode(img: &HdrImage) -> Vec<u8> {
    let (w, h) = (img.width(), img.height());
    let mut out = Vec::with_capacity(64 + w * h * 4 / 2);
    out.extend_from_slice(
        format!("#?RADIANCE\n# written by lumiprobe\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n")
            .as_bytes(),
    );
    if w == 0 {
        return out;
    }
    let rle = (8..=0x7fff).contains(&w);
    let mut comp = vec![0u8; w];
    for row in img.data().chunks_exact(3 * w) {
        let px: Vec<[u8; 4]> = row
            .chunks_exact(3)
            .map(|p| to_rgbe([p[0], p[1], p[2]]))
            .collect();
        if !rle {
            for p in &px {
                out.extend_from_slice(p);
            }
            continue;
        }
        out.extend_from_slice(&[2, 2, (w >> 8) as u8, (w & 0xff) as u8]);
        for c in 0..4 {
            for (d, p) in comp.iter_mut().zip(&px) {
                *d = p[c];
            }
            rle_component(&comp, &mut out);
        }
    }
    out
}

/// Appends one component of a scanline: runs of 4+ equal bytes as (128 + n, v),
/// the rest as literal blocks of up to 128 bytes.
fn rle_component(a: &[u8], out: &mut Vec<u8>) {
    let n = a.len();
    let mut i = 0;
    while i < n {
        // Find the next run of at least 4 equal bytes, starting at j >= i.
        let mut j = i;
        let mut run = 0;
        while j < n {
            run = 1;
            while j + run < n && run < 127 && a[j + run] == a[j] {
                run += 1;
            }
            if run >= 4 {
                break;
            }
            j += run;
        }
        while i < j {
            let k = (j - i).min(128);
            out.push(k as u8);
            out.extend_from_slice(&a[i..i + k]);
            i += k;
        }
        if j < n {
            out.push((128 + run) as u8);
            out.push(a[j]);
            i = j + run;
        }
    }
}

/// Writes an RLE Radiance file atomically. NaN/Inf samples are refused; negative
/// samples are stored as zero.
pub fn write(path: &Path, img: &HdrImage) -> Result<()> {
    check_nonempty(path, img.width(), img.height())?;
    check_finite(path, img)?;
    crate::fsutil::write_atomic(path, &encode(img))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rgbe_conversion_is_accurate_and_safe() {
        for &v in &[1.0f32, 0.5, 2.71, 1e-20, 1e-31, 12345.678, 1e30, 1.7e38] {
            let back = from_rgbe(to_rgbe([v, v * 0.5, v * 0.25]));
            assert!(((back[0] - v) / v).abs() < 4e-3, "{v} -> {back:?}");
            assert!(((back[1] - v * 0.5) / v).abs() < 4e-3, "{v} -> {back:?}");
        }
        assert_eq!(to_rgbe([1e-33, 0.0, 0.0]), [0; 4]);
        assert_eq!(to_rgbe([0.0; 3]), [0; 4]);
        assert_eq!(to_rgbe([-5.0, 1.0, 0.0])[0], 0);
        assert_eq!(to_rgbe([1.0, 0.0, 0.0]), [128, 0, 0, 129]);
        // Largest values saturate rather than wrap.
        let p = to_rgbe([f32::MAX, 1.0, 0.0]);
        assert_eq!(p[3], 255);
        assert!(from_rgbe(p)[0] > 1e38);
        // Rounding up to 256 bumps the exponent.
        let p = to_rgbe([0.99999, 0.0, 0.0]);
        assert_eq!(p, [128, 0, 0, 129]);
    }

    #[test]
    fn rle_component_round_trips() {
        let cases: Vec<Vec<u8>> = vec![
            vec![7; 300],
            (0..300).map(|i| (i * 7 % 256) as u8).collect(),
            [
                vec![1, 2, 3],
                vec![9; 5],
                vec![4, 4, 4],
                vec![5; 200],
                vec![6],
            ]
            .concat(),
        ];
        for a in cases {
            let mut enc = Vec::new();
            rle_component(&a, &mut enc);
            let mut out = vec![[0u8; 4]; a.len()];
            let mut pos = 0;
            // Feed the same component four times.
            let data = [enc.clone(), enc.clone(), enc.clone(), enc].concat();
            read_rle_components(&data, &mut pos, &mut out, 0).unwrap();
            assert_eq!(pos, data.len());
            assert!(out.iter().zip(&a).all(|(p, &v)| p == &[v; 4]));
        }
    }

    #[test]
    fn orientations_are_handled() {
        // 2 wide, 1 high image stored as columns "+X 2 -Y 1": one pixel per scanline.
        let mut b = b"#?RADIANCE\n\n+X 2 -Y 1\n".to_vec();
        b.extend_from_slice(&[128, 0, 0, 129, 0, 128, 0, 129]);
        let img = decode(&b, Path::new("o.hdr"), &Limits::default()).unwrap();
        assert_eq!((img.width(), img.height()), (2, 1));
        assert_eq!(img.get(0, 0), [1.0, 0.0, 0.0]);
        assert_eq!(img.get(1, 0), [0.0, 1.0, 0.0]);
        // "+Y 2 -X 1": bottom row first, right to left.
        let mut b = b"#?RADIANCE\n\n+Y 2 -X 1\n".to_vec();
        b.extend_from_slice(&[128, 0, 0, 129, 0, 128, 0, 129]);
        let img = decode(&b, Path::new("o.hdr"), &Limits::default()).unwrap();
        assert_eq!(img.get(0, 1), [1.0, 0.0, 0.0]);
        assert_eq!(img.get(0, 0), [0.0, 1.0, 0.0]);
    }

    #[test]
    fn old_style_rle_repeats_previous_pixel() {
        let mut b = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 4\n".to_vec();
        b.extend_from_slice(&[128, 0, 0, 129, 1, 1, 1, 3]);
        let img = decode(&b, Path::new("old.hdr"), &Limits::default()).unwrap();
        assert!(img.pixels().all(|p| p == [1.0, 0.0, 0.0]));
    }

    #[test]
    fn exposure_is_ignored_and_xyze_rejected() {
        let mut b = b"#?RADIANCE\nEXPOSURE=4.0\n\n-Y 1 +X 1\n".to_vec();
        b.extend_from_slice(&[128, 128, 128, 129]);
        let img = decode(&b, Path::new("e.hdr"), &Limits::default()).unwrap();
        assert_eq!(img.get(0, 0), [1.0; 3]);
        let b = b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n\0\0\0\0";
        let e = decode(b, Path::new("x.hdr"), &Limits::default()).unwrap_err();
        assert!(e.to_string().contains("xyze"), "{e}");
    }
}
