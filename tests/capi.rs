//! The C ABI: header and library agree, calls behave on good and bad input, and a
//! C program built against `include/lumiprobe.h` links and runs.

use lumiprobe::ffi::*;
use std::ffi::{CStr, CString};
use std::path::{Path, PathBuf};
use std::process::Command;

fn manifest() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Names of `lp_*` functions declared in a text (header or Rust source): every
/// identifier `lp_...` directly followed by `(` on a line that is not a comment.
fn names(text: &str, rust: bool) -> Vec<String> {
    let mut v = Vec::new();
    for l in text.lines() {
        let t = l.trim_start();
        if t.starts_with("//") || t.starts_with('*') || t.starts_with("/*") {
            continue;
        }
        if rust && !l.contains("extern \"C\" fn") {
            continue;
        }
        let b = l.as_bytes();
        let mut i = 0;
        while let Some(off) = l[i..].find("lp_") {
            let s = i + off;
            let prev_ok = s == 0 || !(b[s - 1].is_ascii_alphanumeric() || b[s - 1] == b'_');
            let mut e = s;
            while e < b.len() && (b[e].is_ascii_alphanumeric() || b[e] == b'_') {
                e += 1;
            }
            if prev_ok && l[e..].trim_start().starts_with('(') {
                v.push(l[s..e].to_string());
            }
            i = e;
        }
    }
    v.sort();
    v.dedup();
    v
}

#[test]
fn header_declares_exactly_the_exported_functions() {
    let header = std::fs::read_to_string(manifest().join("include/lumiprobe.h")).unwrap();
    let rust = std::fs::read_to_string(manifest().join("src/ffi.rs")).unwrap();
    let (h, r) = (names(&header, false), names(&rust, true));
    assert!(r.len() >= 10, "found only {r:?}");
    assert_eq!(h, r, "header and src/ffi.rs disagree");
}

#[test]
fn header_is_what_cbindgen_makes_of_the_library() {
    let root = manifest();
    let config =
        cbindgen::Config::from_file(root.join("cbindgen.toml")).expect("cbindgen.toml is readable");
    let bindings = cbindgen::Builder::new()
        .with_config(config)
        .with_src(root.join("src/ffi.rs"))
        .generate()
        .expect("cbindgen reads src/ffi.rs");
    let mut made = Vec::new();
    bindings.write(&mut made);
    let path = root.join("include/lumiprobe.h");
    if std::env::var_os("LP_BLESS").is_some() {
        std::fs::write(&path, &made).unwrap();
    }
    let committed = std::fs::read(&path).expect("include/lumiprobe.h exists");
    assert!(
        made == committed,
        "include/lumiprobe.h is not what cbindgen makes of src/ffi.rs; \
         regenerate it with LP_BLESS=1 cargo test --test capi header"
    );
    // The generated header declares what the library exports.
    let text = String::from_utf8(made).unwrap();
    for name in [
        "lp_image_read",
        "lp_probe_set_query",
        "lp_prefiltered_shade",
    ] {
        assert!(text.contains(&format!("{name}(")), "{name} missing");
    }
    assert!(text.contains("LP_STATUS_LIMIT = 7"), "{text}");
}

fn last_error() -> String {
    let n = unsafe { lp_last_error(std::ptr::null_mut(), 0) };
    let mut buf = vec![0u8; n + 1];
    unsafe { lp_last_error(buf.as_mut_ptr() as *mut _, buf.len()) };
    CStr::from_bytes_until_nul(&buf)
        .unwrap()
        .to_string_lossy()
        .into_owned()
}

