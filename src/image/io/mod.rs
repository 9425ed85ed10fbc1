//! HDR and 8-bit image files: OpenEXR, Radiance RGBE, PFM, PNG and JPEG.
//!
//! Readers pick the format from the file's magic bytes (the extension is only a
//! fallback), check the declared size against [`Limits`] before allocating, and
//! never panic on malformed input: every failure is an [`Error`] naming the file.
//! Writers pick the format from the extension and write atomically
//! (temporary file + rename, see [`crate::fsutil`]).

pub mod exr;
pub mod gpano;
pub mod ldr;
pub mod pfm;
pub mod rgbe;

pub use self::exr::{ExrCompression, ExrWriteOptions, Overflow};
pub use self::ldr::{linear_to_sdr, sdr_to_linear, sdr_to_linear_rgb};

use crate::error::{Error, Result};
use crate::image::{HdrImage, SdrImage};
use std::path::Path;

/// Resource limits applied while decoding untrusted files.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest accepted `width * height`; larger declared sizes fail with
    /// [`Error::Limit`] before any pixel buffer is allocated.
    pub max_pixels: u64,
}

impl Default for Limits {
    /// 2^28 pixels (e.g. 23170 x 11585), about 3 GiB as float RGB.
    fn default() -> Self {
        Limits {
            max_pixels: 1 << 28,
        }
    }
}

/// The image file formats lumiprobe reads and writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// OpenEXR (`.exr`), HDR.
    Exr,
    /// Radiance RGBE (`.hdr`, `.pic`), HDR.
    Rgbe,
    /// Portable float map (`.pfm`), HDR.
    Pfm,
    /// PNG (`.png`), 8-bit.
    Png,
    /// JPEG (`.jpg`, `.jpeg`), 8-bit.
    Jpeg,
}

impl Format {
    /// Recognises a format from the first bytes of a file.
    pub fn sniff(bytes: &[u8]) -> Option<Format> {
        if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
            Some(Format::Exr)
        } else if bytes.starts_with(b"#?RADIANCE") || bytes.starts_with(b"#?RGBE") {
            Some(Format::Rgbe)
        } else if (bytes.starts_with(b"PF") || bytes.starts_with(b"Pf"))
            && bytes.get(2).is_some_and(|b| b.is_ascii_whitespace())
        {
            Some(Format::Pfm)
        } else if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
            Some(Format::Png)
        } else if bytes.starts_with(&[0xff, 0xd8, 0xff]) {
            Some(Format::Jpeg)
        } else {
            None
        }
    }

    /// Recognises a format from a file name's extension (case-insensitive).
    pub fn from_extension(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "exr" => Some(Format::Exr),
            "hdr" | "pic" | "rgbe" => Some(Format::Rgbe),
            "pfm" => Some(Format::Pfm),
            "png" => Some(Format::Png),
            "jpg" | "jpeg" => Some(Format::Jpeg),
            _ => None,
        }
    }

    /// Magic bytes first, then the extension of `name`.
    pub fn detect(bytes: &[u8], name: &Path) -> Option<Format> {
        Format::sniff(bytes).or_else(|| Format::from_extension(name))
    }

    /// Whether the format stores linear floating-point radiance.
    pub fn is_hdr(self) -> bool {
        matches!(self, Format::Exr | Format::Rgbe | Format::Pfm)
    }

    /// Human-readable name used in messages.
    pub fn name(self) -> &'static str {
        match self {
            Format::Exr => "OpenEXR",
            Format::Rgbe => "Radiance RGBE",
            Format::Pfm => "PFM",
            Format::Png => "PNG",
            Format::Jpeg => "JPEG",
        }
    }
}

/// Reads an HDR image (EXR, Radiance `.hdr` or PFM) with default [`Limits`].
pub fn read_hdr(path: &Path) -> Result<HdrImage> {
    read_hdr_with(path, &Limits::default())
}

/// Reads an HDR image as every command does: NaN, infinite and negative samples
/// are repaired ([`HdrImage::repair_invalid`]) and the warning to print is
/// returned with the image (`None` when nothing was repaired). Library functions
/// that take an image instead refuse such samples; the caller decides.
pub fn read_hdr_repaired(path: &Path) -> Result<(HdrImage, Option<String>)> {
    let mut img = read_hdr(path)?;
    let n = img.repair_invalid();
    Ok((img, (n > 0).then(|| repaired_warning(path, n))))
}

/// The one wording of the repair warning.
pub fn repaired_warning(path: &Path, n: usize) -> String {
    format!(
        "warning: {}: {n} NaN, infinite or negative samples repaired (set to zero; +inf to \
         the brightest finite sample)",
        path.display()
    )
}

