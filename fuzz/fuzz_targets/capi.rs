//! The C ABI (`include/lumiprobe.h`) driven the way a C program could drive
//! it: a fuzzer-chosen sequence of calls on files the fuzzer wrote, buffers
//! the fuzzer filled and handles earlier calls returned.
//!
//! Every pointer passed is one a correct C caller could pass: NULL where the
//! header allows it (it must then be reported, not dereferenced), buffers of
//! exactly the documented length, handles that are live (a freed handle is
//! dropped from the harness's list, as a C caller would forget it). Paths are
//! files below a scratch folder (so the fuzzer cannot make the library read
//! /dev/zero or walk the machine), with fuzzer-chosen names, extensions and
//! non-UTF-8 bytes.
//!
//! The harness also checks what the header promises: output pointers are
//! written only on success, images have `width * height * 3` readable floats,
//! `lp_last_error` is empty after a success and NUL-terminated within `len`.
#![no_main]
use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use lumiprobe::ffi::*;
use lumiprobe_fuzz::scratch;
use std::ffi::{c_char, CString};
use std::path::{Path, PathBuf};
use std::ptr::{null, null_mut};

/// A handle slot: `None` passes NULL, `Some(i)` the live handle `i % count`
/// (NULL when there is none).
type Slot = Option<u8>;

#[derive(Arbitrary, Debug)]
struct FileName {
    /// Stem bytes ('/' and NUL are dropped so the file stays in its folder).
    stem: Vec<u8>,
    /// Index into [`EXTS`].
    ext: u8,
}

const EXTS: [&str; 10] = [
    ".exr", ".hdr", ".pfm", ".png", ".jpg", ".pic", ".EXR", "", ".tiff", ".hdr.tmp",
];

/// Files a fuzzed scene may hold, relative to the scene folder.
const SCENE_FILES: [&str; 6] = [
    "probes/p0.exr",
    "probes/p1.hdr",
    "probes/p2.pfm",
    "path/f0.jpg",
    "path/f1.png",
    "out/f0.exr",
];

const METHODS: [&[u8]; 6] = [b"warp", b"flow", b"hybrid", b"fusion", b"", b"WARP"];

#[derive(Arbitrary, Debug)]
enum Op {
    Version,
    LastError {
        len: u8,
        null_buf: bool,
    },
    /// Writes `bytes` to a file and reads it with `lp_image_read`.
    ReadFile {
        name: FileName,
        bytes: Vec<u8>,
        null_out: bool,
    },
    /// Reads one of a few valid files (see [`templates`]) after the given byte
    /// edits and an optional cut, so the calls after it get real images.
    ReadTemplate {
        which: u8,
        edits: Vec<(u16, u8)>,
        cut: Option<u16>,
    },
    /// `lp_image_read` on a path that does not exist, is a folder, or NULL.
    ReadOther {
        which: u8,
    },
    FromRgb {
        width: u16,
        height: u16,
        values: Vec<f32>,
        null_rgb: bool,
        null_out: bool,
    },
    Inspect {
        img: Slot,
    },
    Write {
        img: Slot,
        name: FileName,
        null_path: bool,
    },
    FreeImage {
        img: Slot,
    },
    ShProject {
        img: Slot,
        null_coeffs: bool,
    },
    ShIrradiance {
        coeffs: [f32; 27],
        n: [f32; 3],
        nulls: u8,
    },
    Prefilter {
        img: Slot,
        face_size: u32,
        mip_count: u32,
        samples: u32,
        null_out: bool,
    },
    PrefilteredInspect {
        p: Slot,
        mip: u32,
        face: u32,
    },
    Shade {
        p: Slot,
        n: [f32; 3],
        v: [f32; 3],
        base_color: [f32; 3],
        metallic: f32,
        roughness: f32,
        nulls: u8,
    },
    FreePrefiltered {
        p: Slot,
    },
    /// Writes a scene folder (`poses.json` plus some of [`SCENE_FILES`]) and
    /// opens it as a probe set, with or without the run folder `out`.
    ProbeSetOpen {
        poses: Vec<u8>,
        files: Vec<(u8, Vec<u8>)>,
        run_dir: bool,
        null_out: bool,
    },
    ProbeSetPosition {
        set: Slot,
        index: u32,
        null_xyz: bool,
    },
    ProbeSetQuery {
        set: Slot,
        xyz: [f32; 3],
        blend: u32,
        null_out: bool,
    },
    FreeProbeSet {
        set: Slot,
    },
    /// Writes a valid scene folder (probes p0.exr and p1.hdr, frame f0.png, all
    /// 16x8, and `out/f0.exr`) with fuzzer-chosen positions and response, and
    /// opens it as a probe set.
    SceneTemplate {
        positions: [[f32; 3]; 3],
        response: u8,
        gain: f32,
        run_dir: bool,
    },
    /// `lp_run` over the last scene folder written (or a missing one).
    Run {
        method: u8,
        raw_method: Vec<u8>,
        null_arg: u8,
    },
}