#[test]
fn bad_calls_return_errors_naming_the_problem() {
    unsafe {
        let mut img: *mut LpImage = std::ptr::null_mut();
        let missing = CString::new("/nonexistent/probe.exr").unwrap();
        assert_eq!(lp_image_read(missing.as_ptr(), &mut img), LpStatus::Io);
        assert!(img.is_null());
        assert!(last_error().contains("/nonexistent/probe.exr"));

        assert_eq!(lp_image_read(std::ptr::null(), &mut img), LpStatus::Invalid);
        assert!(last_error().contains("NULL"));

        let dir = tempfile::tempdir().unwrap();
        let junk = dir.path().join("junk.exr");
        std::fs::write(&junk, b"v/1\x01 definitely not an EXR").unwrap();
        let cj = CString::new(junk.to_str().unwrap()).unwrap();
        assert_eq!(lp_image_read(cj.as_ptr(), &mut img), LpStatus::Format);
        assert!(last_error().contains("junk.exr"));

        // Each kind of failure has its own status: a limit, an unsupported
        // variant of a format.
        for name in ["huge_exr_100000x100000.exr", "huge_pfm_100000x100000.pfm"] {
            let p = manifest().join("tests/corpus").join(name);
            assert!(p.is_file(), "{} is missing", p.display());
            let c = CString::new(p.to_str().unwrap()).unwrap();
            assert_eq!(
                lp_image_read(c.as_ptr(), &mut img),
                LpStatus::Limit,
                "{name}"
            );
            assert!(last_error().contains(name), "{}", last_error());
        }
        let xyz = dir.path().join("xyz.hdr");
        std::fs::write(
            &xyz,
            b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n\x80\x80\x80\x81",
        )
        .unwrap();
        let cx = CString::new(xyz.to_str().unwrap()).unwrap();
        assert_eq!(lp_image_read(cx.as_ptr(), &mut img), LpStatus::Unsupported);
        assert!(last_error().contains("xyz.hdr"), "{}", last_error());
        assert!(img.is_null());

        let m = CString::new("teleport").unwrap();
        let d = CString::new(dir.path().to_str().unwrap()).unwrap();
        assert_eq!(
            lp_run(d.as_ptr(), d.as_ptr(), m.as_ptr()),
            LpStatus::Invalid
        );
        assert!(last_error().contains("teleport"));

        // Accessors and free are NULL-safe.
        assert_eq!(lp_image_width(std::ptr::null()), 0);
        assert!(lp_image_data(std::ptr::null()).is_null());
        lp_image_free(std::ptr::null_mut());

        // A buffer shorter than the size given is refused, not read past.
        let short = [1f32; 5];
        assert_eq!(
            lp_image_from_rgb(short.as_ptr(), short.len(), 4, 2, &mut img),
            LpStatus::Invalid
        );
        assert!(last_error().contains("holds 5 floats"), "{}", last_error());
        // NaN is refused alike by the SH projection and evaluation.
        let mut px = vec![1f32; 8 * 4 * 3];
        px[7] = f32::NAN;
        assert_eq!(
            lp_image_from_rgb(px.as_ptr(), px.len(), 8, 4, &mut img),
            LpStatus::Ok
        );
        let mut coeffs = [0f32; 27];
        assert_eq!(lp_sh_project(img, coeffs.as_mut_ptr()), LpStatus::Invalid);
        assert!(last_error().contains("NaN"), "{}", last_error());
        coeffs[4] = f32::NAN;
        let up = [0f32, 1.0, 0.0];
        assert_eq!(
            lp_sh_irradiance(coeffs.as_ptr(), up.as_ptr(), [0f32; 3].as_mut_ptr()),
            LpStatus::Invalid
        );
        // No folder is made for a write.
        let deep = dir.path().join("no/such/folder/p.exr");
        let cd = CString::new(deep.to_str().unwrap()).unwrap();
        assert_eq!(lp_image_write(img, cd.as_ptr()), LpStatus::Io);
        assert!(!dir.path().join("no").exists());
        lp_image_free(img);
        img = std::ptr::null_mut();
        let _ = img;

        let zero = [0f32; 3];
        assert_eq!(
            lp_sh_irradiance(
                zero.repeat(9).as_ptr(),
                zero.as_ptr(),
                [0f32; 3].as_mut_ptr()
            ),
            LpStatus::Invalid
        );
    }
}

