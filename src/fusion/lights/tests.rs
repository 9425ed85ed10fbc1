//! Tests of light placement, surfaces and views.

use super::*;

#[test]
fn a_lamp_seen_by_two_probes_is_placed_and_scaled() {
    let lamp = Vec3::new(1.0, 0.5, 2.6);
    let (pa, pb) = (Vec3::new(0.0, 0.0, 1.5), Vec3::new(2.0, 0.0, 1.5));
    let la = Light {
        dir: (lamp - pa).normalize(),
        power: 2.0,
        solid_angle: 0.01,
        ..Default::default()
    };
    let lb = Light {
        dir: (lamp - pb).normalize(),
        power: 2.0,
        solid_angle: 0.01,
        ..Default::default()
    };
    let far = Light {
        dir: Vec3::new(0.0, -1.0, 0.0),
        power: 1.0,
        solid_angle: 0.01,
        ..Default::default()
    };
    let placed = triangulate(&[la, far.clone()], pa, &[far, lb], pb, 0.2, f64::INFINITY);
    assert_eq!(placed.len(), 2);
    let lamp_light = placed.iter().find(|p| !p.at_infinity).unwrap();
    assert!(lamp_light.position.distance(lamp) < 1e-3);
    // Halfway between, closer to the lamp: more power than either probe saw.
    let frame = Vec3::new(1.0, 0.5, 1.6);
    let (dir, power) = lamp_light.seen_from(frame);
    assert!(dir.dot(Vec3::Z) > 0.999);
    let expect = 2.0 * (lamp.distance(pa) as f64 / 1.0).powi(2);
    assert!(
        (power - expect).abs() / expect < 1e-3,
        "{power} vs {expect}"
    );
    let sun = placed.iter().find(|p| p.at_infinity).unwrap();
    assert!((sun.seen_from(frame).1 - 1.0).abs() < 1e-9);
}

#[test]
fn lights_at_a_frame_do_not_depend_on_the_poses_unit() {
    // A lamp seen by two probes, drawn as a bright disc of 4 degrees around
    // its direction from each; the same walk in metres and in centimetres.
    let (w, h) = (256, 128);
    let lamp = Vec3::new(1.0, 0.4, 2.5);
    // Probe b sees the lamp 10 cm higher (the centroids of an extended lamp
    // seen from two sides): the rays miss by about 0.1 m, within a tenth of
    // the 2 m between the probes, but 10 units once the walk is in cm.
    let probe = |at: Vec3, lamp: Vec3| {
        let to = (lamp - at).normalize();
        let img = HdrImage::from_fn(w, h, |x, y| {
            if pixel_to_dir(x, y, w, h).dot(to) > 4f32.to_radians().cos() {
                [50.0, 40.0, 30.0]
            } else {
                [0.2, 0.2, 0.2]
            }
        });
        let pose = Pose {
            position: at,
            world_from_camera: glam::Mat3::IDENTITY,
        };
        (img, pose)
    };
    let a = probe(Vec3::new(0.0, 0.0, 1.5), lamp);
    let b = probe(Vec3::new(2.0, 0.0, 1.5), lamp + Vec3::new(0.0, 0.0, 0.1));
    let frame = Pose {
        position: Vec3::new(0.8, 0.3, 1.5),
        world_from_camera: glam::Mat3::IDENTITY,
    };
    let p = FusionParams::default();
    let metres = lights_at_frame((&a.0, &a.1), (&b.0, &b.1), &frame, 1.0, &p);
    assert_eq!(metres.len(), 1);
    let scaled = |q: &Pose| Pose {
        position: q.position * 100.0,
        ..*q
    };
    let (sa, sb, sf) = (scaled(&a.1), scaled(&b.1), scaled(&frame));
    let centimetres = lights_at_frame((&a.0, &sa), (&b.0, &sb), &sf, 1.0, &p);
    assert_eq!(centimetres.len(), 1);
    let (m, d) = (metres[0], centimetres[0]);
    assert!(m.dir.dot(d.dir) > 0.99999);
    assert!(
        (m.power - d.power).abs() < 1e-4 * m.power,
        "{} vs {}",
        m.power,
        d.power
    );
    assert!((m.radiance - d.radiance).abs() < 1e-9 * m.radiance);
    // Nearer the lamp than either probe: more power than either saw.
    assert!(m.power > metres_power_seen(&a.0, &a.1) && m.power > metres_power_seen(&b.0, &b.1));
}

