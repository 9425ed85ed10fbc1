//! `lumiprobe export` end to end on a synthetic scene, its files read by real
//! clients: the KTX2 cubes by npm `ktx-parse` (what three.js's KTX2Loader is
//! built on; installed into tools/js by scripts/setup.sh and scripts/test.sh),
//! the equirect files by lumiprobe's own readers; and `eval`'s warning for
//! probes at another scale than the truth.

use lumiprobe::ibl::ktx2::gl_face_dir;
use lumiprobe::image::io::read_hdr;
use lumiprobe::image::luminance;
use lumiprobe::scene::Scene;
use lumiprobe::sphere::pixel_to_dir;
#[path = "common/predictions.rs"]
mod predictions;
use predictions::scene_with_predictions;
use std::path::Path;
use std::process::Command;

fn lumiprobe(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_lumiprobe"))
        .args(args)
        .output()
        .unwrap()
}

/// The JSON a client script of `tools/js` prints for `args`, run with node.
/// Fails, with what to do, when node or the client's npm package is missing:
/// the tests do not pass without them.
fn client(script: &str, package: &str, args: &[String]) -> serde_json::Value {
    let js = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/js");
    assert!(
        js.join("node_modules").join(package).is_dir(),
        "npm {package} is not installed: run `npm ci --prefix tools/js` (scripts/test.sh does)"
    );
    let out = Command::new("node")
        .arg(js.join(script))
        .args(args)
        .output()
        .expect("node is needed to run the clients (Debian: apt install nodejs npm)");
    assert!(
        out.status.success(),
        "{script} {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// What npm `ktx-parse` reads of a KTX2 file (`tools/js/ktx2_check.mjs`).
fn ktx_parse(file: &Path) -> serde_json::Value {
    client("ktx2_check.mjs", "ktx-parse", &[file.display().to_string()])
}

/// Direction of the brightest pixel of an equirect.
fn brightest(img: &lumiprobe::HdrImage) -> glam::Vec3 {
    let (w, h) = (img.width(), img.height());
    let (mut best, mut at) = (f32::MIN, (0, 0));
    for y in 0..h {
        for x in 0..w {
            let l = luminance(img.get(x, y));
            if l > best {
                best = l;
                at = (x, y);
            }
        }
    }
    pixel_to_dir(at.0, at.1, w, h)
}

#[test]
fn export_writes_cubes_a_real_client_reads_with_the_light_where_the_world_has_it() {
    let tmp = tempfile::tempdir().unwrap();
    let (scene, pred) = scene_with_predictions(tmp.path());
    let out = tmp.path().join("export");
    export_frame_1(
        &scene,
        &pred,
        &out,
        &["--face-size", "32", "--mips", "4", "--samples", "64"],
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("export.json")).unwrap()).unwrap();
    assert_eq!(report["orientation"], "y");
    assert_eq!(report["frames"].as_array().unwrap().len(), 1);
    // The cube holds the probe's light: luminance power of mip 0 against the
    // equirect's, within 1%.
    let power = &report["frames"][0]["power"];
    let (eq, cube) = (power[0].as_f64().unwrap(), power[1].as_f64().unwrap());
    assert!((cube / eq - 1.0).abs() < 0.01, "{cube} vs {eq}");

    let spec = ktx_parse(&out.join("frame_001_specular.ktx2"));
    assert_eq!(spec["vkFormat"], 97, "RGBA16F");
    assert_eq!(
        (spec["pixelWidth"].as_u64(), spec["faceCount"].as_u64()),
        (Some(32), Some(6))
    );
    assert_eq!(spec["levelCount"], 4);
    let bytes: Vec<u64> = spec["levelBytes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    assert_eq!(bytes, [32, 16, 8, 4].map(|n| 6 * n * n * 8));
    assert_eq!(spec["transferFunction"], 1, "linear");
    assert_eq!(
        spec["keyValue"]["lumiprobe.roughness"],
        "0 0.33333334 0.6666667 1"
    );
    assert_eq!(spec["keyValue"]["lumiprobe.up"], "+y");
    let irr = ktx_parse(&out.join("frame_001_irradiance.ktx2"));
    assert_eq!(
        (irr["pixelWidth"].as_u64(), irr["levelCount"].as_u64()),
        (Some(32), Some(1))
    );

    // The brightest texel the client decodes looks where the exported equirect
    // (read back by lumiprobe) has its brightest pixel, and that is where the
    // frame's pose puts the light in y-up world axes.
    let b = &spec["brightest"];
    let n = 32.0;
    let dir = gl_face_dir(
        b["face"].as_u64().unwrap() as usize,
        (b["x"].as_f64().unwrap() as f32 + 0.5) / n,
        (b["y"].as_f64().unwrap() as f32 + 0.5) / n,
    )
    .normalize();
    let hdr = read_hdr(&out.join("frame_001.hdr")).unwrap();
    let exr = read_hdr(&out.join("frame_001.exr")).unwrap();
    let in_hdr = brightest(&hdr);
    assert!(in_hdr.angle_between(brightest(&exr)).to_degrees() < 3.0);
    assert!(
        dir.angle_between(in_hdr).to_degrees() < 6.0,
        "cube {dir} vs equirect {in_hdr}"
    );
    let s = Scene::load(&scene).unwrap();
    let gt = read_hdr(s.frames[1].ground_truth.as_ref().unwrap()).unwrap();
    let world = s.frames[1].pose.world_from_camera * brightest(&gt);
    let y_up = glam::Vec3::new(world.x, world.z, -world.y);
    assert!(
        dir.angle_between(y_up).to_degrees() < 6.0,
        "cube {dir} vs world {y_up}"
    );

    // three.js's LightProbe JSON: 27 numbers, and the irradiance three.js
    // itself computes from them is the cosine-weighted integral of the
    // exported equirect (order-2 SH: within 10% of the larger value here)
    // along each axis.
    let sh: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("frame_001_sh.json")).unwrap()).unwrap();
    assert_eq!(sh["type"], "LightProbe");
    assert_eq!(sh["sh"].as_array().unwrap().len(), 27);
    let axes = [
        glam::Vec3::X,
        -glam::Vec3::X,
        glam::Vec3::Y,
        -glam::Vec3::Y,
        glam::Vec3::Z,
        -glam::Vec3::Z,
    ];
    let three = three_irradiance(&out.join("frame_001_sh.json"), &axes);
    let (w, h) = (hdr.width(), hdr.height());
    let sa = lumiprobe::sphere::row_solid_angles(w, h);
    let peak = axes
        .iter()
        .map(|n| {
            let mut e = 0.0f64;
            for y in 0..h {
                for x in 0..w {
                    let c = pixel_to_dir(x, y, w, h).dot(*n).max(0.0);
                    e += luminance(hdr.get(x, y)) as f64 * c as f64 * sa[y] as f64;
                }
            }
            e
        })
        .collect::<Vec<f64>>();
    let top = peak.iter().cloned().fold(0.0, f64::max);
    for ((n, e3), e) in axes.iter().zip(&three).zip(&peak) {
        let l3 = luminance([e3[0] as f32, e3[1] as f32, e3[2] as f32]) as f64;
        assert!(
            (l3 - e).abs() < 0.1 * top,
            "along {n}: three.js {l3}, integral {e}"
        );
    }
}