#[derive(Arbitrary, Debug)]
struct Program {
    ops: Vec<Op>,
}

struct Handles {
    images: Vec<*mut LpImage>,
    prefiltered: Vec<*mut LpPrefiltered>,
    sets: Vec<*mut LpProbeSet>,
}

fn pick<T>(v: &[*mut T], s: Slot) -> *mut T {
    match s {
        Some(i) if !v.is_empty() => v[i as usize % v.len()],
        _ => null_mut(),
    }
}

/// Removes and returns the handle a slot names (NULL when none).
fn take<T>(v: &mut Vec<*mut T>, s: Slot) -> *mut T {
    match s {
        Some(i) if !v.is_empty() => {
            let k = i as usize % v.len();
            v.swap_remove(k)
        }
        _ => null_mut(),
    }
}

fn c_path(p: &Path) -> CString {
    use std::os::unix::ffi::OsStrExt;
    CString::new(p.as_os_str().as_bytes()).expect("scratch paths have no NUL")
}

fn file_path(dir: &Path, f: &FileName) -> PathBuf {
    use std::os::unix::ffi::OsStrExt;
    let mut stem: Vec<u8> = f
        .stem
        .iter()
        .copied()
        .filter(|&b| b != b'/' && b != 0)
        .take(24)
        .collect();
    if stem.is_empty() || stem == b"." || stem == b".." {
        stem = b"img".to_vec();
    }
    stem.extend_from_slice(EXTS[f.ext as usize % EXTS.len()].as_bytes());
    dir.join(std::ffi::OsStr::from_bytes(&stem))
}

/// This thread's last error, checking `lp_last_error`'s contract.
fn last_error() -> String {
    let n = unsafe { lp_last_error(null_mut(), 0) };
    let mut buf = vec![0xAAu8; n + 1];
    let m = unsafe { lp_last_error(buf.as_mut_ptr() as *mut c_char, buf.len()) };
    assert_eq!(n, m, "lp_last_error length changed between calls");
    assert_eq!(buf[n], 0, "message not NUL-terminated");
    String::from_utf8_lossy(&buf[..n]).into_owned()
}

/// Checks the status conventions: success clears the message, failure sets
/// one; no call reports an internal error (a panic inside the library).
fn check_status(s: LpStatus, what: &str) {
    let msg = last_error();
    match s {
        LpStatus::Ok => assert!(msg.is_empty(), "{what}: OK but message {msg:?}"),
        LpStatus::Panic => panic!("{what}: internal error: {msg}"),
        _ => assert!(!msg.is_empty(), "{what}: {s:?} without a message"),
    }
}

/// Reads every float of an image as a C caller would.
unsafe fn touch_image(img: *const LpImage) {
    let (w, h) = (lp_image_width(img), lp_image_height(img));
    let data = lp_image_data(img);
    if img.is_null() {
        assert!(w == 0 && h == 0 && data.is_null());
        return;
    }
    assert!(w > 0 && h > 0 && !data.is_null());
    let s = std::slice::from_raw_parts(data, w as usize * h as usize * 3);
    std::hint::black_box(s.iter().fold(0f32, |a, &v| a + v));
}