/// The size an OpenEXR file declares, read from its first 64 KiB (where its
/// header is); `None` for other formats or a header not found there. For
/// planning only: the file is not validated.
pub fn hdr_size_hint(path: &Path) -> Option<(usize, usize)> {
    use std::io::Read;
    let mut head = Vec::new();
    std::fs::File::open(path)
        .ok()?
        .take(1 << 16)
        .read_to_end(&mut head)
        .ok()?;
    exr::declared_size(&head)
}

/// Reads an HDR image, rejecting files that declare more than `limits` allow.
pub fn read_hdr_with(path: &Path, limits: &Limits) -> Result<HdrImage> {
    let bytes = crate::fsutil::read(path)?;
    decode_hdr(&bytes, path, limits)
}

/// Decodes an HDR image held in memory; `name` is used for format fallback by
/// extension and in error messages.
pub fn decode_hdr(bytes: &[u8], name: &Path, limits: &Limits) -> Result<HdrImage> {
    match detect_or_err(bytes, name)? {
        Format::Exr => exr::decode(bytes, name, limits),
        Format::Rgbe => rgbe::decode(bytes, name, limits),
        Format::Pfm => pfm::decode(bytes, name, limits),
        f @ (Format::Png | Format::Jpeg) => Err(Error::format(
            name,
            format!(
                "is an 8-bit {} image, not HDR: merge brackets into an HDR probe with \
                 `lumiprobe merge`, or give an .exr, .hdr or .pfm file",
                f.name()
            ),
        )),
    }
}

/// Reads an 8-bit image (PNG or JPEG) as RGB with default [`Limits`].
pub fn read_sdr(path: &Path) -> Result<SdrImage> {
    read_sdr_with(path, &Limits::default())
}

/// Reads an 8-bit image as RGB, rejecting files that declare more than `limits`.
pub fn read_sdr_with(path: &Path, limits: &Limits) -> Result<SdrImage> {
    let bytes = crate::fsutil::read(path)?;
    decode_sdr(&bytes, path, limits)
}

/// Width and height an 8-bit image file (PNG or JPEG) declares, from its
/// first [`HEADER_BYTES`] (a JPEG's frame header follows its metadata; a file
/// whose metadata runs past them is read whole). A walk's frames are compared
/// this way before any is decoded. Fails as [`read_sdr`] does on a file that
/// is no 8-bit image.
pub fn sdr_dimensions(path: &Path) -> Result<(usize, usize)> {
    use std::io::Read;
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut head = Vec::new();
    // The first 4 KiB hold a camera JPEG's frame header unless its metadata is
    // large; then up to HEADER_BYTES; then the whole file.
    for limit in [4 << 10, HEADER_BYTES] {
        let want = limit - head.len() as u64;
        let got = (&mut file)
            .take(want)
            .read_to_end(&mut head)
            .map_err(|e| Error::io(path, e))?;
        let found = match detect_or_err(&head, path)? {
            Format::Png => png_size(&head),
            Format::Jpeg => jpeg_size(&head),
            f => return Err(not_8bit(path, f)),
        };
        if let Some(d) = found {
            return Ok(d);
        }
        if (got as u64) < want {
            break;
        }
    }
    let img = read_sdr(path)?;
    Ok((img.width(), img.height()))
}

/// How much of a file [`sdr_dimensions`] reads first.
const HEADER_BYTES: u64 = 64 << 10;

/// A PNG's size from its IHDR chunk, which must come first.
fn png_size(b: &[u8]) -> Option<(usize, usize)> {
    if b.get(12..16)? != b"IHDR" {
        return None;
    }
    let be = |o: usize| -> Option<usize> {
        Some(u32::from_be_bytes(b.get(o..o + 4)?.try_into().ok()?) as usize)
    };
    Some((be(16)?, be(20)?))
}

/// A JPEG's size from its frame header (SOF0-SOF15 but DHT, JPG and DAC),
/// walking the marker segments from the start.
fn jpeg_size(b: &[u8]) -> Option<(usize, usize)> {
    let mut pos = 2;
    loop {
        // Fill bytes (0xFF) may pad a marker.
        while *b.get(pos)? == 0xFF && *b.get(pos + 1)? == 0xFF {
            pos += 1;
        }
        if *b.get(pos)? != 0xFF {
            return None;
        }
        let marker = *b.get(pos + 1)?;
        let len = u16::from_be_bytes([*b.get(pos + 2)?, *b.get(pos + 3)?]) as usize;
        if (0xC0..=0xCF).contains(&marker) && !matches!(marker, 0xC4 | 0xC8 | 0xCC) {
            let h = u16::from_be_bytes([*b.get(pos + 5)?, *b.get(pos + 6)?]) as usize;
            let w = u16::from_be_bytes([*b.get(pos + 7)?, *b.get(pos + 8)?]) as usize;
            return Some((w, h));
        }
        if marker == 0xD9 || marker == 0xDA || len < 2 {
            return None;
        }
        pos += 2 + len;
    }
}

