use super::*;
use crate::sphere::{pixel_to_dir, rotate};
use crate::tonemap::Response;
use std::sync::Arc;

/// A panorama with blocky texture at several scales (corners for SIFT) and a lamp.
fn textured(w: usize, h: usize) -> HdrImage {
    let hash = |a: i32, b: i32, s: u32| -> f32 {
        let mut x = (a as u32).wrapping_mul(73856093)
            ^ (b as u32).wrapping_mul(19349663)
            ^ s.wrapping_mul(83492791);
        x ^= x >> 13;
        x = x.wrapping_mul(0x5bd1e995);
        x ^= x >> 15;
        (x & 0xffff) as f32 / 65535.0
    };
    HdrImage::from_fn(w, h, |x, y| {
        let d = pixel_to_dir(x, y, w, h);
        // Cells on the cube around the camera, so texture density is even.
        let (f, a, b) = CubeFace::of_dir(d);
        let s = f.index() as u32;
        let c1 = hash((a * 6.0).floor() as i32, (b * 6.0).floor() as i32, s);
        let c2 = hash((a * 17.0).floor() as i32, (b * 17.0).floor() as i32, s + 9);
        let v = 0.05 + 0.6 * c1 + 0.35 * c2;
        let lamp = if d.dot(Vec3::new(0.3, 0.9, -0.3).normalize()) > 0.995 {
            200.0
        } else {
            0.0
        };
        [v + lamp, 0.9 * v + lamp, 0.8 * v + lamp]
    })
}

fn pose(yaw: f32) -> Pose {
    Pose {
        position: Vec3::ZERO,
        world_from_camera: ypr_to_mat(yaw, 0.0, 0.0),
    }
}

#[test]
fn known_rotation_is_recovered_as_homographies() {
    let (w, h) = (512, 256);
    let probe_img = textured(w, h);
    let probe_pose = pose(0.0);
    let frame_pose = pose(30.0);
    let rel = frame_pose.from_other(&probe_pose);
    // The frame sees exactly the probe turned by 30 degrees (no parallax).
    let truth = rotate(&probe_img, rel, w, h);
    let resp = Response::Gamma { gamma: 2.2 };
    let sdr_codes: Vec<u8> = truth
        .data()
        .iter()
        .map(|&v| (resp.encode(v * 0.8) * 255.0 + 0.5) as u8)
        .collect();
    let sdr = SdrImage::from_vec(w, h, sdr_codes).unwrap();
    let lin = truth.clone();
    let probe = PreparedProbe::new(
        Arc::new(probe_img),
        probe_pose,
        ProbeTonemap::Camera,
        &resp,
        0.8,
    );
    let p = WarpParams {
        blur_sigma: 0.0,
        ..WarpParams::default()
    };
    let (out, rep) = warp_frame(&sdr, &lin, &frame_pose, &probe, &p, w, h).unwrap();
    let sides: Vec<&FaceReport> = rep.faces.iter().filter(|f| f.face.is_side()).collect();
    assert!(
        sides.iter().all(|f| f.source == "homography"),
        "{:#?}",
        rep.faces
    );
    // Each homography agrees with the rotation's at the face corners.
    for f in &sides {
        let hm = homography_to_dmat(&f.homography.unwrap());
        let cand = f.candidate.unwrap();
        let rot = ypr_to_mat(p.yaw_deg(cand.yaw_step), 0.0, 0.0);
        let hinv = hm.inverse();
        for &(a, b) in &[(-1.0f32, -1.0f32), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            let (qa, qb) = apply_h(&hinv, a as f64, b as f64).unwrap();
            let (ea, eb) = rotation_prediction(rel, rot, f.face, cand.face, a, b).unwrap();
            let err = ((qa as f32 - ea).powi(2) + (qb as f32 - eb).powi(2)).sqrt();
            assert!(err < 0.02, "{:?}: corner off by {err} face units", f.face);
        }
    }
    // And the warped HDR matches the truth, lamp included (no clamping): 99% of
    // pixels within 25% (only lamp and block edges, a pixel off, may exceed it).
    let mut errs = Vec::new();
    for y in 40..216 {
        for x in 0..w {
            let (a, b) = (out.get(x, y), truth.get(x, y));
            errs.push((a[1] - b[1]).abs() / b[1].max(0.2));
        }
    }
    errs.sort_by(f32::total_cmp);
    let p99 = errs[errs.len() * 99 / 100];
    let max_out = out.data().iter().cloned().fold(0.0f32, f32::max);
    assert!(max_out > 150.0, "lamp lost: max {max_out}");
    assert!(p99 < 0.25, "99th percentile relative error {p99}");
    let mean_err: f32 = out
        .data()
        .iter()
        .zip(truth.data())
        .map(|(a, b)| (a - b).abs() / b.max(0.2))
        .sum::<f32>()
        / out.data().len() as f32;
    assert!(mean_err < 0.03, "mean relative error {mean_err}");
}

