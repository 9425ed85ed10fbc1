//! HDR and 8-bit file formats. (Minimal first version; hardened per-codec modules follow.)

use crate::error::Result;
use crate::error::Error as LpError;
use crate::image::{HdrImage, SdrImage};
use std::path::Path;

/// Reads an HDR image, choosing the format by extension.
pub fn read_hdr(path: &Path) -> Result<HdrImage> {
    use exr::prelude::*;
    let img = read_first_rgba_layer_from_file(
        path,
        |res, _| HdrImage::new(res.width(), res.height()),
        |img: &mut HdrImage, pos, (r, g, b, _a): (f32, f32, f32, f32)| img.set(pos.x(), pos.y(), [r, g, b]),
    )
    .map_err(|e| LpError::format(path, e.to_string()))?;
    Ok(img.layer_data.channel_data.pixels)
}

/// Writes an HDR image atomically, choosing the format by extension.
pub fn write_hdr(path: &Path, img: &HdrImage) -> Result<()> {
    use exr::prelude::*;
    let tmp = crate::fsutil::temp_path(path);
    write_rgb_file(&tmp, img.width(), img.height(), |x, y| {
        let p = img.get(x, y);
        (p[0], p[1], p[2])
    })
    .map_err(|e| LpError::format(path, e.to_string()))?;
    std::fs::rename(&tmp, path).map_err(|e| LpError::io(path, e))
}

/// Reads an 8-bit RGB image (PNG or JPEG).
pub fn read_sdr(path: &Path) -> Result<SdrImage> {
    let img = image::open(path).map_err(|e| LpError::format(path, e.to_string()))?.to_rgb8();
    let (w, h) = img.dimensions();
    SdrImage::from_vec(w as usize, h as usize, img.into_raw())
}

/// Writes an 8-bit RGB image atomically (PNG or JPEG by extension).
pub fn write_sdr(path: &Path, img: &SdrImage) -> Result<()> {
    let buf = image::RgbImage::from_raw(img.width() as u32, img.height() as u32, img.data().to_vec())
        .ok_or_else(|| LpError::Invalid("SDR buffer size".into()))?;
    let fmt = image::ImageFormat::from_path(path).map_err(|e| LpError::format(path, e.to_string()))?;
    let mut bytes = std::io::Cursor::new(Vec::new());
    buf.write_to(&mut bytes, fmt).map_err(|e| LpError::format(path, e.to_string()))?;
    crate::fsutil::write_atomic(path, bytes.get_ref())
}