fn metres_power_seen(img: &HdrImage, pose: &Pose) -> f64 {
    find_lights(img, pose, 1.0, 0.7)
        .iter()
        .map(|l| l.power)
        .sum()
}

#[test]
fn fragments_of_one_lamp_closer_than_the_join_angle_are_one_light() {
    // Two bright patches two pixels apart (one dark column between them) on a
    // 512-wide panorama (0.7 degrees per pixel).
    let (w, h) = (512, 256);
    let img = HdrImage::from_fn(w, h, |x, y| {
        let lit =
            (100..=102).contains(&y) && ((200..=203).contains(&x) || (205..=208).contains(&x));
        if lit {
            [10.0, 10.0, 10.0]
        } else {
            [0.1, 0.1, 0.1]
        }
    });
    let pose = Pose {
        position: Vec3::ZERO,
        world_from_camera: glam::Mat3::IDENTITY,
    };
    let apart = find_lights(&img, &pose, 1.0, 0.0);
    assert_eq!(apart.len(), 2);
    let joined = find_lights(&img, &pose, 1.0, 0.7);
    assert_eq!(joined.len(), 1);
    // Joining adds no power and no solid angle: only the bright pixels count.
    let sum = |v: &[Light], f: fn(&Light) -> f64| v.iter().map(f).sum::<f64>();
    assert!((sum(&joined, |l| l.power) - sum(&apart, |l| l.power)).abs() < 1e-9);
    assert!((sum(&joined, |l| l.solid_angle) - sum(&apart, |l| l.solid_angle)).abs() < 1e-12);
}

#[test]
fn the_probe_that_extrapolates_least_weighs_most() {
    let light = PlacedLight {
        position: Vec3::ZERO,
        at_infinity: false,
        dir: Vec3::ZERO,
        seen: [(4.0, 1.0), (0.3, 3.0)],
        radiance: [1.0, 1.0],
        peak: [1.0, 1.0],
        from: (0, 0),
    };
    // Seen from 1.1 m: probe A (at 1 m) predicts 4 / 1.21, probe B (at 3 m)
    // 0.3 * 9 / 1.21.
    let (_, p) = light.seen_from(Vec3::new(1.1, 0.0, 0.0));
    let (a, b) = (4.0 / 1.21, 2.7 / 1.21);
    assert!(p > b && p < a, "{p}");
    assert!((p - a).abs() < 0.25 * (a - b), "{p} should be near {a}");
    // Where both extrapolate as much, both count the same.
    let (_, p) = light.seen_from(Vec3::new(3.0f32.sqrt(), 0.0, 0.0));
    assert!((p - 0.5 * (4.0 / 3.0 + 0.3 * 3.0)).abs() < 1e-4, "{p}");
}