#[test]
fn textureless_frame_falls_back_cleanly() {
    let (w, h) = (256, 128);
    let probe_img = textured(w, h);
    let flat = SdrImage::from_vec(w, h, vec![120; w * h * 3]).unwrap();
    let lin = HdrImage::from_fn(w, h, |_, _| [0.2, 0.2, 0.2]);
    let resp = Response::Srgb;
    let probe = PreparedProbe::new(
        Arc::new(probe_img.clone()),
        pose(0.0),
        ProbeTonemap::Reinhard05,
        &resp,
        1.0,
    );
    let (out, rep) = warp_frame(
        &flat,
        &lin,
        &pose(10.0),
        &probe,
        &WarpParams::default(),
        w,
        h,
    )
    .unwrap();
    assert!(rep.faces.iter().all(|f| f.source != "homography"));
    assert_eq!(out.count_invalid(), 0);
    // Away from the bottom face the output is the rotated probe.
    let expect = rotate(&probe_img, pose(10.0).from_other(&pose(0.0)), w, h);
    let (a, b) = (out.get(100, 64), expect.get(100, 64));
    assert!((a[0] - b[0]).abs() < 1e-4);
}

/// A frame that clipped everywhere (with its linearised copy: the white point's
/// radiance, far below the lamp) and a probe with a bright floor light straight
/// down, which the frame cannot measure.
fn white_frame_over_floor_light(w: usize, h: usize) -> (SdrImage, HdrImage, PreparedProbe) {
    let mut probe_img = textured(w, h);
    for y in h - 3..h {
        for x in 0..w {
            probe_img.set(x, y, [50.0, 50.0, 50.0]);
        }
    }
    white_frame_over(probe_img)
}

/// A frame of the probe's size that clipped everywhere, its linearised copy at
/// the white point, and the probe prepared at the origin.
fn white_frame_over(probe_img: HdrImage) -> (SdrImage, HdrImage, PreparedProbe) {
    let (w, h) = (probe_img.width(), probe_img.height());
    let white = SdrImage::from_vec(w, h, vec![255; w * h * 3]).unwrap();
    let lin = HdrImage::from_fn(w, h, |_, _| [1.0, 1.0, 1.0]);
    let probe = PreparedProbe::new(
        Arc::new(probe_img),
        pose(0.0),
        ProbeTonemap::Camera,
        &Response::Srgb,
        1.0,
    );
    (white, lin, probe)
}

#[test]
fn saturated_frame_takes_the_light_from_the_probe() {
    let (w, h) = (128, 64);
    let (white, lin, probe) = white_frame_over_floor_light(w, h);
    let (out, _) = warp_frame(
        &white,
        &lin,
        &pose(0.0),
        &probe,
        &WarpParams::default(),
        w,
        h,
    )
    .unwrap();
    assert_eq!(out.count_invalid(), 0);
    // Bottom rows: never below the SDR lower bound, and the probe's brighter
    // values come through.
    for x in 0..w {
        let o = out.get(x, h - 1);
        assert!(o[0] > 45.0, "floor light lost at column {x}: {o:?}");
    }
    for y in h - h / 8..h {
        for x in 0..w {
            assert!(
                out.get(x, y)[1] >= 1.0 - 1e-4,
                "below the SDR bound at {x},{y}"
            );
        }
    }
}

