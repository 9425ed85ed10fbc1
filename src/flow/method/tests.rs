use super::*;
use crate::synth::rng::SplitMix64;

const W: usize = 128;
const H: usize = 64;
/// The clipped region of the test frame: columns 40..60, rows 20..30.
fn in_region(x: usize, y: usize) -> bool {
    (40..60).contains(&x) && (20..30).contains(&y)
}
fn on_rim(x: usize, y: usize) -> bool {
    in_region(x, y) && !((42..58).contains(&x) && (22..28).contains(&y))
}

/// A textured frame whose region clips, its radiance, and the camera.
fn frame() -> (SdrImage, HdrImage, Response) {
    let resp = Response::Gamma { gamma: 2.2 };
    let mut rng = SplitMix64::new(7);
    let mut sdr = SdrImage::new(W, H);
    for y in 0..H {
        for x in 0..W {
            let v = if in_region(x, y) {
                255
            } else {
                rng.range(30.0, 200.0) as u8
            };
            let o = 3 * (y * W + x);
            sdr.data_mut()[o..o + 3].copy_from_slice(&[v, v, v]);
        }
    }
    let lin = HdrImage::from_fn(W, H, |x, y| {
        let c = sdr.get(x, y);
        [0, 1, 2].map(|k| resp.decode(c[k] as f32 / 255.0))
    });
    (sdr, lin, resp)
}

/// The frame's radiance outside the region, `inside(x, y)` in it.
fn source(lin: &HdrImage, inside: impl Fn(usize, usize) -> f32) -> HdrImage {
    HdrImage::from_fn(W, H, |x, y| {
        if in_region(x, y) {
            [inside(x, y); 3]
        } else {
            lin.get(x, y)
        }
    })
}

/// Share of region pixels (interior only when `interior`) whose output is `v`.
fn share(out: &HdrImage, v: f32, interior: bool) -> f32 {
    let mut n = 0;
    let mut hit = 0;
    for y in 0..H {
        for x in 0..W {
            if in_region(x, y) && !(interior && on_rim(x, y)) {
                n += 1;
                if (out.get(x, y)[1] - v).abs() < 0.05 * v {
                    hit += 1;
                }
            }
        }
    }
    hit as f32 / n as f32
}

#[test]
fn a_clipped_channel_charges_only_labels_darker_than_the_frame() {
    // Red clipped (code 255, display 1.0); green and blue measured.
    let frame = [1.0, 0.5, 0.25];
    let clipped = [true, false, false];
    // A label brighter than the clip in red agrees with the frame there.
    let bright = colour_cost(&[1.0, 0.5, 0.25], &frame, &clipped);
    let brighter = colour_cost(&[1.0, 0.5, 0.25], &[0.98, 0.5, 0.25], &clipped);
    assert_eq!(bright, 0.0);
    assert_eq!(
        brighter, 0.0,
        "a label above a clipped channel costs nothing"
    );
    // One darker than the clip in red contradicts it.
    let dark = colour_cost(&[0.7, 0.5, 0.25], &frame, &clipped);
    assert!((dark - 0.1).abs() < 1e-6, "{dark}");
    // Measured channels are charged both ways.
    let off = colour_cost(&[1.0, 0.8, 0.25], &frame, &clipped);
    assert!((off - 0.1).abs() < 1e-6, "{off}");
    let off = colour_cost(&[1.0, 0.2, 0.25], &frame, &clipped);
    assert!((off - 0.1).abs() < 1e-6, "{off}");
}

#[test]
fn a_label_darker_than_the_clip_level_does_not_fill_a_clipped_pixel() {
    let (sdr, lin, resp) = frame();
    // The far probe has the lamp; the near one is dark where the frame clipped.
    let lamp = source(&lin, |_, _| 50.0);
    let dark = source(&lin, |_, _| 0.5);
    let sources = [
        Source {
            name: "far".into(),
            image: &lamp,
            distance_m: 2.0,
        },
        Source {
            name: "near".into(),
            image: &dark,
            distance_m: 0.5,
        },
    ];
    let p = FlowMethodParams::default();
    let (out, rep) = flow_frame(&sdr, &lin, &sources, &resp, 1.0, &p).unwrap();
    assert!(share(&out, 50.0, false) > 0.9, "{:?}", rep.label_fractions);
    // With the thesis's unit weights the distance prior wins and the lamp is
    // lost: the reason for the defaults.
    let thesis = FlowMethodParams {
        dc_weight: 1.0,
        clipped_dc_weight: 1.0,
        ..Default::default()
    };
    let (out, _) = flow_frame(&sdr, &lin, &sources, &resp, 1.0, &thesis).unwrap();
    assert!(share(&out, 0.5, false) > 0.5);
}