#[test]
fn probes_that_disagree_on_a_lights_intensity_are_inconsistent() {
    let lamp = Vec3::new(1.0, 0.5, 2.6);
    let (pa, pb) = (Vec3::new(0.0, 0.0, 1.5), Vec3::new(3.0, 0.0, 1.5));
    let (da, db) = (lamp.distance(pa) as f64, lamp.distance(pb) as f64);
    let light = |pw_a: f64, pw_b: f64| {
        let la = Light {
            dir: (lamp - pa).normalize(),
            power: pw_a,
            solid_angle: 0.01,
            ..Default::default()
        };
        let lb = Light {
            dir: (lamp - pb).normalize(),
            power: pw_b,
            solid_angle: 0.01,
            ..Default::default()
        };
        triangulate(&[la], pa, &[lb], pb, 0.2, f64::INFINITY)[0]
    };
    // A compact source: power falls with the squared distance, same intensity.
    assert!(light(1.0, (da / db).powi(2)).consistent(2.0));
    // One probe sees ten times the intensity (a window seen whole by one probe,
    // as a sliver by the other).
    assert!(!light(1.0, 0.1 * (da / db).powi(2)).consistent(2.0));
    assert!(!light(0.0, 1.0).consistent(2.0));
    // Radiance is power over solid angle.
    assert!((light(1.0, 1.0).radiance[0] - 100.0).abs() < 1e-9);
}

/// A room whose ceiling (z = 2.6) holds a 0.6 m square panel centred at (1.0,
/// 0.5), lighting the ceiling around it; walls and floor dim.
pub(crate) fn ceiling_room(from: Vec3, d: Vec3) -> [f32; 3] {
    if d.z <= 1e-4 {
        return [0.3, 0.3, 0.3];
    }
    let x = from + d * ((2.6 - from.z) / d.z);
    let (dx, dy) = (x.x - 1.0, x.y - 0.5);
    if dx.abs() < 0.3 && dy.abs() < 0.3 {
        return [60.0, 50.0, 40.0];
    }
    let g = 1.0 + 5.0 * (-(dx * dx + dy * dy) / 0.36).exp();
    [g, 0.9 * g, 0.8 * g]
}

/// An upright camera (its y axis along world z) at `at`.
pub(crate) fn upright(at: Vec3) -> Pose {
    Pose {
        position: at,
        world_from_camera: glam::Mat3::from_cols(Vec3::X, Vec3::Z, -Vec3::Y),
    }
}

/// The panorama a camera with `pose` takes of [`ceiling_room`].
pub(crate) fn render(pose: &Pose, w: usize, h: usize) -> HdrImage {
    HdrImage::from_fn(w, h, |x, y| {
        ceiling_room(
            pose.position,
            pose.world_from_camera * pixel_to_dir(x, y, w, h),
        )
    })
}

/// [`render`] as a camera (or a path tracer) records it: each pixel the mean
/// over its area (4 x 4 samples), so an edge falls over a pixel or two.
pub(crate) fn render_area(pose: &Pose, w: usize, h: usize) -> HdrImage {
    HdrImage::from_fn(w, h, |x, y| {
        let mut acc = [0.0f32; 3];
        for k in 0..16 {
            let u = (x as f32 + (k % 4) as f32 * 0.25 + 0.125) / w as f32;
            let v = (y as f32 + (k / 4) as f32 * 0.25 + 0.125) / h as f32;
            let c = ceiling_room(
                pose.position,
                pose.world_from_camera * crate::sphere::uv_to_dir(u, v),
            );
            for j in 0..3 {
                acc[j] += c[j] / 16.0;
            }
        }
        acc
    })
}

#[test]
fn a_ray_meets_a_plane_where_the_geometry_says_and_infinity_everywhere() {
    let ceiling = Surface::Plane {
        point: Vec3::new(0.0, 0.0, 2.0),
        normal: Vec3::Z,
    };
    let up = Vec3::new(0.6, 0.0, 0.8);
    // From the origin the ray meets the ceiling at (1.5, 0, 2); seen from
    // (1.5, 0, 0) that point is straight up.
    let v = ceiling
        .seen_from(Vec3::ZERO, up, Vec3::new(1.5, 0.0, 0.0))
        .unwrap();
    assert!(v.dot(Vec3::Z) > 0.99999, "{v}");
    // Parallel to the plane, or meeting it behind the origin: no point.
    assert!(ceiling.seen_from(Vec3::ZERO, Vec3::X, Vec3::ZERO).is_none());
    assert!(ceiling.seen_from(Vec3::ZERO, -up, Vec3::ZERO).is_none());
    // At infinity every camera sees it in the same direction.
    assert_eq!(
        Surface::Infinity.seen_from(Vec3::ZERO, up, Vec3::ONE),
        Some(up)
    );
}