/// Whether a prefilter call is cheap enough to run each iteration, or its
/// arguments are outside the documented range (so it must fail at once).
fn prefilter_worth_calling(face: u32, mips: u32, samples: u32) -> bool {
    let out_of_range =
        face == 0 || mips == 0 || samples == 0 || face > 8192 || mips > 16 || samples > 1 << 16;
    let work = [face as u64, face as u64, samples as u64, mips as u64]
        .iter()
        .fold(6u64, |a, &b| a.saturating_mul(b));
    out_of_range || (face <= 32 && work <= 1 << 20)
}

/// Valid files written by the crate's own writers, as (extension, bytes):
/// a 16x8 image as float EXR, RLE Radiance, PFM, and an 8-bit PNG.
fn templates() -> &'static [(&'static str, Vec<u8>)] {
    static T: std::sync::OnceLock<Vec<(&'static str, Vec<u8>)>> = std::sync::OnceLock::new();
    T.get_or_init(|| {
        use lumiprobe::image::io::{exr, ldr, pfm, rgbe, ExrWriteOptions};
        let img = lumiprobe::HdrImage::from_fn(16, 8, |x, y| {
            let v = 0.05 + (x * 8 + y) as f32 / 64.0;
            if y == 0 && x == 3 {
                [50.0, 40.0, 30.0]
            } else {
                [v, v * 0.8, v * 0.6]
            }
        });
        let sdr =
            lumiprobe::image::io::linear_to_sdr(&img, &lumiprobe::tonemap::Response::Srgb, 1.0);
        vec![
            (
                ".exr",
                exr::encode(&img, Path::new("t.exr"), &ExrWriteOptions::default()).unwrap(),
            ),
            (".hdr", rgbe::encode(&img)),
            (".pfm", pfm::encode(&img, pfm::Endian::Little)),
            (".png", ldr::encode_png(&sdr, Path::new("t.png")).unwrap()),
        ]
    })
}

fn scene_dir() -> PathBuf {
    scratch().join("scene")
}

unsafe fn run_op(op: &Op, h: &mut Handles, files: &Path) {
    match op {
        Op::Version => {
            let v = std::ffi::CStr::from_ptr(lp_version());
            assert!(!v.to_bytes().is_empty());
        }
        Op::LastError { len, null_buf } => {
            let mut buf = vec![0x55u8; *len as usize];
            let p = if *null_buf || buf.is_empty() {
                null_mut()
            } else {
                buf.as_mut_ptr() as *mut c_char
            };
            let len = if p.is_null() { 0 } else { buf.len() };
            let n = lp_last_error(p, len);
            if !p.is_null() {
                let k = n.min(len - 1);
                assert_eq!(buf[k], 0, "not NUL-terminated within len");
            }
        }
        Op::ReadFile {
            name,
            bytes,
            null_out,
        } => {
            let path = file_path(files, name);
            std::fs::write(&path, bytes).unwrap();
            read_image(h, &path, *null_out);
        }
        Op::ReadTemplate { which, edits, cut } => {
            let t = templates();
            let (ext, valid) = &t[*which as usize % t.len()];
            let mut bytes = valid.clone();
            for &(at, v) in edits.iter().take(8) {
                if !bytes.is_empty() {
                    let k = at as usize % bytes.len();
                    bytes[k] = v;
                }
            }
            if let Some(c) = cut {
                bytes.truncate(*c as usize);
            }
            let path = files.join(format!("template{ext}"));
            std::fs::write(&path, &bytes).unwrap();
            read_image(h, &path, false);
        }
        Op::ReadOther { which } => match which % 3 {
            0 => read_image(h, &files.join("missing.exr"), false),
            1 => read_image(h, files, false),
            _ => {
                let mut out = null_mut();
                let s = lp_image_read(null(), &mut out);
                assert_eq!(s, LpStatus::Invalid);
                assert!(out.is_null());
                check_status(s, "lp_image_read(NULL)");
            }
        },
        Op::FromRgb {
            width,
            height,
            values,
            null_rgb,
            null_out,
        } => {
            // A caller owns width * height * 3 floats; keep that buffer small.
            let n = *width as usize * *height as usize * 3;
            if n > 3 << 16 {
                return;
            }
            let mut buf = vec![0f32; n.max(1)];
            for (d, s) in buf.iter_mut().zip(values.iter().cycle()) {
                *d = *s;
            }
            let rgb = if *null_rgb { null() } else { buf.as_ptr() };
            let mut out: *mut LpImage = null_mut();
            let outp = if *null_out { null_mut() } else { &mut out };
            let s = lp_image_from_rgb(rgb, buf.len(), *width as u32, *height as u32, outp);
            check_status(s, "lp_image_from_rgb");
            if s == LpStatus::Ok {
                assert!(!out.is_null());
                assert_eq!(lp_image_width(out), *width as u32);
                let d = std::slice::from_raw_parts(lp_image_data(out), n);
                assert!(d.iter().zip(&buf).all(|(a, b)| a.to_bits() == b.to_bits()));
                h.images.push(out);
            } else {
                assert!(out.is_null(), "output written on failure");
            }
        }
        Op::Inspect { img } => touch_image(pick(&h.images, *img)),
        Op::Write {
            img,
            name,
            null_path,
        } => {
            let path = file_path(files, name);
            let c = c_path(&path);
            let p = if *null_path { null() } else { c.as_ptr() };
            let s = lp_image_write(pick(&h.images, *img), p);
            check_status(s, "lp_image_write");
            if s == LpStatus::Ok {
                // What was written reads back with the same size.
                let src = pick(&h.images, *img);
                let mut back = null_mut();
                let r = lp_image_read(c.as_ptr(), &mut back);
                check_status(r, "lp_image_read after lp_image_write");
                assert_eq!(r, LpStatus::Ok, "{}: {}", path.display(), last_error());
                assert_eq!(lp_image_width(back), lp_image_width(src));
                assert_eq!(lp_image_height(back), lp_image_height(src));
                lp_image_free(back);
            }
        }
        Op::FreeImage { img } => lp_image_free(take(&mut h.images, *img)),
        Op::ShProject { img, null_coeffs } => {
            let mut c = [0f32; 27];
            let p = if *null_coeffs {
                null_mut()
            } else {
                c.as_mut_ptr()
            };
            let s = lp_sh_project(pick(&h.images, *img), p);
            check_status(s, "lp_sh_project");
        }
        Op::ShIrradiance { coeffs, n, nulls } => {
            let mut out = [f32::NAN; 3];
            let c = if nulls & 1 != 0 {
                null()
            } else {
                coeffs.as_ptr()
            };
            let np = if nulls & 2 != 0 { null() } else { n.as_ptr() };
            let o = if nulls & 4 != 0 {
                null_mut()
            } else {
                out.as_mut_ptr()
            };
            let s = lp_sh_irradiance(c, np, o);
            check_status(s, "lp_sh_irradiance");
            if s != LpStatus::Ok {
                assert!(out.iter().all(|v| v.is_nan()), "output written on failure");
            }
        }
        Op::Prefilter {
            img,
            face_size,
            mip_count,
            samples,
            null_out,
        } => {
            let src = pick(&h.images, *img);
            if !prefilter_worth_calling(*face_size, *mip_count, *samples) {
                return;
            }
            // The source's size drives the cost too; keep it to what a quick
            // iteration can afford.
            if !src.is_null() && lp_image_width(src) as u64 * lp_image_height(src) as u64 > 1 << 16
            {
                return;
            }
            let mut out = null_mut();
            let o = if *null_out { null_mut() } else { &mut out };
            let s = lp_prefilter(src, *face_size, *mip_count, *samples, o);
            check_status(s, "lp_prefilter");
            if s == LpStatus::Ok {
                assert!(!out.is_null());
                assert_eq!(lp_prefiltered_mip_count(out), *mip_count);
                h.prefiltered.push(out);
            } else {
                assert!(out.is_null(), "output written on failure");
            }
        }
        Op::PrefilteredInspect { p, mip, face } => {
            let p = pick(&h.prefiltered, *p);
            let count = lp_prefiltered_mip_count(p);
            let (mut r, mut size) = (f32::NAN, u32::MAX);
            let s = lp_prefiltered_mip_info(p, *mip, &mut r, &mut size);
            check_status(s, "lp_prefiltered_mip_info");
            let data = lp_prefiltered_face(p, *mip, *face);
            if s == LpStatus::Ok {
                assert!(*mip < count);
                assert!((0.0..=1.0).contains(&r));
                if *face < 6 {
                    assert!(!data.is_null());
                    let t = std::slice::from_raw_parts(data, size as usize * size as usize * 3);
                    assert!(t.iter().all(|v| v.is_finite()));
                } else {
                    assert!(data.is_null());
                }
            } else {
                assert!(data.is_null());
            }
            let mut c = [0f32; 27];
            let s = lp_prefiltered_sh(p, c.as_mut_ptr());
            check_status(s, "lp_prefiltered_sh");
        }
        Op::Shade {
            p,
            n,
            v,
            base_color,
            metallic,
            roughness,
            nulls,
        } => {
            let mut out = [f32::NAN; 3];
            let ptr = |a: &[f32; 3], bit: u8| if nulls & bit != 0 { null() } else { a.as_ptr() };
            let o = if nulls & 8 != 0 {
                null_mut()
            } else {
                out.as_mut_ptr()
            };
            let s = lp_prefiltered_shade(
                pick(&h.prefiltered, *p),
                ptr(n, 1),
                ptr(v, 2),
                ptr(base_color, 4),
                *metallic,
                *roughness,
                o,
            );
            check_status(s, "lp_prefiltered_shade");
        }
        Op::FreePrefiltered { p } => lp_prefiltered_free(take(&mut h.prefiltered, *p)),
        Op::ProbeSetOpen {
            poses,
            files: scene_files,
            run_dir,
            null_out,
        } => {
            let dir = scene_dir();
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(dir.join("out")).unwrap();
            std::fs::write(dir.join("poses.json"), poses).unwrap();
            for (k, bytes) in scene_files.iter().take(4) {
                let p = dir.join(SCENE_FILES[*k as usize % SCENE_FILES.len()]);
                std::fs::create_dir_all(p.parent().unwrap()).unwrap();
                std::fs::write(p, bytes).unwrap();
            }
            let scene = c_path(&dir);
            let run = c_path(&dir.join("out"));
            let mut out = null_mut();
            let o = if *null_out { null_mut() } else { &mut out };
            let s = lp_probe_set_open(
                scene.as_ptr(),
                if *run_dir { run.as_ptr() } else { null() },
                o,
            );
            check_status(s, "lp_probe_set_open");
            if s == LpStatus::Ok {
                assert!(!out.is_null());
                h.sets.push(out);
            } else {
                assert!(out.is_null(), "output written on failure");
            }
        }
        Op::SceneTemplate {
            positions,
            response,
            gain,
            run_dir,
        } => {
            let dir = scene_dir();
            let _ = std::fs::remove_dir_all(&dir);
            let t = templates();
            for (rel, k) in [
                ("probes/p0.exr", 0),
                ("probes/p1.hdr", 1),
                ("out/f0.exr", 0),
            ] {
                let p = dir.join(rel);
                std::fs::create_dir_all(p.parent().unwrap()).unwrap();
                std::fs::write(p, &t[k].1).unwrap();
            }
            std::fs::create_dir_all(dir.join("path")).unwrap();
            std::fs::write(dir.join("path/f0.png"), &t[3].1).unwrap();
            let responses = [
                "srgb",
                "gamma 2.2",
                "gamma 0",
                "linear?",
                "f(x) = min(1, 1.08 * x^(1/2.2) / (1 + 0.08 * x^(1/2.2)))",
            ];
            let v = |p: &[f32; 3]| format!("[{}, {}, {}]", p[0], p[1], p[2]);
            let rot = "[[1,0,0],[0,0,-1],[0,1,0]]";
            let poses = format!(
                r#"{{"scene": "fuzz", "probes": [
                {{"id": "p0", "position": {}, "world_from_camera": {rot}, "hdr": "probes/p0.exr"}},
                {{"id": "p1", "position": {}, "world_from_camera": {rot}, "hdr": "probes/p1.hdr"}}],
                "frames": [{{"id": "f0", "position": {}, "world_from_camera": {rot}, "sdr": "path/f0.png"}}],
                "camera": {{"response": "{}", "path_gain": {gain}}}}}"#,
                v(&positions[0]),
                v(&positions[1]),
                v(&positions[2]),
                responses[*response as usize % responses.len()],
            );
            std::fs::write(dir.join("poses.json"), poses).unwrap();
            let scene = c_path(&dir);
            let run = c_path(&dir.join("out"));
            let mut out = null_mut();
            let s = lp_probe_set_open(
                scene.as_ptr(),
                if *run_dir { run.as_ptr() } else { null() },
                &mut out,
            );
            check_status(s, "lp_probe_set_open (template)");
            if s == LpStatus::Ok {
                h.sets.push(out);
            }
        }
        Op::ProbeSetPosition {
            set,
            index,
            null_xyz,
        } => {
            let set = pick(&h.sets, *set);
            let mut xyz = [f32::NAN; 3];
            let p = if *null_xyz {
                null_mut()
            } else {
                xyz.as_mut_ptr()
            };
            let s = lp_probe_set_position(set, *index, p);
            check_status(s, "lp_probe_set_position");
            if s == LpStatus::Ok {
                assert!(*index < lp_probe_set_count(set));
                assert!(xyz.iter().all(|v| v.is_finite()));
            }
        }
        Op::ProbeSetQuery {
            set,
            xyz,
            blend,
            null_out,
        } => {
            let mut out = null_mut();
            let o = if *null_out { null_mut() } else { &mut out };
            let s = lp_probe_set_query(pick(&h.sets, *set), xyz.as_ptr(), *blend, o);
            check_status(s, "lp_probe_set_query");
            if s == LpStatus::Ok {
                touch_image(out);
                h.images.push(out);
            } else {
                assert!(out.is_null(), "output written on failure");
            }
        }
        Op::FreeProbeSet { set } => lp_probe_set_free(take(&mut h.sets, *set)),
        Op::Run {
            method,
            raw_method,
            null_arg,
        } => {
            let m = if method & 0x80 != 0 {
                let mut m: Vec<u8> = raw_method.iter().copied().filter(|&b| b != 0).collect();
                m.truncate(16);
                m
            } else {
                METHODS[*method as usize % METHODS.len()].to_vec()
            };
            let m = CString::new(m).unwrap();
            let scene = c_path(&scene_dir());
            let out = c_path(&scratch().join("run"));
            let arg = |c: &CString, bit: u8| {
                if null_arg & bit != 0 {
                    null()
                } else {
                    c.as_ptr()
                }
            };
            let s = lp_run(arg(&scene, 1), arg(&out, 2), arg(&m, 4));
            check_status(s, "lp_run");
        }
    }
}

