//! The C ABI: what C and C++ renderers link against (`liblumiprobe.so` plus
//! `include/lumiprobe.h`).
//!
//! Every exported function lives in this module and nowhere else. Conventions:
//! * Objects are opaque handles created by `lp_*_new`/`lp_*_read` style calls and
//!   released with the matching `lp_*_free`; freeing `NULL` is a no-op.
//! * Functions that can fail return an [`LpStatus`]; on failure the message (which
//!   names the file when one is involved) is kept per thread and read back with
//!   [`lp_last_error`]. Output pointers are written only on success.
//! * No Rust panic crosses the boundary: each entry point runs under
//!   `catch_unwind` and reports `LP_ERR_PANIC`.
//! * Pointers passed in must be valid for the stated lengths; `NULL` where a
//!   pointer is required is reported as `LP_ERR_INVALID`, never dereferenced.
//!
//! Images are linear RGB, 32-bit float, row-major, three interleaved channels,
//! with the equirect conventions of [`crate::sphere`].

#![allow(clippy::missing_safety_doc)]

use crate::error::Error;
use crate::ibl::Sh9;
use crate::image::HdrImage;
use std::cell::RefCell;
use std::ffi::{c_char, CStr};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;

/// Result of a C ABI call.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LpStatus {
    /// Success.
    Ok = 0,
    /// Bad arguments (null pointer, size mismatch, unknown name, ...).
    Invalid = 1,
    /// The operating system refused a read or write.
    Io = 2,
    /// A file's contents are malformed.
    Format = 3,
    /// An external library failed (OpenCV).
    External = 4,
    /// A panic inside the library (a bug): the call was abandoned safely.
    Panic = 5,
    /// The input is valid but not supported (a pixel type, a compression).
    Unsupported = 6,
    /// The input asks for more than a limit allows; nothing was allocated.
    Limit = 7,
    /// A check inside the library failed on data it made itself (a bug).
    Internal = 8,
}

/// How `lp_probe_set_query` blends the probes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LpBlend {
    /// The nearest probe alone.
    Nearest = 0,
    /// The two nearest, weighted by inverse distance.
    InverseDistance = 1,
}

/// An HDR image owned by the library.
pub struct LpImage {
    img: HdrImage,
}

thread_local! {
    static LAST_ERROR: RefCell<String> = const { RefCell::new(String::new()) };
}

fn set_error(msg: String) {
    LAST_ERROR.with(|e| *e.borrow_mut() = msg);
}

fn status_of(e: &Error) -> LpStatus {
    match e {
        Error::Io { .. } => LpStatus::Io,
        Error::Format { .. } => LpStatus::Format,
        Error::Invalid(_) => LpStatus::Invalid,
        Error::Unsupported { .. } => LpStatus::Unsupported,
        Error::Limit { .. } => LpStatus::Limit,
        Error::External { .. } => LpStatus::External,
        Error::Internal(_) => LpStatus::Internal,
    }
}

/// Runs `f`, turning errors and panics into a status plus the thread's message.
fn guard(f: impl FnOnce() -> crate::Result<()>) -> LpStatus {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => {
            set_error(String::new());
            LpStatus::Ok
        }
        Ok(Err(e)) => {
            let s = status_of(&e);
            set_error(e.to_string());
            s
        }
        Err(p) => {
            let msg = p
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            set_error(format!("internal error: {msg}"));
            LpStatus::Panic
        }
    }
}

fn invalid(msg: &str) -> Error {
    Error::Invalid(msg.to_string())
}

unsafe fn path_arg(p: *const c_char, what: &str) -> crate::Result<PathBuf> {
    if p.is_null() {
        return Err(invalid(&format!("{what} is NULL")));
    }
    let s = CStr::from_ptr(p)
        .to_str()
        .map_err(|_| invalid(&format!("{what} is not UTF-8")))?;
    Ok(PathBuf::from(s))
}

unsafe fn str_arg(p: *const c_char, what: &str) -> crate::Result<String> {
    Ok(path_arg(p, what)?.to_string_lossy().into_owned())
}

/// Library version as a static NUL-terminated string.
#[no_mangle]
pub extern "C" fn lp_version() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr() as *const c_char
}

/// Copies the calling thread's last error message (empty after a success) into
/// `buf` (NUL-terminated, truncated to `len`) and returns its full length in bytes
/// without the NUL, so a caller can size a buffer. `buf` may be NULL when `len`
/// is 0.
#[no_mangle]
pub unsafe extern "C" fn lp_last_error(buf: *mut c_char, len: usize) -> usize {
    LAST_ERROR.with(|e| {
        let e = e.borrow();
        let bytes = e.as_bytes();
        if !buf.is_null() && len > 0 {
            let n = bytes.len().min(len - 1);
            std::ptr::copy_nonoverlapping(bytes.as_ptr(), buf as *mut u8, n);
            *buf.add(n) = 0;
        }
        bytes.len()
    })
}