#[test]
fn a_uniform_panel_seen_small_and_large_is_fitted_to_the_ceiling() {
    // No glow: only the panel's outline tells the planes apart. One probe is
    // almost under it, the other sees it small and far.
    let (w, h) = (256, 128);
    let room = |from: Vec3, d: Vec3| -> [f32; 3] {
        if d.z > 1e-4 {
            let x = from + d * ((2.6 - from.z) / d.z);
            if (x.x - 1.0).abs() < 0.3 && (x.y - 0.5).abs() < 0.3 {
                return [300.0, 280.0, 250.0];
            }
        }
        [0.5, 0.5, 0.5]
    };
    let render = |pose: &Pose| {
        HdrImage::from_fn(w, h, |x, y| {
            room(
                pose.position,
                pose.world_from_camera * pixel_to_dir(x, y, w, h),
            )
        })
    };
    let (a, b) = (
        upright(Vec3::new(0.8, 0.3, 1.5)),
        upright(Vec3::new(-1.6, -0.9, 1.5)),
    );
    let (ia, ib) = (render(&a), render(&b));
    let (la, lb) = (
        find_lights(&ia, &a, 2.0, 0.7),
        find_lights(&ib, &b, 2.0, 0.7),
    );
    assert_eq!((la.len(), lb.len()), (1, 1));
    assert!(la[0].pixels.len() > 3 * lb[0].pixels.len());
    let placed = triangulate(&la, a.position, &lb, b.position, 0.5, f64::INFINITY);
    assert_eq!(placed.len(), 1);
    let (surface, _) = fit_surface((&ia, &a), &la[0], (&ib, &b), &lb[0], placed[0].position);
    match surface {
        Surface::Plane { normal, .. } => assert!(normal.z.abs() > 0.999, "{normal}"),
        Surface::Infinity => panic!("the panel is not at infinity"),
    }
}

/// Two upright probes 2.2 m apart under the ceiling panel, and their panoramas.
fn two_probes(w: usize, h: usize) -> (Pose, Pose, HdrImage, HdrImage) {
    let (a, b) = (
        upright(Vec3::new(0.0, 0.0, 1.5)),
        upright(Vec3::new(2.2, 0.3, 1.5)),
    );
    let (ia, ib) = (render(&a, w, h), render(&b, w, h));
    (a, b, ia, ib)
}