/// Irradiance three.js's `LightProbe` computes from an exported SH file along
/// each direction (`tools/js/sh_check.mjs`).
fn three_irradiance(file: &Path, dirs: &[glam::Vec3]) -> Vec<[f64; 3]> {
    let mut args = vec![file.display().to_string()];
    args.extend(dirs.iter().map(|d| format!("{},{},{}", d.x, d.y, d.z)));
    serde_json::from_value(client("sh_check.mjs", "three", &args)).unwrap()
}

/// The lights three.js's GLTFLoader builds from an exported lights file
/// (`tools/js/lights_check.mjs`).
fn three_lights(file: &Path) -> serde_json::Value {
    client("lights_check.mjs", "three", &[file.display().to_string()])
}

/// `lumiprobe export` of frame 1 of `scene`'s predictions in `pred` into
/// `out`, with `extra` arguments; asserts that it succeeds.
fn export_frame_1(scene: &Path, pred: &Path, out: &Path, extra: &[&str]) {
    let mut args = vec![
        "export",
        scene.to_str().unwrap(),
        "--probes",
        pred.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--frames",
        "1",
    ];
    args.extend_from_slice(extra);
    let o = lumiprobe(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// The lights export of frame 1 ([`export_frame_1`]).
fn export_lights(scene: &Path, pred: &Path, out: &Path) {
    export_frame_1(scene, pred, out, &["--formats", "lights"]);
}

#[test]
fn a_sun_is_exported_as_a_gltf_light_three_js_reads_and_the_light_is_kept() {
    let tmp = tempfile::tempdir().unwrap();
    let (scene, pred) = scene_with_predictions(tmp.path());
    // Frame 1's prediction gets a sun of 1e5 in a known camera direction.
    let s = Scene::load(&scene).unwrap();
    let path = pred.join("frame_001.exr");
    let mut img = read_hdr(&path).unwrap();
    let sun_cam = glam::Vec3::new(0.4, 0.7, -0.3).normalize();
    let (w, h) = (img.width(), img.height());
    let sa = lumiprobe::sphere::row_solid_angles(w, h);
    let mut sun_sa = 0.0f64;
    for y in 0..h {
        for x in 0..w {
            if pixel_to_dir(x, y, w, h).dot(sun_cam) > 3f32.to_radians().cos() {
                img.set(x, y, [1e5, 9e4, 7e4]);
                sun_sa += sa[y] as f64;
            }
        }
    }
    assert!(sun_sa > 0.0);
    lumiprobe::image::io::exr::write(&path, &img, &Default::default()).unwrap();
    let out = tmp.path().join("export");
    export_lights(&scene, &pred, &out);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("export.json")).unwrap()).unwrap();
    let fe = &report["frames"][0];
    let files: Vec<&str> = fe["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert_eq!(
        files,
        [
            "frame_001_lights.gltf",
            "frame_001_residual.hdr",
            "frame_001_residual.exr"
        ]
    );
    // Lights plus residual hold the probe's light, channel by channel.
    let l = &fe["lights"];
    for k in 0..3 {
        let (p, kept) = (
            l["probe"][k].as_f64().unwrap(),
            l["kept"][k].as_f64().unwrap(),
        );
        assert!((kept / p - 1.0).abs() < 1e-4, "channel {k}: {kept} vs {p}");
    }
    let lights = l["lights"].as_array().unwrap();
    assert_eq!(lights.len(), 1, "{lights:?}");
    // The light is where the pose puts the sun, in y-up world axes.
    let world = s.frames[1].pose.world_from_camera * sun_cam;
    let y_up = glam::Vec3::new(world.x, world.z, -world.y);
    assert_eq!(lights[0]["placement"]["type"], "directional");
    let d: Vec<f32> = lights[0]["dir"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap() as f32)
        .collect();
    let d = glam::Vec3::new(d[0], d[1], d[2]);
    assert!(d.angle_between(y_up).to_degrees() < 1.0, "{d} vs {y_up}");
    // The sun's light: its radiance over its pixels' solid angle, less the
    // threshold-level glow the residual keeps there (under 1%).
    let red = lights[0]["rgb"][0].as_f64().unwrap();
    let sun = 1e5 * sun_sa;
    assert!(red <= sun && red > 0.99 * sun, "{red} vs {sun}");

    // three.js reads one directional light shining away from the sun, with the
    // sun's colour and light.
    let three = three_lights(&out.join("frame_001_lights.gltf"));
    let t = &three[0];
    assert_eq!(three.as_array().unwrap().len(), 1, "{three}");
    assert_eq!(t["type"], "DirectionalLight");
    let travel = glam::Vec3::new(
        t["travel"][0].as_f64().unwrap() as f32,
        t["travel"][1].as_f64().unwrap() as f32,
        t["travel"][2].as_f64().unwrap() as f32,
    );
    assert!(travel.angle_between(-y_up).to_degrees() < 1.0, "{travel}");
    assert!((t["intensity"].as_f64().unwrap() / red - 1.0).abs() < 1e-6);
    assert!((t["color"][1].as_f64().unwrap() - 0.9).abs() < 0.01, "{t}");

    // The residual has no sun left.
    let res = read_hdr(&out.join("frame_001_residual.exr")).unwrap();
    let top = res.pixels().map(luminance).fold(0.0f32, f32::max);
    assert!(top < 1e3, "{top}");

    // Where the run's report places a light 2.5 units away in that direction
    // (a fusion run's `lights`), it is a point light there, as bright at the
    // frame.
    let (u, v) = lumiprobe::sphere::dir_to_uv(sun_cam);
    let report = serde_json::json!({
        "id": "frame_001",
        "fusion": { "lights": [
            { "at_px": [u * w as f32, v * h as f32], "power": 1.0, "region": 0, "distance": 2.5 },
            { "at_px": [3.0, 3.0], "power": 1.0, "region": null, "distance": 1.0 }
        ] }
    });
    std::fs::write(pred.join("frame_001.json"), report.to_string()).unwrap();
    let out2 = tmp.path().join("export_point");
    export_lights(&scene, &pred, &out2);
    let three = three_lights(&out2.join("frame_001_lights.gltf"));
    assert_eq!(three.as_array().unwrap().len(), 1, "{three}");
    let t = &three[0];
    assert_eq!(t["type"], "PointLight");
    let p = s.frames[1].pose.position;
    let want = glam::Vec3::new(p.x, p.z, -p.y) + 2.5 * y_up;
    let at = glam::Vec3::new(
        t["position"][0].as_f64().unwrap() as f32,
        t["position"][1].as_f64().unwrap() as f32,
        t["position"][2].as_f64().unwrap() as f32,
    );
    assert!(at.distance(want) < 0.05, "{at} vs {want}");
    assert!((t["intensity"].as_f64().unwrap() / (red * 6.25) - 1.0).abs() < 1e-6);

    // Where the report says the light lies on a plane facing the frame (a
    // ceiling panel: world -z), it is a spot light there shining down over a
    // half-space, its intensity on the axis set so that the frame, off the
    // axis, gets the light it measured under glTF's spot falloff.
    let down_world = glam::Vec3::NEG_Z;
    let facing_cam = s.frames[1].pose.world_from_camera.transpose() * down_world;
    let mut report = report;
    report["fusion"]["lights"][0]["facing"] = serde_json::json!(facing_cam.to_array());
    std::fs::write(pred.join("frame_001.json"), report.to_string()).unwrap();
    let out3 = tmp.path().join("export_spot");
    export_lights(&scene, &pred, &out3);
    let three = three_lights(&out3.join("frame_001_lights.gltf"));
    assert_eq!(three.as_array().unwrap().len(), 1, "{three}");
    let t = &three[0];
    assert_eq!(t["type"], "SpotLight", "{t}");
    let at = glam::Vec3::new(
        t["position"][0].as_f64().unwrap() as f32,
        t["position"][1].as_f64().unwrap() as f32,
        t["position"][2].as_f64().unwrap() as f32,
    );
    assert!(at.distance(want) < 0.05, "{at} vs {want}");
    let travel = glam::Vec3::new(
        t["travel"][0].as_f64().unwrap() as f32,
        t["travel"][1].as_f64().unwrap() as f32,
        t["travel"][2].as_f64().unwrap() as f32,
    );
    assert!(
        travel.angle_between(glam::Vec3::NEG_Y).to_degrees() < 1.0,
        "{travel}"
    );
    assert!(
        (t["angle"].as_f64().unwrap() - std::f64::consts::FRAC_PI_2).abs() < 1e-6,
        "{t}"
    );
    assert!((t["penumbra"].as_f64().unwrap() - 1.0).abs() < 1e-6, "{t}");
    // The frame sits off the spot's axis by the sun's elevation's complement.
    let cos = down_world.dot(-world) as f64;
    assert!(cos > 0.2, "the test's light is above the frame: {cos}");
    let want_intensity = red * 6.25 / (cos * cos);
    assert!(
        (t["intensity"].as_f64().unwrap() / want_intensity - 1.0).abs() < 1e-4,
        "{} vs {want_intensity}",
        t["intensity"]
    );
}