/// Reads an HDR image (OpenEXR, Radiance .hdr or PFM) into `*out`. 8-bit files
/// are refused: they need the camera's response to become radiance.
#[no_mangle]
pub unsafe extern "C" fn lp_image_read(path: *const c_char, out: *mut *mut LpImage) -> LpStatus {
    guard(|| {
        if out.is_null() {
            return Err(invalid("out is NULL"));
        }
        let p = path_arg(path, "path")?;
        let img = crate::image::io::read_hdr(&p)?;
        *out = Box::into_raw(Box::new(LpImage { img }));
        Ok(())
    })
}

/// Copies `width * height * 3` floats from `rgb`, which holds `len` floats,
/// into a new image; a `len` other than `width * height * 3` is refused.
#[no_mangle]
pub unsafe extern "C" fn lp_image_from_rgb(
    rgb: *const f32,
    len: usize,
    width: u32,
    height: u32,
    out: *mut *mut LpImage,
) -> LpStatus {
    guard(|| {
        if out.is_null() || rgb.is_null() {
            return Err(invalid("rgb or out is NULL"));
        }
        let n = (width as usize)
            .checked_mul(height as usize)
            .and_then(|n| n.checked_mul(3))
            .filter(|&n| n > 0 && n <= 3 << 28)
            .ok_or_else(|| invalid("image size is zero or too large"))?;
        if len != n {
            return Err(invalid(&format!(
                "rgb holds {len} floats but a {width}x{height} image needs {n}"
            )));
        }
        let data = std::slice::from_raw_parts(rgb, n).to_vec();
        let img = HdrImage::from_vec(width as usize, height as usize, data)?;
        *out = Box::into_raw(Box::new(LpImage { img }));
        Ok(())
    })
}

/// Width in pixels (0 for NULL).
#[no_mangle]
pub unsafe extern "C" fn lp_image_width(img: *const LpImage) -> u32 {
    img.as_ref().map_or(0, |i| i.img.width() as u32)
}

/// Height in pixels (0 for NULL).
#[no_mangle]
pub unsafe extern "C" fn lp_image_height(img: *const LpImage) -> u32 {
    img.as_ref().map_or(0, |i| i.img.height() as u32)
}

/// The pixels (`width * height * 3` floats), valid until the image is freed;
/// NULL for NULL.
#[no_mangle]
pub unsafe extern "C" fn lp_image_data(img: *const LpImage) -> *const f32 {
    img.as_ref()
        .map_or(std::ptr::null(), |i| i.img.data().as_ptr())
}

/// Writes the image; the format follows the extension (.exr float32, .hdr,
/// .pfm; 8-bit extensions are refused). The file is written to a temporary name
/// and renamed.
#[no_mangle]
pub unsafe extern "C" fn lp_image_write(img: *const LpImage, path: *const c_char) -> LpStatus {
    guard(|| {
        let img = img.as_ref().ok_or_else(|| invalid("image is NULL"))?;
        let p = path_arg(path, "path")?;
        // The library writes into folders that exist; it makes none.
        if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
            if !dir.is_dir() {
                return Err(Error::io(
                    dir,
                    std::io::Error::new(std::io::ErrorKind::NotFound, "no such folder"),
                ));
            }
        }
        crate::image::io::write_hdr(&p, &img.img)
    })
}

/// Releases an image (NULL is ignored).
#[no_mangle]
pub unsafe extern "C" fn lp_image_free(img: *mut LpImage) {
    if !img.is_null() {
        drop(Box::from_raw(img));
    }
}

/// Projects an equirect probe onto order-2 spherical harmonics: `coeffs` takes
/// 27 floats, 9 coefficients of 3 channels each, basis order 1; y, z, x; xy,
/// yz, 3z^2 - 1, xz, x^2 - y^2.
#[no_mangle]
pub unsafe extern "C" fn lp_sh_project(img: *const LpImage, coeffs: *mut f32) -> LpStatus {
    guard(|| {
        let img = img.as_ref().ok_or_else(|| invalid("image is NULL"))?;
        if coeffs.is_null() {
            return Err(invalid("coeffs is NULL"));
        }
        let bad = img.img.count_invalid();
        if bad > 0 {
            return Err(invalid(&format!(
                "image has {bad} NaN, infinite or negative samples"
            )));
        }
        let sh = Sh9::project(&img.img);
        let out = std::slice::from_raw_parts_mut(coeffs, 27);
        for (k, c) in sh.coeffs.iter().enumerate() {
            out[3 * k..3 * k + 3].copy_from_slice(c);
        }
        Ok(())
    })
}