#[test]
fn a_clipped_region_takes_the_label_its_rim_supports() {
    let (sdr, lin, resp) = frame();
    // Both probes are saturated inside the region, but the near probe's lamp
    // is smaller: dark on the region's rim, where the frame clipped.
    let whole = source(&lin, |_, _| 50.0);
    let small = source(&lin, |x, y| if on_rim(x, y) { 0.5 } else { 20.0 });
    let sources = [
        Source {
            name: "far".into(),
            image: &whole,
            distance_m: 2.0,
        },
        Source {
            name: "near".into(),
            image: &small,
            distance_m: 0.5,
        },
    ];
    let p = FlowMethodParams::default();
    let (out, rep) = flow_frame(&sdr, &lin, &sources, &resp, 1.0, &p).unwrap();
    assert!(share(&out, 50.0, true) > 0.9, "{:?}", rep.label_fractions);
    assert!(rep.energy_history.windows(2).all(|w| w[1] <= w[0] + 1e-6));
    // Per pixel, the interior (no evidence there) goes to the nearer probe.
    let abl = FlowMethodParams {
        no_smoothness: true,
        ..Default::default()
    };
    let (out, _) = flow_frame(&sdr, &lin, &sources, &resp, 1.0, &abl).unwrap();
    assert!(share(&out, 20.0, true) > 0.9);
}

#[test]
fn a_measured_pixel_keeps_its_label_next_to_a_clipped_region() {
    // A smooth frame (so the flow is near zero and warping keeps values) whose
    // region clips.
    let (mut sdr, _, resp) = frame();
    for y in 0..H {
        for x in 0..W {
            if !in_region(x, y) {
                let v = 110.0 + 60.0 * (x as f32 / 9.0).sin() * (y as f32 / 7.0).cos();
                let o = 3 * (y * W + x);
                sdr.data_mut()[o..o + 3].fill(v as u8);
            }
        }
    }
    let lin = HdrImage::from_fn(W, H, |x, y| {
        let c = sdr.get(x, y);
        [0, 1, 2].map(|k| resp.decode(c[k] as f32 / 255.0))
    });
    // The ring of measured pixels around the region.
    let ring =
        |x: usize, y: usize| !in_region(x, y) && (39..61).contains(&x) && (19..31).contains(&y);
    // "exact" matches the frame on the ring but is below white in the region; "lamp"
    // fills the region but is 15% off on the ring.
    let exact = source(&lin, |_, _| 0.9);
    let lamp = HdrImage::from_fn(W, H, |x, y| {
        if in_region(x, y) {
            [50.0; 3]
        } else if ring(x, y) {
            lin.get(x, y).map(|v| 1.15 * v)
        } else {
            lin.get(x, y)
        }
    });
    let sources = [
        Source {
            name: "exact".into(),
            image: &exact,
            distance_m: 1.0,
        },
        Source {
            name: "lamp".into(),
            image: &lamp,
            distance_m: 1.0,
        },
    ];
    // Share of ring pixels output nearer the frame's radiance than the lamp's.
    let ring_exact = |out: &HdrImage| {
        let (mut n, mut hit) = (0, 0);
        for y in 0..H {
            for x in 0..W {
                if ring(x, y) {
                    n += 1;
                    let (o, f) = (out.get(x, y)[1], lin.get(x, y)[1]);
                    hit += usize::from((o - f).abs() < (o - 1.15 * f).abs());
                }
            }
        }
        hit as f32 / n as f32
    };
    let p = FlowMethodParams {
        measured_decides: true,
        ..Default::default()
    };
    let (out, _) = flow_frame(&sdr, &lin, &sources, &resp, 1.0, &p).unwrap();
    assert!(share(&out, 50.0, false) > 0.9);
    assert!(ring_exact(&out) > 0.8, "{}", ring_exact(&out));
    // Without it the Potts term pulls the ring onto the region's label where the
    // ring's evidence is weaker than a label change (0.84 against 0.38 here; the
    // rest of the ring prefers the lamp on its flow confidence alone).
    let pulled = FlowMethodParams {
        measured_decides: false,
        ..Default::default()
    };
    let (out, _) = flow_frame(&sdr, &lin, &sources, &resp, 1.0, &pulled).unwrap();
    assert!(share(&out, 50.0, false) > 0.9);
    assert!(ring_exact(&out) < 0.5, "{}", ring_exact(&out));
}