/// Decodes an 8-bit PNG or JPEG held in memory (gray and alpha become RGB).
pub fn decode_sdr(bytes: &[u8], name: &Path, limits: &Limits) -> Result<SdrImage> {
    match detect_or_err(bytes, name)? {
        f @ (Format::Png | Format::Jpeg) => ldr::decode(bytes, name, f, limits),
        f => Err(not_8bit(name, f)),
    }
}

/// The error for an HDR file where an 8-bit image was expected.
fn not_8bit(name: &Path, f: Format) -> Error {
    Error::format(
        name,
        format!(
            "is an HDR {} image, not 8-bit; read it with read_hdr",
            f.name()
        ),
    )
}

/// Writes an HDR image atomically; `.exr` (float32, [`ExrCompression::Auto`]), `.hdr`/`.pic` (RLE RGBE)
/// or `.pfm` (little-endian RGB) by extension.
pub fn write_hdr(path: &Path, img: &HdrImage) -> Result<()> {
    write_hdr_with(path, img, &ExrWriteOptions::default())
}

/// [`write_hdr`] with the EXR options `exr` (other formats ignore them).
pub fn write_hdr_with(path: &Path, img: &HdrImage, exr: &ExrWriteOptions) -> Result<()> {
    match Format::from_extension(path) {
        Some(Format::Exr) => exr::write(path, img, exr),
        Some(Format::Rgbe) => rgbe::write(path, img),
        Some(Format::Pfm) => pfm::write(path, img),
        Some(f @ (Format::Png | Format::Jpeg)) => Err(Error::Invalid(format!(
            "{}: {} is an 8-bit format; write HDR images as .exr, .hdr or .pfm \
             (`lumiprobe tonemap` writes 8-bit previews)",
            path.display(),
            f.name()
        ))),
        None => Err(unknown_extension(path, ".exr, .hdr, .pic or .pfm")),
    }
}

/// Writes an 8-bit RGB image atomically: `.png`, or `.jpg`/`.jpeg` (quality 95).
pub fn write_sdr(path: &Path, img: &SdrImage) -> Result<()> {
    match Format::from_extension(path) {
        Some(Format::Png) => ldr::write_png(path, img),
        Some(Format::Jpeg) => ldr::write_jpeg(path, img, ldr::DEFAULT_JPEG_QUALITY),
        Some(f) => Err(Error::Invalid(format!(
            "{}: {} is an HDR format; write 8-bit images as .png or .jpg \
             (or use write_hdr)",
            path.display(),
            f.name()
        ))),
        None => Err(unknown_extension(path, ".png, .jpg or .jpeg")),
    }
}

fn unknown_extension(path: &Path, allowed: &str) -> Error {
    Error::Invalid(format!(
        "{}: unknown image extension {:?}; expected {}",
        path.display(),
        path.extension()
            .map(|e| e.to_string_lossy().into_owned())
            .unwrap_or_default(),
        allowed
    ))
}

fn detect_or_err(bytes: &[u8], name: &Path) -> Result<Format> {
    Format::detect(bytes, name).ok_or_else(|| {
        let head: Vec<String> = bytes.iter().take(8).map(|b| format!("{b:02x}")).collect();
        Error::format(
            name,
            format!(
                "unrecognised image format (first bytes [{}]); expected OpenEXR, Radiance \
                 RGBE, PFM, PNG or JPEG",
                head.join(" ")
            ),
        )
    })
}

/// Validates a declared image size: non-zero, within `limits`, and addressable
/// as `3 * width * height` samples. Returns it as `usize`.
pub(crate) fn check_dims(
    name: &Path,
    width: u64,
    height: u64,
    limits: &Limits,
) -> Result<(usize, usize)> {
    if width == 0 || height == 0 {
        return Err(Error::format(
            name,
            format!("declares an empty {width}x{height} image"),
        ));
    }
    let too_large = || {
        Error::limit(
            Some(name),
            format!("image of {width}x{height} pixels"),
            format!("{} pixels", limits.max_pixels),
        )
    };
    let pixels = width.checked_mul(height).ok_or_else(too_large)?;
    if pixels > limits.max_pixels {
        return Err(too_large());
    }
    let w = usize::try_from(width).map_err(|_| too_large())?;
    let h = usize::try_from(height).map_err(|_| too_large())?;
    w.checked_mul(h)
        .and_then(|p| p.checked_mul(3 * std::mem::size_of::<f32>()))
        .ok_or_else(too_large)?;
    Ok((w, h))
}