#[test]
fn a_ceiling_panel_is_fitted_to_the_ceiling_and_carried_pixel_by_pixel() {
    let (w, h) = (256, 128);
    let (a, b, ia, ib) = two_probes(w, h);
    let white = 2.0;
    let (la, lb) = (
        find_lights(&ia, &a, white, 0.7),
        find_lights(&ib, &b, white, 0.7),
    );
    assert_eq!((la.len(), lb.len()), (1, 1));
    let placed = triangulate(&la, a.position, &lb, b.position, 0.2, f64::INFINITY);
    assert_eq!(placed.len(), 1);
    let point = placed[0].position;
    assert!((point.z - 2.6).abs() < 0.1, "{point}");
    let (surface, err) = fit_surface((&ia, &a), &la[0], (&ib, &b), &lb[0], point);
    match surface {
        Surface::Plane { normal, point } => {
            assert!(normal.z.abs() > 0.999, "{normal}");
            // The search along the normal finds the ceiling itself.
            assert!((point.z - 2.6).abs() < 0.03, "{point}");
        }
        Surface::Infinity => panic!("the panel is not at infinity"),
    }
    assert!(err < 0.1, "{err}");
    // A frame almost under the panel sees it far larger than either probe did.
    let frame = upright(Vec3::new(1.1, 0.6, 1.5));
    let truth = render(&frame, w, h);
    let view = LightView {
        surface,
        probes: [(&ia, &a), (&ib, &b)],
        frame,
    };
    let (mut close, mut lit) = (0, 0);
    let (mut got, mut want) = (0.0f64, 0.0f64);
    let sa = row_solid_angles(w, h);
    for (y, &row_sa) in sa.iter().enumerate() {
        for x in 0..w {
            let t = luminance(truth.get(x, y));
            if t <= white {
                continue;
            }
            lit += 1;
            let r = view
                .radiance(pixel_to_dir(x, y, w, h))
                .expect("the ceiling is up");
            if (luminance(r) / t - 1.0).abs() < 0.15 {
                close += 1;
            }
            got += luminance(r) as f64 * row_sa as f64;
            want += t as f64 * row_sa as f64;
        }
    }
    // Only pixels along the panel's edge, sampled between pixels, miss.
    assert!(close as f64 > 0.85 * lit as f64, "{close} of {lit}");
    assert!((got / want - 1.0).abs() < 0.05, "{got} vs {want}");
    // The panel faces the frame below it: its plane's normal, turned to the
    // frame's side, points down (world -z) in the frame's camera axes.
    let down = frame.world_from_camera.transpose() * Vec3::NEG_Z;
    let facing = Vec3::from_array(view.facing().expect("a panel on a plane"));
    assert!(
        facing.angle_between(down).to_degrees() < 2.0,
        "{facing} vs {down}"
    );
    let above = LightView {
        frame: upright(Vec3::new(1.1, 0.6, 3.5)),
        ..view
    };
    let up = above.frame.world_from_camera.transpose() * Vec3::Z;
    let facing = Vec3::from_array(above.facing().expect("a panel on a plane"));
    assert!(
        facing.angle_between(up).to_degrees() < 2.0,
        "{facing} vs {up}"
    );
    let far = LightView {
        surface: Surface::Infinity,
        ..view
    };
    assert_eq!(far.facing(), None);
}

#[test]
fn a_pairs_lights_found_once_serve_every_frame() {
    let (a, b, ia, ib) = two_probes(128, 64);
    let p = FusionParams::default();
    let pair = pair_lights((&ia, &a), (&ib, &b), 2.0, &p);
    assert!(!pair.lights.is_empty());
    assert!(pair.lights.iter().all(|(_, s)| s.is_some()));
    for at in [
        Vec3::new(1.1, 0.6, 1.5),
        Vec3::new(0.4, -0.2, 1.4),
        a.position,
    ] {
        let frame = upright(at);
        let once = pair.at_frame((&ia, &a), (&ib, &b), &frame);
        let each = lights_at_frame((&ia, &a), (&ib, &b), &frame, 2.0, &p);
        assert_eq!(once.len(), each.len());
        for (x, y) in once.iter().zip(&each) {
            assert_eq!((x.dir, x.power, x.radiance), (y.dir, y.power, y.radiance));
            assert_eq!(x.view.map(|v| v.surface), y.view.map(|v| v.surface));
            assert_eq!(x.view.map(|v| v.frame.position), Some(at));
        }
    }
}