/// Diffuse irradiance E (RGB into `out_rgb[3]`, not divided by pi) at the normal
/// `n[3]` (camera axes of the probe: x right, y up, -z forward) from the 27 SH
/// coefficients of `coeffs`, clamped at 0. NaN or infinite coefficients are
/// an error.
#[no_mangle]
pub unsafe extern "C" fn lp_sh_irradiance(
    coeffs: *const f32,
    n: *const f32,
    out_rgb: *mut f32,
) -> LpStatus {
    guard(|| {
        if coeffs.is_null() || n.is_null() || out_rgb.is_null() {
            return Err(invalid("coeffs, n or out_rgb is NULL"));
        }
        let c = std::slice::from_raw_parts(coeffs, 27);
        if c.iter().any(|v| !v.is_finite()) {
            return Err(invalid("coefficients must be finite"));
        }
        let mut sh = Sh9::zero();
        for k in 0..9 {
            sh.coeffs[k] = [c[3 * k], c[3 * k + 1], c[3 * k + 2]];
        }
        let nv = std::slice::from_raw_parts(n, 3);
        let d = glam::Vec3::new(nv[0], nv[1], nv[2]);
        if !d.is_finite() || d.length_squared() < 1e-12 {
            return Err(invalid("normal must be finite and non-zero"));
        }
        let e = sh.irradiance_clamped(d.normalize());
        std::slice::from_raw_parts_mut(out_rgb, 3).copy_from_slice(&e);
        Ok(())
    })
}

/// Runs `method` ("warp", "flow", "hybrid" or "fusion") with default settings
/// over the scene in `scene_dir` (a folder with `poses.json`), writing one probe
/// per frame into `out_dir`. A rerun keeps frames already produced from the same
/// inputs by the same host program (a rebuilt library of the same version does
/// not count as a change: remove the frames to recompute them).
#[no_mangle]
pub unsafe extern "C" fn lp_run(
    scene_dir: *const c_char,
    out_dir: *const c_char,
    method: *const c_char,
) -> LpStatus {
    guard(|| {
        let scene_dir = path_arg(scene_dir, "scene_dir")?;
        let out_dir = path_arg(out_dir, "out_dir")?;
        let m = str_arg(method, "method")?;
        let method = match m.as_str() {
            "warp" => crate::pipeline::Method::Warp,
            "flow" => crate::pipeline::Method::Flow,
            "hybrid" => crate::pipeline::Method::Hybrid,
            "fusion" => crate::pipeline::Method::Fusion,
            _ => return Err(invalid(&format!("unknown method '{m}'"))),
        };
        let scene = crate::scene::Scene::load(&scene_dir)?;
        let params = crate::pipeline::RunParams {
            method,
            ..Default::default()
        };
        crate::pipeline::run(&scene, &out_dir, &params, &|_, _| {})?;
        Ok(())
    })
}

/// Probes placed in the world (a run's per-frame outputs or a scene's own
/// probes), queried by position.
pub struct LpProbeSet {
    set: crate::pipeline::probe_set::ProbeSet,
}

/// Opens the probes of a scene (`scene_dir` holds `poses.json`): the per-frame
/// outputs of a run in `run_dir`, or, when `run_dir` is NULL, the scene's own
/// HDR probes.
#[no_mangle]
pub unsafe extern "C" fn lp_probe_set_open(
    scene_dir: *const c_char,
    run_dir: *const c_char,
    out: *mut *mut LpProbeSet,
) -> LpStatus {
    guard(|| {
        if out.is_null() {
            return Err(invalid("out is NULL"));
        }
        let scene = path_arg(scene_dir, "scene_dir")?;
        let run = if run_dir.is_null() {
            None
        } else {
            Some(path_arg(run_dir, "run_dir")?)
        };
        let set = crate::pipeline::probe_set::ProbeSet::open(&scene, run.as_deref())?;
        *out = Box::into_raw(Box::new(LpProbeSet { set }));
        Ok(())
    })
}

/// Number of probes in a set (0 for NULL).
#[no_mangle]
pub unsafe extern "C" fn lp_probe_set_count(set: *const LpProbeSet) -> u32 {
    set.as_ref().map_or(0, |s| s.set.entries.len() as u32)
}