#[test]
fn images_round_trip_and_a_constant_probe_gives_pi_l() {
    unsafe {
        let (w, h) = (32u32, 16u32);
        let px: Vec<f32> = (0..w * h * 3).map(|_| 0.75).collect();
        let mut img: *mut LpImage = std::ptr::null_mut();
        assert_eq!(
            lp_image_from_rgb(px.as_ptr(), px.len(), w, h, &mut img),
            LpStatus::Ok
        );
        assert_eq!((lp_image_width(img), lp_image_height(img)), (w, h));
        let dir = tempfile::tempdir().unwrap();
        let path = CString::new(dir.path().join("c.exr").to_str().unwrap()).unwrap();
        assert_eq!(lp_image_write(img, path.as_ptr()), LpStatus::Ok);
        let mut back: *mut LpImage = std::ptr::null_mut();
        assert_eq!(lp_image_read(path.as_ptr(), &mut back), LpStatus::Ok);
        let data = std::slice::from_raw_parts(lp_image_data(back), (w * h * 3) as usize);
        assert_eq!(data, &px[..]);

        let mut sh = [0f32; 27];
        assert_eq!(lp_sh_project(back, sh.as_mut_ptr()), LpStatus::Ok);
        let mut e = [0f32; 3];
        let n = [0.3f32, -0.8, 0.2];
        assert_eq!(
            lp_sh_irradiance(sh.as_ptr(), n.as_ptr(), e.as_mut_ptr()),
            LpStatus::Ok
        );
        for c in e {
            assert!((c - std::f32::consts::PI * 0.75).abs() < 0.01, "{e:?}");
        }
        lp_image_free(img);
        lp_image_free(back);
    }
}

/// The directory holding `liblumiprobe.so` of this build (`target/<profile>`).
fn lib_dir() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    // target/<profile>/deps/capi-xxxx
    let profile = exe.parent()?.parent()?;
    [profile.to_path_buf(), profile.join("deps")]
        .into_iter()
        .find(|d| d.join("liblumiprobe.so").exists())
}

fn have(cmd: &str) -> bool {
    Command::new(cmd).arg("--version").output().is_ok()
}

#[test]
fn a_c_program_links_and_runs() {
    assert!(have("cc"), "a C compiler (cc) is needed to check the C ABI");
    // Cargo builds the cdylib next to the test binaries (`target/<profile>/deps`).
    let lib = lib_dir().expect("liblumiprobe.so next to the test binary");
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("t.c");
    std::fs::write(
        &src,
        r#"
#include <stdio.h>
#include <string.h>
#include "lumiprobe.h"
int main(int argc, char **argv) {
    float px[32 * 16 * 3];
    for (int i = 0; i < 32 * 16 * 3; i++) px[i] = 2.0f;
    LpImage *img = NULL;
    if (lp_image_from_rgb(px, 32 * 16 * 3, 32, 16, &img) != LP_OK) return 2;
    if (lp_image_write(img, argv[1]) != LP_OK) return 3;
    LpImage *back = NULL;
    if (lp_image_read(argv[1], &back) != LP_OK) return 4;
    if (lp_image_width(back) != 32 || lp_image_data(back)[5] != 2.0f) return 5;
    float sh[27], n[3] = {0, 1, 0}, e[3];
    if (lp_sh_project(back, sh) != LP_OK) return 6;
    if (lp_sh_irradiance(sh, n, e) != LP_OK) return 7;
    LpImage *bad = NULL;
    if (lp_image_read("/no/such/file.hdr", &bad) == LP_OK || bad != NULL) return 8;
    char msg[256];
    lp_last_error(msg, sizeof msg);
    if (!strstr(msg, "/no/such/file.hdr")) return 9;
    printf("%s %.4f\n", lp_version(), e[1]);
    lp_image_free(img);
    lp_image_free(back);
    return 0;
}
"#,
    )
    .unwrap();
    let exe = dir.path().join("t");
    let out = Command::new("cc")
        .arg(&src)
        .arg("-I")
        .arg(manifest().join("include"))
        .arg("-L")
        .arg(&lib)
        .arg(format!("-Wl,-rpath,{}", lib.display()))
        .arg("-llumiprobe")
        .arg("-o")
        .arg(&exe)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "cc failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let img = dir.path().join("x.exr");
    let run = Command::new(&exe).arg(&img).output().unwrap();
    assert!(run.status.success(), "exit {:?}", run.status.code());
    let stdout = String::from_utf8_lossy(&run.stdout);
    let e: f32 = stdout.split_whitespace().nth(1).unwrap().parse().unwrap();
    assert!((e - 2.0 * std::f32::consts::PI).abs() < 0.02, "{stdout}");
    assert!(Path::new(&img).exists());
}