#[test]
fn a_near_lamp_a_probe_sees_is_not_a_far_source_where_the_frame_does_not_see_it() {
    // A dim room (0.5) with a lamp ball of radius 0.1 m and radiance 1000. The
    // probe sees the lamp in direction `dw`; the frame, 1.4 m away, sees the wall
    // in that same direction.
    let lamp = Vec3::new(2.0, 0.0, 2.5);
    let ball = |from: Vec3, d: Vec3, r: f32| {
        let v = lamp - from;
        let t = v.dot(d);
        t > 0.0 && (v - t * d).length() <= r
    };
    let (w, h) = (256, 128);
    let probe = upright(Vec3::new(0.0, 0.0, 1.5));
    let img = HdrImage::from_fn(w, h, |x, y| {
        let d = probe.world_from_camera * pixel_to_dir(x, y, w, h);
        if ball(probe.position, d, 0.1) {
            [1000.0; 3]
        } else {
            [0.5; 3]
        }
    });
    let frame = upright(Vec3::new(1.0, -1.0, 1.5));
    let dw = (lamp - probe.position).normalize();
    assert!(!ball(frame.position, dw, 0.1));
    let d = frame.world_from_camera.transpose() * dw;
    let sky = |near: Vec<NearLight>| SkyView {
        probes: vec![(&img, &probe)],
        frame,
        floor: 1.0,
        near,
        witnesses: &[],
    };
    // With nothing placed the lamp is taken for a far source.
    assert!(sky(Vec::new()).radiance(d).is_some_and(|c| c[1] > 500.0));
    // Placed where it is, it is not.
    let placed = NearLight {
        position: lamp,
        radius: 0.1,
    };
    assert_eq!(sky(vec![placed]).radiance(d), None);
    // A window's aperture (a light triangulated at its centre, as large as the
    // window) is met by the frame's ray too: the sky through it is at infinity.
    let window = NearLight {
        position: lamp,
        radius: 1.5,
    };
    assert!(sky(vec![window]).radiance(d).is_some());
}

#[test]
fn a_lamp_hidden_from_the_frame_is_no_far_source_there_though_its_ray_meets_it() {
    // The lamp of the test above, and a frame on the probe's line of sight to
    // it: the frame's ray in that direction meets the lamp's ball, so the
    // placed lamp alone does not stop the probe's sample from counting as a
    // far source there. The fusion found the lamp hidden from this frame (a
    // facade in between, which the probe does not see): the sample is refused.
    let lamp = Vec3::new(2.0, 0.0, 2.5);
    let (w, h) = (256, 128);
    let probe = upright(Vec3::new(0.0, 0.0, 1.5));
    let dw = (lamp - probe.position).normalize();
    let img = HdrImage::from_fn(w, h, |x, y| {
        let d = probe.world_from_camera * pixel_to_dir(x, y, w, h);
        if d.angle_between(dw) < 0.04 {
            [1000.0; 3]
        } else {
            [0.5; 3]
        }
    });
    let frame = upright(probe.position + 0.5 * (lamp - probe.position));
    let d = frame.world_from_camera.transpose() * dw;
    let ball = NearLight {
        position: lamp,
        radius: 0.1,
    };
    let sky = SkyView {
        probes: vec![(&img, &probe)],
        frame,
        floor: 1.0,
        near: vec![ball],
        witnesses: &[],
    };
    assert!(sky.radiance(d).is_some_and(|c| c[1] > 500.0));
    assert_eq!(sky.radiance_past(d, &[ball]), None);
    // Another direction is untouched.
    let aside = frame.world_from_camera.transpose() * Vec3::new(-1.0, 0.2, 0.1).normalize();
    assert_eq!(sky.radiance_past(aside, &[ball]), sky.radiance(aside));
}