/// Refuses to write NaN or infinite samples, naming how many there are.
pub(crate) fn check_finite(path: &Path, img: &HdrImage) -> Result<()> {
    let bad = img.data().iter().filter(|v| !v.is_finite()).count();
    if bad > 0 {
        return Err(Error::Invalid(format!(
            "{}: image has {bad} NaN or infinite samples; refusing to write them \
             (`lumiprobe convert` repairs them)",
            path.display()
        )));
    }
    Ok(())
}

/// Refuses to write an image without pixels.
pub(crate) fn check_nonempty(path: &Path, width: usize, height: usize) -> Result<()> {
    if width == 0 || height == 0 {
        return Err(Error::Invalid(format!(
            "{}: cannot write an empty {width}x{height} image",
            path.display()
        )));
    }
    Ok(())
}

/// Runs a third-party decoder, turning a panic inside it into a format error.
pub(crate) fn guard_panic<T>(name: &Path, what: &str, f: impl FnOnce() -> Result<T>) -> Result<T> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(_) => Err(Error::format(
            name,
            format!("{what} decoder failed on malformed data"),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_images_size_is_read_from_its_header() {
        let dir = tempfile::tempdir().unwrap();
        let img = SdrImage::from_vec(37, 21, (0..37 * 21 * 3).map(|i| (i % 251) as u8).collect())
            .unwrap();
        let png = dir.path().join("a.png");
        let jpg = dir.path().join("a.jpg");
        ldr::write_png(&png, &img).unwrap();
        ldr::write_jpeg(&jpg, &img, 90).unwrap();
        assert_eq!(sdr_dimensions(&png).unwrap(), (37, 21));
        assert_eq!(sdr_dimensions(&jpg).unwrap(), (37, 21));
        // From the header alone: the data cut off after the first kilobyte.
        let bytes = std::fs::read(&jpg).unwrap();
        let cut = dir.path().join("cut.jpg");
        std::fs::write(&cut, &bytes[..bytes.len().min(1024)]).unwrap();
        assert_eq!(jpeg_size(&std::fs::read(&cut).unwrap()), Some((37, 21)));
        // An HDR file is named as one, as read_sdr does.
        let exr = dir.path().join("a.exr");
        write_hdr(&exr, &HdrImage::new(4, 2)).unwrap();
        let e = sdr_dimensions(&exr).unwrap_err().to_string();
        assert!(e.contains("a.exr") && e.contains("not 8-bit"), "{e}");
        // Junk names its first bytes.
        let junk = dir.path().join("junk.txt");
        std::fs::write(&junk, b"hello").unwrap();
        let e = sdr_dimensions(&junk).unwrap_err().to_string();
        assert!(e.contains("junk.txt") && e.contains("unrecognised"), "{e}");
    }

    #[test]
    fn sniff_prefers_magic_over_extension() {
        let p = Path::new("x.png");
        assert_eq!(Format::detect(b"#?RADIANCE\n", p), Some(Format::Rgbe));
        assert_eq!(Format::detect(b"PF\n1 1\n-1\n", p), Some(Format::Pfm));
        assert_eq!(
            Format::detect(&[0x76, 0x2f, 0x31, 0x01], p),
            Some(Format::Exr)
        );
        assert_eq!(Format::detect(b"", p), Some(Format::Png));
        assert_eq!(Format::detect(b"", Path::new("x.JPEG")), Some(Format::Jpeg));
        assert_eq!(Format::detect(b"junk", Path::new("x.txt")), None);
    }

    #[test]
    fn check_dims_rejects_zero_and_huge() {
        let n = Path::new("a.hdr");
        let l = Limits::default();
        assert!(matches!(check_dims(n, 0, 5, &l), Err(Error::Format { .. })));
        assert!(matches!(
            check_dims(n, 100_000, 100_000, &l),
            Err(Error::Limit { .. })
        ));
        assert!(matches!(
            check_dims(n, u64::MAX, u64::MAX, &l),
            Err(Error::Limit { .. })
        ));
        assert_eq!(check_dims(n, 4, 2, &l).unwrap(), (4, 2));
    }

    #[test]
    fn unknown_extensions_are_clear_errors() {
        let img = HdrImage::new(2, 2);
        let e = write_hdr(Path::new("/nonexistent/x.tiff"), &img).unwrap_err();
        assert!(e.to_string().contains("x.tiff") && e.to_string().contains("tiff"));
        let e = write_sdr(Path::new("/nonexistent/y.bmp"), &SdrImage::new(1, 1)).unwrap_err();
        assert!(e.to_string().contains("y.bmp"));
    }
}
