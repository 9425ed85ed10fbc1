//! Cube maps in the Khronos KTX 2.0 container, as engines load them (three.js's
//! `KTX2Loader`, Filament, Bevy, anything built on libktx): uncompressed linear
//! RGBA half or single floats, six faces per level, a mip chain.
//!
//! Faces follow the OpenGL/Vulkan cube-map convention that KTX 2.0 prescribes:
//! faces in the order +X, -X, +Y, -Y, +Z, -Z, and within a face texel `(s, t)`
//! (column, row; row 0 first in the file) looks along the direction of
//! [`gl_face_dir`]. The writer is this module's own, from the KTX 2.0
//! specification (header, level index, basic data format descriptor, key/value
//! data, levels from the smallest up); `tests/export.rs` has a real client
//! (npm `ktx-parse`) read what it writes.

use crate::error::{Error, Result};
use crate::image::HdrImage;
use glam::Vec3;

/// The file identifier every KTX 2.0 file starts with.
const IDENTIFIER: [u8; 12] = [
    0xAB, 0x4B, 0x54, 0x58, 0x20, 0x32, 0x30, 0xBB, 0x0D, 0x0A, 0x1A, 0x0A,
];

/// Largest finite half float: a texel above it cannot be stored as RGBA16F.
pub const HALF_MAX: f32 = 65504.0;

/// Texel format of a KTX 2.0 file written here.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum KtxFormat {
    /// `VK_FORMAT_R16G16B16A16_SFLOAT`: 8 bytes a texel, values up to 65504.
    Rgba16f,
    /// `VK_FORMAT_R32G32B32A32_SFLOAT`: 16 bytes a texel, any float.
    Rgba32f,
}

impl KtxFormat {
    /// The Vulkan format number stored in the header.
    pub fn vk_format(self) -> u32 {
        match self {
            KtxFormat::Rgba16f => 97,
            KtxFormat::Rgba32f => 109,
        }
    }

    /// Bytes of one channel.
    fn type_size(self) -> usize {
        match self {
            KtxFormat::Rgba16f => 2,
            KtxFormat::Rgba32f => 4,
        }
    }

    /// Bytes of one texel (four channels).
    fn texel_bytes(self) -> usize {
        4 * self.type_size()
    }
}

/// Direction (not normalised) that texel coordinates `(s, t)` in `[0, 1]` of cube
/// face `face` (0..6: +X, -X, +Y, -Y, +Z, -Z) look along, in the OpenGL/Vulkan
/// convention: with `sc = 2s - 1`, `tc = 2t - 1`, +X looks along `(1, -tc,
/// -sc)`, -X `(-1, -tc, sc)`, +Y `(sc, 1, tc)`, -Y `(sc, -1, -tc)`, +Z `(sc,
/// -tc, 1)`, -Z `(-sc, -tc, -1)`.
pub fn gl_face_dir(face: usize, s: f32, t: f32) -> Vec3 {
    let (sc, tc) = (2.0 * s - 1.0, 2.0 * t - 1.0);
    match face {
        0 => Vec3::new(1.0, -tc, -sc),
        1 => Vec3::new(-1.0, -tc, sc),
        2 => Vec3::new(sc, 1.0, tc),
        3 => Vec3::new(sc, -1.0, -tc),
        4 => Vec3::new(sc, -tc, 1.0),
        _ => Vec3::new(-sc, -tc, -1.0),
    }
}

/// The six faces of an `n`-texel cube whose texel `(x, y)` of face `f` holds
/// `radiance(gl_face_dir(f, (x + 0.5) / n, (y + 0.5) / n))`.
pub fn gl_cube(n: usize, radiance: impl Fn(Vec3) -> [f32; 3] + Sync) -> [HdrImage; 6] {
    std::array::from_fn(|f| {
        HdrImage::from_fn(n, n, |x, y| {
            let (s, t) = ((x as f32 + 0.5) / n as f32, (y as f32 + 0.5) / n as f32);
            radiance(gl_face_dir(f, s, t).normalize())
        })
    })
}