/// The neighbouring frames witness the far sources: a lamp one probe sees past
/// a corner, taken for a far source, is refused where every neighbour measured
/// its direction unclipped, and kept while one neighbour saw it clipped; a sun
/// every view sees stays.
#[test]
fn neighbours_that_measured_a_direction_unclipped_refuse_a_far_source_there() {
    let lamp = Vec3::new(4.0, 3.0, 2.5);
    let (w, h) = (256, 128);
    let probe = upright(Vec3::new(0.0, 0.0, 1.5));
    let sun = Vec3::new(-1.0, 0.3, 0.4).normalize();
    let lit = |pose: &Pose, x: usize, y: usize, lamp_seen: bool| -> [f32; 3] {
        let d = pose.world_from_camera * pixel_to_dir(x, y, w, h);
        if d.dot(sun) > 0.999 {
            [5e4; 3]
        } else if lamp_seen && {
            let v = lamp - pose.position;
            let t = v.dot(d);
            t > 0.0 && (v - t * d).length() <= 0.1
        } {
            [1000.0; 3]
        } else {
            [0.5; 3]
        }
    };
    let img = HdrImage::from_fn(w, h, |x, y| lit(&probe, x, y, true));
    let frame = upright(Vec3::new(0.2, -0.1, 1.5));
    // Two neighbours 15 cm either side: one sees the lamp's direction as a
    // dim wall, the other (with `clipped`) as clipped.
    let neighbour = |dx: f32, clipped: bool| {
        let pose = upright(Vec3::new(0.2 + dx, -0.1, 1.5));
        let dl = (lamp - probe.position).normalize();
        let img = HdrImage::from_fn(w, h, |x, y| {
            let d = pose.world_from_camera * pixel_to_dir(x, y, w, h);
            if clipped && d.dot(dl) > 0.995 {
                [1.0; 3]
            } else {
                lit(&pose, x, y, false).map(|c| c.min(1.0))
            }
        });
        (img, pose)
    };
    let sky = |witnesses: &[(HdrImage, Pose)]| -> (Option<[f32; 3]>, Option<[f32; 3]>) {
        let witnesses: Vec<Witness> = witnesses
            .iter()
            .map(|(radiance, pose)| Witness::new(radiance, 1.0, *pose))
            .collect();
        let view = SkyView {
            probes: vec![(&img, &probe)],
            frame,
            floor: 1.0,
            near: Vec::new(),
            witnesses: &witnesses,
        };
        let to_cam = frame.world_from_camera.transpose();
        (
            view.radiance(to_cam * (lamp - probe.position).normalize()),
            view.radiance(to_cam * sun),
        )
    };
    // No witnesses: the lamp is taken for a far source, as before.
    let (l, s) = sky(&[]);
    assert!(l.is_some_and(|c| c[1] > 500.0), "{l:?}");
    assert!(s.is_some_and(|c| c[1] > 1e4), "{s:?}");
    // Both neighbours measured the lamp's direction unclipped: refused; the sun
    // every neighbour saw clipped stays.
    let (l, s) = sky(&[neighbour(-0.15, false), neighbour(0.15, false)]);
    assert_eq!(l, None);
    assert!(s.is_some_and(|c| c[1] > 1e4), "{s:?}");
    // One neighbour saw it clipped: kept.
    let (l, _) = sky(&[neighbour(-0.15, false), neighbour(0.15, true)]);
    assert!(l.is_some_and(|c| c[1] > 500.0), "{l:?}");
}

/// A witness read from a frame's codes is the witness of its radiance.
#[test]
fn a_witness_from_codes_equals_the_witness_from_radiance() {
    let (w, h) = (64, 32);
    let codes = crate::image::SdrImage::from_vec(
        w,
        h,
        (0..w * h * 3)
            .map(|i| ((i * 37 + i / 5) % 256) as u8)
            .collect(),
    )
    .unwrap();
    // A gamma-like decode: code 250 at the white point 1.
    let radiance: [f32; 256] = std::array::from_fn(|c| (c as f32 / 250.0).powf(2.2));
    let lin = HdrImage::from_vec(
        w,
        h,
        codes.data().iter().map(|&c| radiance[c as usize]).collect(),
    )
    .unwrap();
    let pose = upright(Vec3::new(0.0, 0.0, 1.5));
    let (a, b) = (
        Witness::new(&lin, 1.0, pose),
        Witness::from_codes(&codes, &radiance, 1.0, pose),
    );
    let (mut seen, mut open) = (0, 0);
    for y in 0..h {
        for x in 0..w {
            let d = pose.world_from_camera * pixel_to_dir(x, y, w, h);
            assert_eq!(a.unclipped(d), b.unclipped(d), "({x}, {y})");
            seen += 1;
            open += usize::from(a.unclipped(d));
        }
    }
    assert!(open > 0 && open < seen, "{open} of {seen} unclipped");
}

