//! Builds the thin C++ layer in `cpp/` (cxx bridge) against Debian's OpenCV 4,
//! found with pkg-config, linking only the OpenCV modules the layer calls.

use std::process::Command;

fn pkg_config(args: &[&str]) -> String {
    let out = Command::new("pkg-config")
        .args(args)
        .arg("opencv4")
        .output()
        .unwrap_or_else(|e| panic!("lumiprobe needs pkg-config to find OpenCV 4 (apt install pkg-config libopencv-dev): {e}"));
    if !out.status.success() {
        panic!(
            "pkg-config cannot find opencv4 ({}); install it with: apt-get install libopencv-dev",
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    String::from_utf8_lossy(&out.stdout).trim().to_string()
}

fn main() {
    let cflags = pkg_config(&["--cflags-only-I"]);
    let libdir = pkg_config(&["--variable=libdir"]);

    let mut build = cxx_build::bridge("src/cv.rs");
    build
        .file("cpp/cv_bridge.cc")
        .file("cpp/maxflow.cc")
        .std("c++17")
        .flag_if_supported("-O2")
        .flag_if_supported("-Wno-unused-parameter");
    for inc in cflags.split_whitespace() {
        if let Some(p) = inc.strip_prefix("-I") {
            build.include(p);
        }
    }
    build.compile("lumiprobe_cpp");

    println!("cargo:rustc-link-search=native={libdir}");
    for m in [
        "opencv_core",
        "opencv_imgproc",
        "opencv_features2d",
        "opencv_flann",
        "opencv_calib3d",
        "opencv_video",
    ] {
        println!("cargo:rustc-link-lib=dylib={m}");
    }
    for f in [
        "cpp/cv_bridge.h",
        "cpp/cv_bridge.cc",
        "cpp/maxflow.h",
        "cpp/maxflow.cc",
        "src/cv.rs",
    ] {
        println!("cargo:rerun-if-changed={f}");
    }
}