/// World position (metres, z up) of probe `index`.
#[no_mangle]
pub unsafe extern "C" fn lp_probe_set_position(
    set: *const LpProbeSet,
    index: u32,
    xyz: *mut f32,
) -> LpStatus {
    guard(|| {
        let s = set.as_ref().ok_or_else(|| invalid("set is NULL"))?;
        if xyz.is_null() {
            return Err(invalid("xyz is NULL"));
        }
        let e = s.set.entries.get(index as usize).ok_or_else(|| {
            invalid(&format!(
                "index {index} is out of range (the set has {} probes)",
                s.set.entries.len()
            ))
        })?;
        let p = e.pose.position;
        std::slice::from_raw_parts_mut(xyz, 3).copy_from_slice(&[p.x, p.y, p.z]);
        Ok(())
    })
}

/// The probe for world position `xyz`, as an equirect image in world orientation
/// (camera x = world x, camera up = world z, panorama centre = world +y), at the
/// size of the stored probes. `blend` is an `LpBlend` value, taken as an integer
/// so that an out-of-range value is an error, not undefined behaviour. Free the
/// image with `lp_image_free`.
#[no_mangle]
pub unsafe extern "C" fn lp_probe_set_query(
    set: *const LpProbeSet,
    xyz: *const f32,
    blend: u32,
    out: *mut *mut LpImage,
) -> LpStatus {
    guard(|| {
        let s = set.as_ref().ok_or_else(|| invalid("set is NULL"))?;
        if xyz.is_null() || out.is_null() {
            return Err(invalid("xyz or out is NULL"));
        }
        let p = std::slice::from_raw_parts(xyz, 3);
        let b = match blend {
            k if k == LpBlend::Nearest as u32 => crate::pipeline::probe_set::Blend::Nearest,
            k if k == LpBlend::InverseDistance as u32 => {
                crate::pipeline::probe_set::Blend::InverseDistance2
            }
            k => return Err(invalid(&format!("unknown blend mode {k}"))),
        };
        let (img, _) = s.set.query(glam::Vec3::new(p[0], p[1], p[2]), b, None)?;
        *out = Box::into_raw(Box::new(LpImage { img }));
        Ok(())
    })
}

/// Releases a probe set (NULL is ignored).
#[no_mangle]
pub unsafe extern "C" fn lp_probe_set_free(set: *mut LpProbeSet) {
    if !set.is_null() {
        drop(Box::from_raw(set));
    }
}

/// A probe prefiltered for shading: SH irradiance, GGX specular cube mips, BRDF table.
pub struct LpPrefiltered {
    p: crate::ibl::Prefiltered,
}

/// Prefilters an equirect probe: specular cube of `mip_count` mips (roughness
/// `i / (mip_count - 1)`), mip 0 `face_size` texels, `samples` GGX samples per
/// texel. NaN, infinite or negative texels are an error.
#[no_mangle]
pub unsafe extern "C" fn lp_prefilter(
    probe: *const LpImage,
    face_size: u32,
    mip_count: u32,
    samples: u32,
    out: *mut *mut LpPrefiltered,
) -> LpStatus {
    guard(|| {
        let img = probe.as_ref().ok_or_else(|| invalid("probe is NULL"))?;
        if out.is_null() {
            return Err(invalid("out is NULL"));
        }
        let mut opts = crate::ibl::PrefilterOptions::default();
        opts.specular.face_size = face_size as usize;
        opts.specular.mip_count = mip_count as usize;
        opts.specular.samples = samples as usize;
        let p = crate::ibl::Prefiltered::from_env(&img.img, &opts)?;
        *out = Box::into_raw(Box::new(LpPrefiltered { p }));
        Ok(())
    })
}

/// Number of specular mips (0 for NULL).
#[no_mangle]
pub unsafe extern "C" fn lp_prefiltered_mip_count(p: *const LpPrefiltered) -> u32 {
    p.as_ref().map_or(0, |p| p.p.specular.mips.len() as u32)
}

/// Roughness and face size of specular mip `mip`.
#[no_mangle]
pub unsafe extern "C" fn lp_prefiltered_mip_info(
    p: *const LpPrefiltered,
    mip: u32,
    roughness: *mut f32,
    face_size: *mut u32,
) -> LpStatus {
    guard(|| {
        let p = p.as_ref().ok_or_else(|| invalid("prefiltered is NULL"))?;
        if roughness.is_null() || face_size.is_null() {
            return Err(invalid("roughness or face_size is NULL"));
        }
        let m = p.p.specular.mips.get(mip as usize).ok_or_else(|| {
            invalid(&format!(
                "mip {mip} is out of range ({} mips)",
                p.p.specular.mips.len()
            ))
        })?;
        *roughness = m.roughness;
        *face_size = m.size as u32;
        Ok(())
    })
}