mod witness_property {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        /// Whatever the direction and radiance of a probe's bright sample and
        /// wherever the neighbours stand: with no witness it is a far source;
        /// when every witness measured its direction unclipped it is refused;
        /// when one witness saw it clipped it is kept.
        #[test]
        fn a_far_source_stands_or_falls_with_its_witnesses(
            az in -3.1f32..3.1,
            el in -1.2f32..1.2,
            radiance in 10.0f32..1e5,
            dx in -0.3f32..0.3,
            dy in -0.3f32..0.3,
        ) {
            let (w, h) = (64, 32);
            let src = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
            let probe = upright(Vec3::new(0.0, 0.0, 1.5));
            let bright = |pose: &Pose, x: usize, y: usize| {
                (pose.world_from_camera * pixel_to_dir(x, y, w, h)).dot(src) > 0.995
            };
            let img = HdrImage::from_fn(w, h, |x, y| {
                if bright(&probe, x, y) { [radiance; 3] } else { [0.5; 3] }
            });
            let frame = upright(Vec3::new(dx, dy, 1.5));
            let neighbour = |ox: f32, clipped: bool| {
                let pose = upright(Vec3::new(dx + ox, dy, 1.5));
                let img = HdrImage::from_fn(w, h, |x, y| {
                    if clipped && bright(&pose, x, y) { [1.0; 3] } else { [0.5; 3] }
                });
                Witness::new(&img, 1.0, pose)
            };
            let look = |witnesses: &[Witness]| {
                let view = SkyView {
                    probes: vec![(&img, &probe)],
                    frame,
                    floor: 1.0,
                    near: Vec::new(),
                    witnesses,
                };
                view.radiance(frame.world_from_camera.transpose() * src)
            };
            let alone = look(&[]);
            prop_assert!(alone.is_some_and(|c| c[1] > 0.5 * radiance), "{alone:?}");
            let refused = look(&[neighbour(-0.15, false), neighbour(0.15, false)]);
            prop_assert_eq!(refused, None);
            let kept = look(&[neighbour(-0.15, false), neighbour(0.15, true)]);
            prop_assert!(kept.is_some_and(|c| c[1] > 0.5 * radiance), "{kept:?}");
        }
    }
}

#[test]
fn a_speck_whose_ray_passes_nearer_a_lamp_does_not_take_the_lamp_from_its_pair() {
    let lamp = Vec3::new(1.0, 2.0, 0.0);
    let (pa, pb) = (Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0));
    let light = |from: Vec3, to: Vec3, power: f64| Light {
        dir: (to - from).normalize(),
        power,
        solid_angle: 1e-3,
        ..Default::default()
    };
    // Probe a's ray passes 2 cm above the lamp (placement noise); a speck of
    // probe b, 1e5 times weaker, lies exactly on it.
    let above = lamp + Vec3::new(0.0, 0.0, 0.02);
    let la = light(pa, above, 1.0 / lamp.distance_squared(pa) as f64);
    let lb = light(pb, lamp, 1.0 / lamp.distance_squared(pb) as f64);
    let speck = light(pb, above, 1e-5);
    let (a, b) = ([la], [speck, lb]);
    let placed = triangulate(&a, pa, &b, pb, 0.2, 2.0);
    assert_eq!(placed.len(), 1, "{placed:?}");
    assert_eq!(placed[0].from, (0, 1));
    assert!(
        placed[0].position.distance(lamp) < 0.02,
        "{:?}",
        placed[0].position
    );
    // Without the intensity test the speck wins the nearest-rays race.
    let careless = triangulate(&a, pa, &b, pb, 0.2, f64::INFINITY);
    assert_eq!(careless.len(), 1);
    assert_eq!(careless[0].from, (0, 0));
}