/// What headless Blender reads of equirect files, loaded as a world
/// environment by `tools/blender/load_env.py`: one JSON object per file.
fn blender_reads(files: &[&Path]) -> Vec<serde_json::Value> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/blender/load_env.py");
    let out = Command::new("blender")
        .args(["-b", "--factory-startup", "--python"])
        .arg(&script)
        .arg("--")
        .args(files)
        .output()
        .expect("Blender is needed to check that it reads the exports (Debian: apt install blender; scripts/setup.sh installs it)");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.strip_prefix("LUMIPROBE "))
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn blender_loads_the_exported_equirects_as_its_world_unclamped() {
    let tmp = tempfile::tempdir().unwrap();
    let (scene, run) = scene_with_predictions(tmp.path());
    let out = tmp.path().join("out");
    let o = lumiprobe(&[
        "export",
        scene.to_str().unwrap(),
        "--probes",
        run.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--frames",
        "0",
        "--formats",
        "hdr,exr",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (hdr, exr) = (out.join("frame_000.hdr"), out.join("frame_000.exr"));
    let seen = blender_reads(&[&hdr, &exr]);
    assert_eq!(seen.len(), 2, "{seen:?}");
    for (file, got, tol) in [(&hdr, &seen[0], 1e-2), (&exr, &seen[1], 1e-4)] {
        // lumiprobe's own reading of the same file is the reference.
        let img = read_hdr(file).unwrap();
        assert_eq!(
            got["size"],
            serde_json::json!([img.width(), img.height()]),
            "{got}"
        );
        assert_eq!(got["float"], true, "{got}");
        assert_eq!(got["world_image"], true, "{got}");
        let n = (img.width() * img.height()) as f64;
        for c in 0..3 {
            let mean = img.data()[c..]
                .iter()
                .step_by(3)
                .map(|&v| v as f64)
                .sum::<f64>()
                / n;
            let max = img.data()[c..]
                .iter()
                .step_by(3)
                .fold(0f32, |a, &v| a.max(v)) as f64;
            let (bm, bx) = (
                got["mean"][c].as_f64().unwrap(),
                got["max"][c].as_f64().unwrap(),
            );
            assert!(
                (bm / mean - 1.0).abs() < tol,
                "{}: channel {c} mean {bm} against {mean}",
                file.display()
            );
            // Not clamped: the brightest sample (the synthetic scene's lamps are
            // far above 1) comes through.
            assert!(
                max > 1.0 && (bx / max - 1.0).abs() < tol,
                "{}: channel {c} max {bx} against {max}",
                file.display()
            );
        }
    }
}