#[test]
fn unbounded_bottom_face_gives_the_probes_own_radiance_where_the_frame_clipped() {
    let (w, h) = (128, 64);
    // A dark probe floor under a frame that clipped everywhere.
    let probe_img = HdrImage::from_fn(w, h, |_, y| {
        if y >= h - 4 {
            [0.25, 0.5, 0.75]
        } else {
            [0.3, 0.3, 0.3]
        }
    });
    let (white, lin, probe) = white_frame_over(probe_img);
    let run = |bounded: bool| {
        let p = WarpParams {
            bottom_bounded_by_frame: bounded,
            ..WarpParams::default()
        };
        warp_frame(&white, &lin, &pose(0.0), &probe, &p, w, h)
            .unwrap()
            .0
    };
    let (bounded, own) = (run(true), run(false));
    for x in 0..w {
        let (b, o) = (bounded.get(x, h - 1), own.get(x, h - 1));
        // Bounded: the frame's lower bound wins over the darker probe.
        assert!(b.iter().all(|&v| (v - 1.0).abs() < 1e-4), "{b:?} at {x}");
        // Unbounded: the probe's own floor.
        for (k, want) in [0.25, 0.5, 0.75].into_iter().enumerate() {
            assert!((o[k] - want).abs() < 1e-3, "{o:?} at {x}");
        }
    }
}

#[test]
fn a_saturated_frame_at_another_output_size_still_takes_the_light_from_the_probe() {
    let (w, h) = (128, 64);
    let (white, lin, probe) = white_frame_over_floor_light(w, h);
    // Twice the frame's size: the bottom face samples the frame.
    let (ow, oh) = (2 * w, 2 * h);
    let p = WarpParams::default();
    let (out, _) = warp_frame(&white, &lin, &pose(0.0), &probe, &p, ow, oh).unwrap();
    for x in 0..ow {
        let o = out.get(x, oh - 1);
        assert!(o[0] > 45.0, "floor light lost at column {x}: {o:?}");
    }
    // A linearised copy of another size is refused.
    let small = HdrImage::from_fn(w / 2, h / 2, |_, _| [1.0, 1.0, 1.0]);
    let err = warp_frame(&white, &small, &pose(0.0), &probe, &p, w, h).unwrap_err();
    assert!(err.to_string().contains("64x32"), "{err}");
}

#[test]
fn degenerate_homographies_are_rejected() {
    let p = WarpParams::default();
    let rel = Mat3::IDENTITY;
    let rot = Mat3::IDENTITY;
    let f = CubeFace::Front;
    // Identity passes.
    assert!(check_homography(&DMat3::IDENTITY, rel, rot, f, f, &p).is_none());
    // Mirror, collapse, huge scale, far from the rotation, non-finite.
    let mirror = DMat3::from_diagonal(DVec3::new(-1.0, 1.0, 1.0));
    let collapse = DMat3::from_diagonal(DVec3::new(1.0, 0.0, 1.0));
    let zoom = DMat3::from_diagonal(DVec3::new(5.0, 5.0, 1.0));
    let shift = DMat3::from_cols(DVec3::X, DVec3::Y, DVec3::new(0.9, 0.0, 1.0));
    let nan = DMat3::from_diagonal(DVec3::new(f64::NAN, 1.0, 1.0));
    let behind = DMat3::from_cols(DVec3::X, DVec3::Y, DVec3::new(0.0, 0.0, -1.0));
    for (name, hm) in [
        ("mirror", mirror),
        ("collapse", collapse),
        ("zoom", zoom),
        ("shift", shift),
        ("nan", nan),
        ("behind", behind),
    ] {
        assert!(
            check_homography(&hm, rel, rot, f, f, &p).is_some(),
            "{name} accepted"
        );
    }
}