/// Largest channel value of a cube's levels (NaN counts as infinite).
pub fn peak(levels: &[[HdrImage; 6]]) -> f32 {
    levels
        .iter()
        .flat_map(|l| l.iter())
        .flat_map(|f| f.data().iter())
        .fold(
            0.0f32,
            |m, &v| if v.is_nan() { f32::INFINITY } else { m.max(v) },
        )
}

/// Rounds `n` up to a multiple of `to`.
fn align(n: usize, to: usize) -> usize {
    n.div_ceil(to) * to
}

/// The basic data format descriptor of an RGBA float format (linear, BT.709
/// primaries, straight alpha), with its leading total size.
fn dfd(format: KtxFormat) -> Vec<u8> {
    let bits = 8 * format.type_size();
    let samples = 4usize;
    let block = 24 + 16 * samples;
    let mut w: Vec<u32> = Vec::with_capacity(1 + block / 4);
    w.push((4 + block) as u32); // dfdTotalSize
    w.push(0); // vendorId 0 (Khronos), descriptorType 0 (basic)
    w.push(2 | ((block as u32) << 16)); // versionNumber 2, descriptorBlockSize
                                        // colorModel RGBSDA (1), primaries BT.709 (1), transfer linear (1), flags 0.
    w.push(1 | (1 << 8) | (1 << 16));
    w.push(0); // texel block 1x1x1x1
    w.push(format.texel_bytes() as u32); // bytesPlane0
    w.push(0);
    // Channel ids R, G, B and A (15), each a signed float.
    for (k, id) in [0u32, 1, 2, 15].into_iter().enumerate() {
        let channel_type = id | 0x80 | 0x40;
        w.push((k * bits) as u32 | (((bits - 1) as u32) << 16) | (channel_type << 24));
        w.push(0); // sample position
        w.push((-1.0f32).to_bits()); // sampleLower
        w.push(1.0f32.to_bits()); // sampleUpper
    }
    w.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// Key/value data: each entry's length, the key and value each NUL-terminated,
/// padded to 4 bytes; keys sorted by their bytes as the specification requires.
fn kvd(pairs: &[(&str, &str)]) -> Vec<u8> {
    let mut pairs = pairs.to_vec();
    pairs.sort_by(|a, b| a.0.as_bytes().cmp(b.0.as_bytes()));
    let mut out = Vec::new();
    for (k, v) in pairs {
        let len = k.len() + 1 + v.len() + 1;
        out.extend_from_slice(&(len as u32).to_le_bytes());
        out.extend_from_slice(k.as_bytes());
        out.push(0);
        out.extend_from_slice(v.as_bytes());
        out.push(0);
        out.resize(align(out.len(), 4), 0);
    }
    out
}

/// One level's six faces as texels, alpha 1.
fn level_bytes(faces: &[HdrImage; 6], format: KtxFormat) -> Vec<u8> {
    let n = faces[0].width();
    let mut out = Vec::with_capacity(6 * n * n * format.texel_bytes());
    for f in faces {
        for c in f.data().chunks_exact(3) {
            for v in [c[0], c[1], c[2], 1.0] {
                match format {
                    KtxFormat::Rgba16f => {
                        out.extend_from_slice(&half::f16::from_f32(v).to_bits().to_le_bytes())
                    }
                    KtxFormat::Rgba32f => out.extend_from_slice(&v.to_le_bytes()),
                }
            }
        }
    }
    out
}

/// A KTX 2.0 cube map: `levels[i]` holds the six faces of mip `i` (faces in the
/// order of [`gl_face_dir`], each `max(n >> i, 1)` texels square where `n` is
/// level 0's size), with `key_values` (keys not starting with `KTX` are the
/// writer's own; `KTXwriter` names lumiprobe).
///
/// Fails with [`Error::Invalid`] for no levels, faces of the wrong size, a
/// negative, NaN or infinite texel, or a texel above [`HALF_MAX`] in `Rgba16f`
/// (which would become infinite: choose `Rgba32f`).
pub fn encode_cube(
    levels: &[[HdrImage; 6]],
    format: KtxFormat,
    key_values: &[(&str, &str)],
) -> Result<Vec<u8>> {
    let Some(first) = levels.first() else {
        return Err(Error::Invalid(
            "a KTX2 cube map needs at least one level".into(),
        ));
    };
    let n = first[0].width();
    if n == 0 || levels.len() > 1 + (usize::BITS - n.leading_zeros()) as usize {
        return Err(Error::Invalid(format!(
            "{} levels do not fit a {n}-texel cube",
            levels.len()
        )));
    }
    for (i, l) in levels.iter().enumerate() {
        let m = (n >> i).max(1);
        if l.iter().any(|f| f.width() != m || f.height() != m) {
            return Err(Error::Invalid(format!(
                "level {i} of a {n}-texel cube must have {m}x{m} faces"
            )));
        }
    }
    let bad = levels
        .iter()
        .flat_map(|l| l.iter())
        .map(|f| f.count_invalid())
        .sum::<usize>();
    if bad > 0 {
        return Err(Error::Invalid(format!(
            "the cube has {bad} negative, NaN or infinite values"
        )));
    }
    let top = peak(levels);
    if format == KtxFormat::Rgba16f && top > HALF_MAX {
        return Err(Error::Invalid(format!(
            "a texel of {top} does not fit a half float (at most {HALF_MAX}); \
             write RGBA32F instead"
        )));
    }
    let mut kv: Vec<(&str, &str)> = vec![(
        "KTXwriter",
        concat!("lumiprobe ", env!("CARGO_PKG_VERSION")),
    )];
    kv.extend(key_values.iter().filter(|(k, _)| *k != "KTXwriter"));
    let (dfd, kvd) = (dfd(format), kvd(&kv));
    let header = 12 + 9 * 4 + 4 * 4 + 2 * 8;
    let index_len = 24 * levels.len();
    let dfd_at = align(header + index_len, 4);
    let kvd_at = dfd_at + dfd.len();
    let data_align = format.texel_bytes().max(4);
    let mut data_at = align(kvd_at + kvd.len(), data_align);
    // Levels are stored from the smallest up; the index lists them from level 0.
    let bodies: Vec<Vec<u8>> = levels.iter().map(|l| level_bytes(l, format)).collect();
    let mut offsets = vec![0usize; levels.len()];
    for i in (0..levels.len()).rev() {
        offsets[i] = data_at;
        data_at = align(data_at + bodies[i].len(), data_align);
    }
    let mut out = Vec::with_capacity(data_at);
    out.extend_from_slice(&IDENTIFIER);
    let u32s = [
        format.vk_format(),
        format.type_size() as u32,
        n as u32,
        n as u32,
        0, // pixelDepth
        0, // layerCount
        6, // faceCount
        levels.len() as u32,
        0, // supercompressionScheme: none
        dfd_at as u32,
        dfd.len() as u32,
        kvd_at as u32,
        kvd.len() as u32,
    ];
    for v in u32s {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&0u64.to_le_bytes()); // sgdByteOffset
    out.extend_from_slice(&0u64.to_le_bytes()); // sgdByteLength
    for (i, b) in bodies.iter().enumerate() {
        for v in [offsets[i], b.len(), b.len()] {
            out.extend_from_slice(&(v as u64).to_le_bytes());
        }
    }
    out.resize(dfd_at, 0);
    out.extend_from_slice(&dfd);
    out.extend_from_slice(&kvd);
    for i in (0..levels.len()).rev() {
        out.resize(offsets[i], 0);
        out.extend_from_slice(&bodies[i]);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn u32_at(b: &[u8], at: usize) -> u32 {
        u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
    }

    fn u64_at(b: &[u8], at: usize) -> usize {
        u64::from_le_bytes(b[at..at + 8].try_into().unwrap()) as usize
    }

    #[test]
    fn face_directions_follow_the_opengl_table() {
        // The centre of each face looks along its axis.
        let axes = [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z];
        for (f, a) in axes.iter().enumerate() {
            assert_eq!(gl_face_dir(f, 0.5, 0.5), *a);
        }
        // First row of +Y looks towards -Z, of +Z towards +Y; first column of
        // +X towards +Z.
        assert!(gl_face_dir(2, 0.5, 0.0).z < 0.0);
        assert!(gl_face_dir(4, 0.5, 0.0).y > 0.0);
        assert!(gl_face_dir(0, 0.0, 0.5).z > 0.0);
        // Every face is right-handed seen from outside the way OpenGL's are:
        // s x t points into the cube (the left-handed RenderMan convention).
        for f in 0..6 {
            let c = gl_face_dir(f, 0.5, 0.5);
            let ds = gl_face_dir(f, 1.0, 0.5) - c;
            let dt = gl_face_dir(f, 0.5, 1.0) - c;
            assert!(ds.cross(dt).dot(c) < 0.0, "face {f}");
        }
    }

    #[test]
    fn the_file_lays_out_header_index_descriptor_and_levels() {
        let levels: Vec<[HdrImage; 6]> = (0..3)
            .map(|i| gl_cube(4 >> i, |d| [d.x.max(0.0), 2.0, 3.0 + i as f32]))
            .collect();
        let b = encode_cube(&levels, KtxFormat::Rgba16f, &[("lumiprobe.up", "+y")]).unwrap();
        assert_eq!(b[..12], IDENTIFIER);
        assert_eq!(u32_at(&b, 12), 97);
        assert_eq!(u32_at(&b, 16), 2);
        assert_eq!((u32_at(&b, 20), u32_at(&b, 24)), (4, 4));
        assert_eq!((u32_at(&b, 36), u32_at(&b, 40)), (6, 3));
        let dfd_at = u32_at(&b, 48) as usize;
        assert_eq!(u32_at(&b, dfd_at), u32_at(&b, 52));
        // Level i holds 6 faces of (4 >> i)^2 texels of 8 bytes, stored from
        // the smallest up, each at a multiple of 8 and after the descriptors.
        let mut prev_end = usize::MAX;
        for i in 0..3 {
            let at = 80 + 24 * i;
            let (off, len) = (u64_at(&b, at), u64_at(&b, at + 8));
            assert_eq!(len, 6 * (4 >> i) * (4 >> i) * 8, "level {i}");
            assert_eq!(off % 8, 0);
            assert!(off + len <= b.len());
            assert!(
                off + len <= prev_end,
                "level {i} before level {}",
                i.wrapping_sub(1)
            );
            prev_end = off;
            // The first texel of level i's +X face reads back.
            let g = half::f16::from_bits(u16::from_le_bytes([b[off + 2], b[off + 3]]));
            let bl = half::f16::from_bits(u16::from_le_bytes([b[off + 4], b[off + 5]]));
            assert_eq!((g.to_f32(), bl.to_f32()), (2.0, 3.0 + i as f32));
        }
        assert!(prev_end >= u32_at(&b, 56) as usize + u32_at(&b, 60) as usize);
        let kv = &b[u32_at(&b, 56) as usize..][..u32_at(&b, 60) as usize];
        let text = String::from_utf8_lossy(kv);
        assert!(text.contains("KTXwriter\0lumiprobe"), "{text}");
        assert!(text.find("KTXwriter").unwrap() < text.find("lumiprobe.up").unwrap());
    }

    #[test]
    fn what_a_half_float_cannot_hold_is_refused_not_clamped() {
        let sun = [gl_cube(2, |d| {
            if d.x > 0.8 {
                [1e6, 1e6, 1e6]
            } else {
                [1.0; 3]
            }
        })];
        let e = encode_cube(&sun, KtxFormat::Rgba16f, &[]).unwrap_err();
        assert!(e.to_string().contains("RGBA32F"), "{e}");
        let b = encode_cube(&sun, KtxFormat::Rgba32f, &[]).unwrap();
        let off = u64_at(&b, 80);
        let v = f32::from_le_bytes(b[off..off + 4].try_into().unwrap());
        assert!(v == 1e6 || v == 1.0);
        let nan = [gl_cube(2, |_| [f32::NAN, 0.0, 0.0])];
        assert!(encode_cube(&nan, KtxFormat::Rgba32f, &[]).is_err());
        assert!(encode_cube(&[], KtxFormat::Rgba32f, &[]).is_err());
        let wrong = [gl_cube(4, |_| [1.0; 3]), gl_cube(4, |_| [1.0; 3])];
        assert!(encode_cube(&wrong, KtxFormat::Rgba32f, &[]).is_err());
    }
}