/// Texels of cube face `face` of specular mip `mip`: face_size * face_size * 3
/// floats, row-major, valid until `lp_prefiltered_free`; NULL when an argument
/// is out of range. Faces 0..5 look along -z, +x, +z, -x, +y, -y (probe axes).
/// Texel (x, y) of a face of size n looks along N + a R + b D with
/// a = 2 (x + 0.5) / n - 1, b = 2 (y + 0.5) / n - 1 and (N, R, D) =
/// (-z, +x, -y), (+x, +z, -y), (+z, -x, -y), (-x, -z, -y), (+y, +x, -z),
/// (-y, +x, +z).
#[no_mangle]
pub unsafe extern "C" fn lp_prefiltered_face(
    p: *const LpPrefiltered,
    mip: u32,
    face: u32,
) -> *const f32 {
    p.as_ref()
        .and_then(|p| p.p.specular.mips.get(mip as usize))
        .and_then(|m| m.faces.get(face as usize))
        .map_or(std::ptr::null(), |f| f.data().as_ptr())
}

/// The 27 SH coefficients the irradiance is computed from (window applied),
/// in the order of `lp_sh_project`; pass them to `lp_sh_irradiance`.
#[no_mangle]
pub unsafe extern "C" fn lp_prefiltered_sh(p: *const LpPrefiltered, coeffs: *mut f32) -> LpStatus {
    guard(|| {
        let p = p.as_ref().ok_or_else(|| invalid("prefiltered is NULL"))?;
        if coeffs.is_null() {
            return Err(invalid("coeffs is NULL"));
        }
        let out = std::slice::from_raw_parts_mut(coeffs, 27);
        for (k, c) in p.p.sh.coeffs.iter().enumerate() {
            out[3 * k..3 * k + 3].copy_from_slice(c);
        }
        Ok(())
    })
}

/// Shades one point with split-sum IBL: `out_rgb` = albedo-weighted diffuse
/// (`base_color * (1 - metallic) * E / pi`) plus specular
/// (`prefiltered(r, roughness) * (F0 A + B)`, `F0` = mix(0.04, base_color, metallic)),
/// for unit normal `n` and view direction `v` (surface towards the eye), all in
/// the probe's axes. No occlusion, no energy compensation.
#[no_mangle]
pub unsafe extern "C" fn lp_prefiltered_shade(
    p: *const LpPrefiltered,
    n: *const f32,
    v: *const f32,
    base_color: *const f32,
    metallic: f32,
    roughness: f32,
    out_rgb: *mut f32,
) -> LpStatus {
    guard(|| {
        let p = p.as_ref().ok_or_else(|| invalid("prefiltered is NULL"))?;
        if n.is_null() || v.is_null() || base_color.is_null() || out_rgb.is_null() {
            return Err(invalid("n, v, base_color or out_rgb is NULL"));
        }
        let vec = |q: *const f32| {
            let s = std::slice::from_raw_parts(q, 3);
            glam::Vec3::new(s[0], s[1], s[2])
        };
        let (nn, vv, bc) = (vec(n), vec(v), vec(base_color));
        if !nn.is_finite() || !vv.is_finite() || nn.length_squared() < 1e-12 {
            return Err(invalid("n and v must be finite and n non-zero"));
        }
        if !bc.is_finite() || !metallic.is_finite() || !roughness.is_finite() {
            return Err(invalid("material parameters must be finite"));
        }
        let nn = nn.normalize();
        let vv = vv.normalize_or_zero();
        let n_dot_v = nn.dot(vv).clamp(1e-4, 1.0);
        let r = (2.0 * nn.dot(vv) * nn - vv).normalize_or(nn);
        let m = metallic.clamp(0.0, 1.0);
        let rough = roughness.clamp(0.0, 1.0);
        let e = p.p.irradiance(nn);
        let s = p.p.specular(r, rough);
        let [a, b] = p.p.brdf(n_dot_v, rough);
        let out = std::slice::from_raw_parts_mut(out_rgb, 3);
        for k in 0..3 {
            let f0 = 0.04 * (1.0 - m) + bc[k] * m;
            let diffuse = bc[k] * (1.0 - m) * e[k] / std::f32::consts::PI;
            out[k] = diffuse + s[k] * (f0 * a + b);
        }
        Ok(())
    })
}

/// Releases a prefiltered probe (NULL is ignored).
#[no_mangle]
pub unsafe extern "C" fn lp_prefiltered_free(p: *mut LpPrefiltered) {
    if !p.is_null() {
        drop(Box::from_raw(p));
    }
}