unsafe fn read_image(h: &mut Handles, path: &Path, null_out: bool) {
    let c = c_path(path);
    let mut out = null_mut();
    let o = if null_out { null_mut() } else { &mut out };
    let s = lp_image_read(c.as_ptr(), o);
    check_status(s, "lp_image_read");
    if s == LpStatus::Ok {
        touch_image(out);
        h.images.push(out);
    } else {
        assert!(out.is_null(), "output written on failure");
        if matches!(s, LpStatus::Io | LpStatus::Format) {
            // Errors about a file name it.
            let msg = last_error();
            let shown = path.display().to_string();
            assert!(msg.contains(&shown), "{msg:?} does not name {shown}");
        }
    }
}

fuzz_target!(|prog: Program| {
    let files = scratch().join("files");
    std::fs::create_dir_all(&files).unwrap();
    let mut h = Handles {
        images: Vec::new(),
        prefiltered: Vec::new(),
        sets: Vec::new(),
    };
    for op in prog.ops.iter().take(16) {
        unsafe { run_op(op, &mut h, &files) };
    }
    unsafe {
        for p in h.images.drain(..) {
            lp_image_free(p);
        }
        for p in h.prefiltered.drain(..) {
            lp_prefiltered_free(p);
        }
        for p in h.sets.drain(..) {
            lp_probe_set_free(p);
        }
    }
});