#[test]
fn a_nan_or_negative_cost_is_an_error_naming_it() {
    let (sdr, lin, resp) = frame();
    let src = source(&lin, |_, _| 50.0);
    let sources = [Source {
        name: "probe".into(),
        image: &src,
        distance_m: 1.0,
    }];
    for p in [
        FlowMethodParams {
            sdr_cost: f32::NAN,
            ..Default::default()
        },
        FlowMethodParams {
            sdr_cost: -1.0,
            ..Default::default()
        },
    ] {
        let e = flow_frame(&sdr, &lin, &sources, &resp, 1.0, &p).unwrap_err();
        assert!(e.to_string().contains("SDR label cost"), "{e}");
    }
    let p = FlowMethodParams {
        light_ring_deg: f32::NAN,
        ..Default::default()
    };
    let e = flow_frame(&sdr, &lin, &sources, &resp, 1.0, &p).unwrap_err();
    assert!(e.to_string().contains("light ring"), "{e}");
}

#[test]
fn restoring_warped_lights_checks_sizes_and_settings() {
    let (sdr, lin, resp) = frame();
    let src = source(&lin, |_, _| 50.0);
    let unwarped: Vec<RotatedSource> = (0..2)
        .map(|i| RotatedSource {
            name: format!("probe{i}"),
            image: &src,
            rotation: Mat3::IDENTITY,
            distance_m: 1.0,
        })
        .collect();
    let p = FlowMethodParams::default();
    let mut small = vec![HdrImage::new(4, 2), HdrImage::new(4, 2)];
    let e = restore_warped_lights(&sdr, &mut small, &unwarped, &resp, 1.0, &p).unwrap_err();
    assert!(e.to_string().contains("4x2"), "{e}");
    let mut one = vec![src.clone()];
    let e = restore_warped_lights(&sdr, &mut one, &unwarped, &resp, 1.0, &p).unwrap_err();
    assert!(e.to_string().contains("1 warped probes for 2"), "{e}");
    let nan = FlowMethodParams {
        light_reach_deg: f32::NAN,
        ..Default::default()
    };
    let mut two = vec![src.clone(), src.clone()];
    let e = restore_warped_lights(&sdr, &mut two, &unwarped, &resp, 1.0, &nan).unwrap_err();
    assert!(e.to_string().contains("light reach"), "{e}");
}

#[test]
fn wide_frames_are_reduced_by_an_integer_factor() {
    let p = FlowMethodParams::default();
    assert_eq!(p.work_factor(512), 1);
    assert_eq!(p.work_factor(2048), 1);
    assert_eq!(p.work_factor(2049), 2);
    assert_eq!(p.work_factor(7776), 4);
    let full = FlowMethodParams {
        work_width: 0,
        ..Default::default()
    };
    assert_eq!(full.work_factor(7776), 1);
}