/// A scene of two constant probes (radiance 1 and 3) 2 m apart, with different
/// headings, in the dataset's `poses.json` layout.
fn two_constant_probes(dir: &Path) {
    std::fs::create_dir_all(dir.join("probes")).unwrap();
    let mut probes = Vec::new();
    for (k, (x, l, yaw)) in [(0.0f32, 1.0f32, 0.0f32), (2.0, 3.0, 1.2)]
        .iter()
        .enumerate()
    {
        let px = vec![*l; 64 * 32 * 3];
        let c_path = CString::new(dir.join(format!("probes/p{k}.exr")).to_str().unwrap()).unwrap();
        let mut img = std::ptr::null_mut();
        assert_eq!(
            unsafe { lp_image_from_rgb(px.as_ptr(), px.len(), 64, 32, &mut img) },
            LpStatus::Ok
        );
        assert_eq!(
            unsafe { lp_image_write(img, c_path.as_ptr()) },
            LpStatus::Ok
        );
        unsafe { lp_image_free(img) };
        let (s, c) = yaw.sin_cos();
        // Camera x = (c, s, 0), up = z, forward (-z) = (-s, c, 0); rows of the matrix.
        probes.push(format!(
            r#"{{"id": "p{k}", "position": [{x}, 0, 1.5], "hdr": "probes/p{k}.exr",
                "world_from_camera": [[{c}, 0, {s}], [{s}, 0, {mc}], [0, 1, 0]]}}"#,
            mc = -c
        ));
    }
    std::fs::write(
        dir.join("poses.json"),
        format!(
            r#"{{"scene": "two", "probes": [{}], "frames": []}}"#,
            probes.join(",")
        ),
    )
    .unwrap();
}

#[test]
fn probe_sets_answer_by_position_and_bad_calls_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    two_constant_probes(dir.path());
    let scene = CString::new(dir.path().to_str().unwrap()).unwrap();
    let mut set = std::ptr::null_mut();
    let st = unsafe { lp_probe_set_open(scene.as_ptr(), std::ptr::null(), &mut set) };
    assert_eq!(st, LpStatus::Ok, "{}", last_error());
    assert_eq!(unsafe { lp_probe_set_count(set) }, 2);
    let mut p = [0f32; 3];
    assert_eq!(
        unsafe { lp_probe_set_position(set, 1, p.as_mut_ptr()) },
        LpStatus::Ok
    );
    assert_eq!(p, [2.0, 0.0, 1.5]);
    assert_eq!(
        unsafe { lp_probe_set_position(set, 2, p.as_mut_ptr()) },
        LpStatus::Invalid
    );
    assert!(last_error().contains("out of range"));
    // A quarter of the way: 0.75 * 1 + 0.25 * 3 = 1.5 everywhere.
    let at = [0.5f32, 0.0, 1.5];
    let mut img = std::ptr::null_mut();
    assert_eq!(
        unsafe { lp_probe_set_query(set, at.as_ptr(), 1, &mut img) },
        LpStatus::Ok
    );
    let n = unsafe { lp_image_width(img) * lp_image_height(img) * 3 } as usize;
    let data = unsafe { std::slice::from_raw_parts(lp_image_data(img), n) };
    assert!(data.iter().all(|v| (v - 1.5).abs() < 1e-4));
    // Unknown blend mode and NaN position are errors, not undefined behaviour.
    let mut other = std::ptr::null_mut();
    assert_eq!(
        unsafe { lp_probe_set_query(set, at.as_ptr(), 7, &mut other) },
        LpStatus::Invalid
    );
    assert!(other.is_null());
    let nan = [f32::NAN, 0.0, 0.0];
    assert_eq!(
        unsafe { lp_probe_set_query(set, nan.as_ptr(), 0, &mut other) },
        LpStatus::Invalid
    );
    // Prefiltering: a constant probe gives E = pi L, every mip holds L.
    let mut pf = std::ptr::null_mut();
    assert_eq!(
        unsafe { lp_prefilter(img, 0, 4, 64, &mut pf) },
        LpStatus::Invalid
    );
    assert_eq!(
        unsafe { lp_prefilter(img, 16, 4, 64, &mut pf) },
        LpStatus::Ok
    );
    assert_eq!(unsafe { lp_prefiltered_mip_count(pf) }, 4);
    for m in 0..4 {
        let (mut r, mut s) = (0f32, 0u32);
        assert_eq!(
            unsafe { lp_prefiltered_mip_info(pf, m, &mut r, &mut s) },
            LpStatus::Ok
        );
        assert!((r - m as f32 / 3.0).abs() < 1e-5);
        for f in 0..6 {
            let t = unsafe { lp_prefiltered_face(pf, m, f) };
            assert!(!t.is_null());
            let t = unsafe { std::slice::from_raw_parts(t, (s * s * 3) as usize) };
            assert!(t.iter().all(|v| (v - 1.5).abs() < 0.02), "mip {m} face {f}");
        }
    }
    assert!(unsafe { lp_prefiltered_face(pf, 0, 6) }.is_null());
    let mut sh = [0f32; 27];
    let mut e = [0f32; 3];
    assert_eq!(
        unsafe { lp_prefiltered_sh(pf, sh.as_mut_ptr()) },
        LpStatus::Ok
    );
    let up = [0f32, 1.0, 0.0];
    assert_eq!(
        unsafe { lp_sh_irradiance(sh.as_ptr(), up.as_ptr(), e.as_mut_ptr()) },
        LpStatus::Ok
    );
    assert!((e[0] - 1.5 * std::f32::consts::PI).abs() < 0.02, "{e:?}");
    unsafe {
        lp_prefiltered_free(pf);
        lp_image_free(img);
        lp_probe_set_free(set);
        lp_probe_set_free(std::ptr::null_mut());
        lp_prefiltered_free(std::ptr::null_mut());
    }
    // A missing scene names the file.
    let missing = CString::new("/no/such/scene").unwrap();
    let mut s2 = std::ptr::null_mut();
    assert_ne!(
        unsafe { lp_probe_set_open(missing.as_ptr(), std::ptr::null(), &mut s2) },
        LpStatus::Ok
    );
    assert!(s2.is_null());
    assert!(last_error().contains("/no/such/scene"), "{}", last_error());
}