#[test]
fn a_reduced_working_size_gives_the_full_size_result() {
    use crate::sphere::{pixel_to_dir, rotate, ypr_to_mat};
    // A smooth probe, seen by the frame through a rotation.
    let (w, h) = (128, 64);
    let probe = HdrImage::from_fn(w, h, |x, y| {
        let d = pixel_to_dir(x, y, w, h);
        let v = 0.3 + 0.2 * (3.0 * d.x).sin() + 0.1 * d.y;
        [v, 0.8 * v, 0.6 * v]
    });
    let rot = ypr_to_mat(30.0, 0.0, 0.0);
    let truth = rotate(&probe, rot, w, h);
    let resp = Response::Gamma { gamma: 2.2 };
    let codes = truth
        .data()
        .iter()
        .map(|&v| (resp.encode(v) * 255.0 + 0.5) as u8)
        .collect();
    let sdr = SdrImage::from_vec(w, h, codes).unwrap();
    let lin = HdrImage::from_fn(w, h, |x, y| {
        let c = sdr.get(x, y);
        [0, 1, 2].map(|k| resp.decode(c[k] as f32 / 255.0))
    });
    let src = [RotatedSource {
        name: "probe".into(),
        image: &probe,
        rotation: rot,
        distance_m: 1.0,
    }];
    let full = FlowMethodParams {
        work_width: 0,
        ..Default::default()
    };
    let reduced = FlowMethodParams {
        work_width: 64,
        ..Default::default()
    };
    let (a, ra) = flow_frame_scaled(&sdr, &lin, &src, &resp, 1.0, &full).unwrap();
    let (b, rb) = flow_frame_scaled(&sdr, &lin, &src, &resp, 1.0, &reduced).unwrap();
    assert_eq!(ra.work_size, None);
    assert_eq!(rb.work_size, Some((64, 32)));
    // At factor 1 it is the flow method on the rotated probe, bit for bit.
    let rotated = rotate(&probe, rot, w, h);
    let plain = [Source {
        name: "probe".into(),
        image: &rotated,
        distance_m: 1.0,
    }];
    assert_eq!(
        flow_frame(&sdr, &lin, &plain, &resp, 1.0, &full).unwrap().0,
        a
    );
    // Both take the probe and reproduce the truth.
    for (out, rep) in [(&a, &ra), (&b, &rb)] {
        assert!(rep.label_fractions[0] > 0.99, "{:?}", rep.label_fractions);
        assert_eq!((out.width(), out.height()), (w, h));
        let err = out
            .data()
            .iter()
            .zip(truth.data())
            .map(|(o, t)| (o - t).abs() / t.max(0.05))
            .sum::<f32>()
            / out.data().len() as f32;
        assert!(err < 0.02, "mean relative error {err}");
    }
}

#[test]
fn a_distant_sun_keeps_the_rotations_alignment_where_the_flow_would_move_it() {
    // Near texture everywhere, shifted 2 px one way in one probe and the other
    // way in the other (parallax), and a 2 x 2 sun straddling the seam that both
    // probes and the frame see in the same place (no parallax: it is distant).
    let resp = Response::Gamma { gamma: 2.2 };
    let sun = |x: usize, y: usize| (x == 0 || x == W - 1) && (y == 30 || y == 31);
    let texture = |x: i64, y: usize| {
        let mut r = SplitMix64::new((y as u64) * 1000 + x.rem_euclid(W as i64) as u64);
        r.range(0.02, 0.6) as f32
    };
    let scene = |shift: i64| {
        HdrImage::from_fn(W, H, |x, y| {
            if sun(x, y) {
                [1e4; 3]
            } else {
                [texture(x as i64 + shift, y); 3]
            }
        })
    };
    let truth = scene(0);
    let mut sdr = SdrImage::new(W, H);
    for y in 0..H {
        for x in 0..W {
            let v = truth.get(x, y);
            let c = v.map(|r| (resp.encode(r) * 255.0).round().clamp(0.0, 255.0) as u8);
            let o = 3 * (y * W + x);
            sdr.data_mut()[o..o + 3].copy_from_slice(&c);
        }
    }
    let lin = HdrImage::from_fn(W, H, |x, y| {
        sdr.get(x, y).map(|c| resp.decode(c as f32 / 255.0))
    });
    let (left, right) = (scene(2), scene(-2));
    let sources = [
        Source {
            name: "left".into(),
            image: &left,
            distance_m: 1.0,
        },
        Source {
            name: "right".into(),
            image: &right,
            distance_m: 1.0,
        },
    ];
    let sun_light = |out: &HdrImage| {
        let mut s = 0.0f32;
        for y in 0..H {
            for x in 0..W {
                if sun(x, y) {
                    s += out.get(x, y)[1];
                }
            }
        }
        s / 4e4
    };
    let p = FlowMethodParams::default();
    let (out, rep) = flow_frame(&sdr, &lin, &sources, &resp, 1.0, &p).unwrap();
    assert!(
        rep.distant_light_px.iter().all(|&n| n > 0),
        "{:?}",
        rep.distant_light_px
    );
    let kept = sun_light(&out);
    assert!(kept > 0.95, "share of the sun kept {kept}");
    // Without it the flow, interpolated from the shifted texture, moves the sun.
    let off = FlowMethodParams {
        distant_light_deg: 0.0,
        ..Default::default()
    };
    let (out, rep) = flow_frame(&sdr, &lin, &sources, &resp, 1.0, &off).unwrap();
    assert_eq!(rep.distant_light_px, vec![0, 0]);
    let moved = sun_light(&out);
    assert!(moved < 0.8 * kept, "kept {kept}, without {moved}");
}

#[test]
fn a_working_pixel_partly_clipped_bounds_its_light_from_below() {
    // A one-pixel lamp at full size, inside a 2 x 2 working pixel whose average
    // code stays under the clip code. The probe with the lamp must win there
    // over the one without it.
    let (w, h) = (128, 64);
    let lamp_at = |x: usize, y: usize| (x, y) == (41, 21);
    let base = |x: usize, y: usize| {
        let v = 0.3 + 0.1 * ((x as f32) * 0.2).sin() + 0.002 * y as f32;
        [v, v, v]
    };
    let lamp = HdrImage::from_fn(
        w,
        h,
        |x, y| if lamp_at(x, y) { [1e3; 3] } else { base(x, y) },
    );
    let dark = HdrImage::from_fn(w, h, base);
    let resp = Response::Gamma { gamma: 2.2 };
    let codes = lamp
        .data()
        .iter()
        .map(|&v| (resp.encode(v).min(1.0) * 255.0 + 0.5) as u8)
        .collect();
    let sdr = SdrImage::from_vec(w, h, codes).unwrap();
    let lin = HdrImage::from_fn(w, h, |x, y| {
        sdr.get(x, y).map(|c| resp.decode(c as f32 / 255.0))
    });
    let src = [
        RotatedSource {
            name: "dark".into(),
            image: &dark,
            rotation: Mat3::IDENTITY,
            distance_m: 1.0,
        },
        RotatedSource {
            name: "lamp".into(),
            image: &lamp,
            rotation: Mat3::IDENTITY,
            distance_m: 1.0,
        },
    ];
    let p = FlowMethodParams {
        work_width: 64,
        ..Default::default()
    };
    let (out, rep) = flow_frame_scaled(&sdr, &lin, &src, &resp, 1.0, &p).unwrap();
    assert_eq!(rep.work_size, Some((64, 32)));
    let got = out.get(41, 21)[1];
    assert!(got > 900.0, "the lamp's pixel holds {got}");
}

/// Flow settings with working width `w`.
fn w(work_width: usize) -> FlowMethodParams {
    FlowMethodParams {
        work_width,
        ..Default::default()
    }
}

#[test]
fn fusions_base_works_at_most_at_its_angular_pixel_size() {
    let deg = crate::fusion::FusionParams::default().base_pixel_deg;
    assert_eq!(w(2048).work_width_at_most(deg), 256);
    assert_eq!(w(0).work_width_at_most(deg), 256);
    assert_eq!(w(128).work_width_at_most(deg), 128);
    assert_eq!(w(2048).work_width_at_most(0.7), 514);
    assert_eq!(w(2048).work_width_at_most(0.0), 2048);
    assert_eq!(w(2048).work_width_at_most(f32::NAN), 2048);
    // A 256-wide frame keeps its full size; a 512-wide one halves.
    let p = FlowMethodParams {
        work_width: w(2048).work_width_at_most(deg),
        ..Default::default()
    };
    assert_eq!(p.work_factor(256), 1);
    assert_eq!(p.work_factor(512), 2);
    assert_eq!(p.work_factor(7776), 31);
    // The base's finest flow level: as the preset gives it up to 256 wide,
    // then no finer than 4 of those pixels (5.625 degrees).
    let flow_deg = crate::fusion::FusionParams::default().base_flow_deg;
    assert_eq!(p.finest_scale_at_least(128, flow_deg), None);
    assert_eq!(p.finest_scale_at_least(256, flow_deg), None);
    assert_eq!(p.finest_scale_at_least(512, flow_deg), Some(3));
    assert_eq!(p.finest_scale_at_least(7776, flow_deg), Some(7));
    assert_eq!(p.finest_scale_at_least(512, 0.0), None);
    let medium = FlowMethodParams {
        flow: crate::flow::dense::FlowParams {
            finest_scale: Some(5),
            ..Default::default()
        },
        ..p.clone()
    };
    assert_eq!(medium.finest_scale_at_least(512, flow_deg), Some(5));
}