#[test]
fn a_cpp_program_lights_a_point_with_a_probe_set() {
    assert!(
        have("c++"),
        "a C++ compiler (c++) is needed to check the C ABI"
    );
    let lib = lib_dir().expect("liblumiprobe.so next to the test binary");
    let dir = tempfile::tempdir().unwrap();
    two_constant_probes(dir.path());
    let exe = dir.path().join("light_a_point");
    let out = Command::new("c++")
        .arg("-std=c++17")
        .arg("-Wall")
        .arg("-Werror")
        .arg(manifest().join("tests/cpp/light_a_point.cpp"))
        .arg("-I")
        .arg(manifest().join("include"))
        .arg("-L")
        .arg(&lib)
        .arg(format!("-Wl,-rpath,{}", lib.display()))
        .arg("-llumiprobe")
        .arg("-o")
        .arg(&exe)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "c++ failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let run = Command::new(&exe)
        .args([dir.path().to_str().unwrap(), "0.5", "0", "1.5"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "exit {:?}: {stdout} {}",
        run.status.code(),
        String::from_utf8_lossy(&run.stderr)
    );
    let field = |name: &str| -> Vec<f32> {
        stdout
            .lines()
            .find(|l| l.starts_with(name))
            .unwrap_or_else(|| panic!("no {name} in {stdout}"))
            .split_whitespace()
            .skip(1)
            .map(|t| t.parse().unwrap())
            .collect()
    };
    // Blended radiance 1.5: E = 1.5 pi; a white rough dielectric returns its
    // diffuse 1.5 plus a small specular part (F0 = 0.04).
    let e = field("irradiance");
    assert!((e[0] - 1.5 * std::f32::consts::PI).abs() < 0.02, "{stdout}");
    let c = field("shaded");
    assert!(c[0] > 1.5 && c[0] < 1.5 * 1.1, "{stdout}");
    assert_eq!(field("mips"), vec![4.0]);
    // Bad input: the program reports lumiprobe's message and fails.
    let bad = Command::new(&exe)
        .args(["/no/such/scene", "0", "0", "0"])
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("/no/such/scene"));
}
