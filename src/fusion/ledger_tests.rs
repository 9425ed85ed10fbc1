//! The ledger's invariants ([`super::ledger`]), with the answer known and as
//! properties over random frames, estimates and probe evidence.
use super::ledger::{Evidence, SeenLight, Source};
use super::tests::{frame_with_lamp, frame_with_lamps};
use super::*;
use crate::image::luminance;
use crate::sphere::{pixel_to_dir, row_solid_angles};
use proptest::prelude::*;

/// The fused frame's luminance power over the linearised frame's.
fn added_power(out: &HdrImage, lin: &HdrImage) -> f64 {
    let (w, h) = (out.width(), out.height());
    let sa = row_solid_angles(w, h);
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            (luminance(out.get(x, y)) - luminance(lin.get(x, y))) as f64 * sa[y] as f64
        })
        .sum()
}

/// A probe or frame at the origin, in world axes.
fn at_origin() -> crate::scene::Pose {
    crate::scene::Pose {
        position: glam::Vec3::ZERO,
        world_from_camera: glam::Mat3::IDENTITY,
    }
}

/// The ledger only reported, not enforced (`fusion.ledger=null`).
fn ledger_off() -> FusionParams {
    FusionParams {
        ledger: None,
        ..Default::default()
    }
}

fn ledger_on() -> FusionParams {
    FusionParams {
        ledger: Some(super::ledger::Budgeted::All),
        ..Default::default()
    }
}

/// A grey frame with a 3x3 block at (30, 12) clipped in red only (a red lamp's
/// rim), and an estimate that has the lamp red with almost nothing in green and
/// blue: the colour ratio a partially clipped pixel is extrapolated with is
/// millions.
fn red_rim(w: usize, h: usize) -> (SdrImage, HdrImage, HdrImage) {
    let block = |x: usize, y: usize| (29..=31).contains(&x) && (11..=13).contains(&y);
    let mut codes = vec![100u8; w * h * 3];
    let lin = HdrImage::from_fn(w, h, |x, y| {
        if block(x, y) {
            codes[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&[255, 150, 150]);
            [1.0, 0.4, 0.4]
        } else {
            [0.2, 0.2, 0.2]
        }
    });
    let est = HdrImage::from_fn(w, h, |x, y| {
        if block(x, y) {
            [6.0, 1e-6, 1e-6]
        } else {
            [0.2, 0.2, 0.2]
        }
    });
    (SdrImage::from_vec(w, h, codes).unwrap(), lin, est)
}

#[test]
fn a_partly_clipped_pixel_is_never_brighter_than_the_probes_measured() {
    let (w, h) = (64, 32);
    let (sdr, lin, est) = red_rim(w, h);
    let ev = Evidence {
        peak: [40.0, 2.0, 2.0],
        seen: vec![SeenLight {
            dir: pixel_to_dir(30, 12, w, h),
            power: 0.05,
            probe: 0,
            at: glam::Vec3::ZERO,
        }],
        walk: Vec::new(),
    };
    let frame = Measured::new(&sdr, &lin, 1.0);
    let max_red = |img: &HdrImage| img.pixels().map(|p| p[0]).fold(0.0f32, f32::max);
    // Without the ledger the extrapolated red is millions (the defect).
    let (off, rep) = fuse_with_lights(&frame, &est, &[], None, Some(&ev), &ledger_off()).unwrap();
    assert!(max_red(&off) > 1e5, "red {}", max_red(&off));
    assert!(rep.ledger.iter().any(|e| e.ceiling_px > 0));
    let (on, rep) = fuse_with_lights(&frame, &est, &[], None, Some(&ev), &ledger_on()).unwrap();
    assert!(max_red(&on) <= 40.0 + 1e-3, "red {}", max_red(&on));
    // Measured channels stay as measured.
    for y in 11..=13 {
        for x in 29..=31 {
            assert_eq!(on.get(x, y)[1], lin.get(x, y)[1]);
        }
    }
    let booked: f64 = rep.ledger.iter().map(|e| e.added).sum();
    assert!((booked - added_power(&on, &lin)).abs() < 1e-6);
}

/// A frame clipped in a 3x3 block at (11, 11) and an estimate holding 500
/// there (0.2 elsewhere).
fn lamp_at_11_with_500_estimated(w: usize, h: usize) -> (SdrImage, HdrImage, HdrImage) {
    let (sdr, lin) = super::tests::frame_with_lamp(w, h, (11, 11), 1);
    let est = HdrImage::from_fn(w, h, |x, y| {
        if (10..=12).contains(&x) && (10..=12).contains(&y) {
            [500.0; 3]
        } else {
            [0.2; 3]
        }
    });
    (sdr, lin, est)
}

#[test]
fn a_region_no_probe_saw_a_light_in_gets_nothing_added() {
    let (w, h) = (64, 32);
    let (sdr, lin, est) = lamp_at_11_with_500_estimated(w, h);
    // The estimate invents a lamp there; the probes saw their only light on the
    // other side of the sphere.
    let ev = Evidence {
        peak: [900.0; 3],
        seen: vec![SeenLight {
            dir: pixel_to_dir(43, 20, w, h),
            power: 2.0,
            probe: 0,
            at: glam::Vec3::ZERO,
        }],
        walk: Vec::new(),
    };
    let frame = Measured::new(&sdr, &lin, 1.0);
    let (off, _) = fuse_with_lights(&frame, &est, &[], None, Some(&ev), &ledger_off()).unwrap();
    assert!(added_power(&off, &lin) > 0.1);
    let (on, rep) = fuse_with_lights(&frame, &est, &[], None, Some(&ev), &ledger_on()).unwrap();
    assert_eq!(rep.ledger.len(), 1);
    assert_eq!(rep.ledger[0].source, Source::None);
    assert!(added_power(&on, &lin).abs() < 1e-9);
}

#[test]
fn a_light_no_probe_placed_is_budgeted_what_the_nearest_probe_saw() {
    let (w, h) = (64, 32);
    // The estimate holds far more than either probe saw there.
    let (sdr, lin, est) = lamp_at_11_with_500_estimated(w, h);
    let seen_at = |x: usize, power: f64, probe: usize, at: f32| SeenLight {
        dir: pixel_to_dir(x, 11, w, h),
        power,
        probe,
        at: glam::Vec3::new(at, 0.0, 0.0),
    };
    let seen = |power: f64, probe: usize, at: f32| seen_at(11, power, probe, at);
    // A probe 0.5 m away saw 0.02 there; one 4 m away, nearer the source, 0.3;
    // one 0.1 m away saw its light on the other side of the sphere only, and
    // is no view of this one. Listed in any order, the budget is the 0.5 m
    // probe's; the interval's upper end keeps the most any saw there.
    for seen in [
        vec![
            seen(0.02, 0, 0.5),
            seen(0.3, 1, 4.0),
            seen_at(43, 5.0, 2, 0.1),
        ],
        vec![
            seen_at(43, 5.0, 0, 0.1),
            seen(0.3, 1, 4.0),
            seen(0.02, 2, 0.5),
        ],
    ] {
        let ev = Evidence {
            peak: [900.0; 3],
            seen,
            walk: Vec::new(),
        };
        let frame = Measured::new(&sdr, &lin, 1.0);
        let (on, rep) = fuse_with_lights(&frame, &est, &[], None, Some(&ev), &ledger_on()).unwrap();
        assert_eq!(rep.ledger.len(), 1);
        let e = &rep.ledger[0];
        assert_eq!(e.source, Source::Probes);
        assert!((e.budget - 0.02).abs() < 1e-9, "{e:?}");
        assert!(e.most >= 0.3 - 1e-9, "{e:?}");
        assert!(added_power(&on, &lin) <= 0.02 + 1e-6);
    }
}

/// A random frame: grey with `lamps` square regions fully clipped or clipped in
/// some channels, an estimate with random (possibly wildly coloured) light
/// there, and random probe evidence.
/// A square region: corner (x, y), half-size, its codes, the estimate there.
type Lamp = (usize, usize, usize, [u8; 3], [f32; 3]);

#[derive(Debug, Clone)]
struct Case {
    lamps: Vec<Lamp>,
    peak: [f32; 3],
    seen: Vec<(usize, usize, f64)>,
}

const W: usize = 48;
const H: usize = 24;

fn case() -> impl Strategy<Value = Case> {
    case_with(prop_oneof![Just(255u8), Just(255u8), 100u8..200])
}

/// Like [`case`], with codes that clip short of the top code (250-254) or
/// measure (100-199): no pixel has a channel at 255, so every pixel that kept
/// a measured channel is one the measured bound applies to.
fn kept_case() -> impl Strategy<Value = Case> {
    case_with(prop_oneof![250u8..255, 100u8..200])
}

/// Random cases whose lamps' codes are drawn from `code`.
fn case_with(code: impl Strategy<Value = u8> + Clone) -> impl Strategy<Value = Case> {
    let lamp = (
        2..W - 4,
        2..H - 4,
        0usize..3,
        [code.clone(), code.clone(), code],
        [1e-6f32..1e4, 1e-6f32..1e4, 1e-6f32..1e4],
    );
    (
        proptest::collection::vec(lamp, 1..4),
        [0.5f32..1e5, 0.5f32..1e5, 0.5f32..1e5],
        proptest::collection::vec((0..W, 0..H, 1e-4f64..10.0), 0..4),
    )
        .prop_map(|(lamps, peak, seen)| Case { lamps, peak, seen })
}

fn build(c: &Case) -> (SdrImage, HdrImage, HdrImage, Evidence) {
    let mut codes = vec![100u8; W * H * 3];
    let mut lin = HdrImage::from_fn(W, H, |_, _| [0.2; 3]);
    let mut est = HdrImage::from_fn(W, H, |_, _| [0.2; 3]);
    for &(x0, y0, r, code, e) in &c.lamps {
        for y in y0..=y0 + r {
            for x in x0..=x0 + r {
                let i = y * W + x;
                codes[3 * i..3 * i + 3].copy_from_slice(&code);
                lin.set(x, y, code.map(|k| if k == 255 { 1.0 } else { 0.4 }));
                est.set(x, y, e);
            }
        }
    }
    let ev = Evidence {
        peak: c.peak,
        seen: c
            .seen
            .iter()
            .enumerate()
            .map(|(k, &(x, y, power))| SeenLight {
                dir: pixel_to_dir(x, y, W, H),
                power,
                probe: k % 2,
                at: glam::Vec3::ZERO,
            })
            .collect(),
        walk: Vec::new(),
    };
    (SdrImage::from_vec(W, H, codes).unwrap(), lin, est, ev)
}

/// Every channel of `out` finite, at most `bound` (or what the frame measured,
/// `lin`) within `tol`, and equal to the measurement outside the clipped
/// regions (`mask`); the ledger sums to what the frame gained.
fn held_everywhere(
    out: &HdrImage,
    lin: &HdrImage,
    mask: &[bool],
    bound: [f32; 3],
    tol: f32,
    rep: &FusionReport,
) -> std::result::Result<(), TestCaseError> {
    for y in 0..H {
        for x in 0..W {
            let (v, s) = (out.get(x, y), lin.get(x, y));
            for k in 0..3 {
                prop_assert!(v[k].is_finite());
                prop_assert!(
                    v[k] <= bound[k].max(s[k]) * (1.0 + tol),
                    "({x},{y}) {v:?} bound {bound:?}"
                );
                if !mask[y * W + x] {
                    prop_assert_eq!(v[k], s[k]);
                }
            }
        }
    }
    let booked: f64 = rep.ledger.iter().map(|e| e.added).sum();
    let gained = added_power(out, lin);
    prop_assert!(
        (booked - gained).abs() <= 1e-6 * (1.0 + gained.abs()),
        "{booked} vs {gained}"
    );
    Ok(())
}

/// The most a pixel of `c`'s frame may hold under the ceiling alone, per
/// channel: the probes' peak, raised to the largest region budget in the
/// smallest pixel any lamp covers (a pixel holds at most all the power its
/// region's sources have at the frame).
fn ceiling_bound(c: &Case, ev: &Evidence, rep: &FusionReport) -> [f32; 3] {
    let sa = row_solid_angles(W, H);
    let min_sa = c
        .lamps
        .iter()
        // The lamp's rows and the margin's row on either side.
        .flat_map(|l| l.1 - 1..=l.1 + l.2 + 1)
        .map(|y| sa[y] as f64)
        .fold(f64::INFINITY, f64::min);
    let most = rep.ledger.iter().map(|e| e.budget).fold(0.0f64, f64::max);
    let lum = luminance(ev.peak) as f64;
    let m = (most / min_sa / lum).max(1.0) as f32;
    ev.peak.map(|v| v * m)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// With no light placed in 3-D: no pixel brighter than the probes measured
    /// (their peak, or a region's budget in one pixel where the region cannot
    /// hold it at the peak; or than the frame measured it), nothing changed outside the clipped
    /// regions, every region's fully clipped light within its budget, nothing
    /// added where no source was named, and the ledger sums to what the frame
    /// gained.
    #[test]
    fn the_ledger_bounds_and_balances_every_fill(c in case()) {
        let (sdr, lin, est, ev) = build(&c);
        let frame = Measured::new(&sdr, &lin, 1.0);
        let (out, rep) = fuse_with_lights(&frame, &est, &[], None, Some(&ev), &ledger_on()).unwrap();
        let mask = clip_mask(&sdr, &frame.censor, ledger_on().margin_px);
        held_everywhere(&out, &lin, &mask, ceiling_bound(&c, &ev, &rep), 1e-4, &rep)?;
        for e in &rep.ledger {
            prop_assert!(e.added <= e.filled + 1e-9);
            if e.source == Source::None {
                // Only partially clipped pixels (bounded by their measured
                // channels and the ceiling) may gain where no source was named.
                let partial = c.lamps.iter().any(|l| l.3.iter().any(|&k| k != 255));
                prop_assert!(partial || e.added < 1e-9, "{e:?}");
            }
        }
        // A region whose clipped pixels all clipped in every channel holds no
        // more than its budget.
        if c.lamps.iter().all(|l| l.3 == [255; 3]) {
            for e in &rep.ledger {
                prop_assert!(e.added <= e.budget * (1.0 + 1e-5) + 1e-9, "{e:?}");
            }
        }
    }

    /// The ceiling alone (`ceiling`; every mode applies it): no channel of any pixel above what the
    /// probes' measurements allow a source there (their peak, or all of a
    /// region's budget in one pixel) or than the frame measured it; nothing
    /// changed outside the clipped regions. Without the ledger the estimate's
    /// light (up to 1e4 per channel) passes it.
    #[test]
    fn no_pixel_is_brighter_than_its_source_under_the_ceiling(c in case()) {
        let (sdr, lin, est, ev) = build(&c);
        let frame = Measured::new(&sdr, &lin, 1.0);
        let p = FusionParams { ledger: Some(super::ledger::Budgeted::Ceiling), ..Default::default() };
        let (out, rep) = fuse_with_lights(&frame, &est, &[], None, Some(&ev), &p).unwrap();
        let bound = ceiling_bound(&c, &ev, &rep);
        let mask = clip_mask(&sdr, &frame.censor, p.margin_px);
        held_everywhere(&out, &lin, &mask, bound, 1e-4, &rep)?;
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// A pixel that kept a measured channel (below the bleed code, none at
    /// 255) holds in each channel at most the clip radiance times the largest
    /// ratio of that channel to one of its measured channels in any colour
    /// the estimate holds (its lights or the grey around them): what a light
    /// could put there without the measured channel recording more than it
    /// did. Whatever path filled it (partly clipped, promoted, the ledger's
    /// spreading of a ceiling's excess).
    #[test]
    fn a_measured_channel_bounds_the_light_at_its_pixel(c in kept_case()) {
        let (sdr, lin, est, ev) = build(&c);
        let frame = Measured::new(&sdr, &lin, 1.0);
        let (out, _) = fuse_with_lights(&frame, &est, &[], None, Some(&ev), &ledger_on()).unwrap();
        let colours: Vec<[f32; 3]> = c.lamps.iter().map(|l| l.4).chain([[0.2; 3]]).collect();
        for y in 0..H {
            for x in 0..W {
                let i = y * W + x;
                let codes = &sdr.data()[3 * i..3 * i + 3];
                let measured: Vec<usize> = (0..3).filter(|&k| !frame.censor.bleeds(codes[k])).collect();
                if measured.is_empty() {
                    continue;
                }
                let (v, s) = (out.get(x, y), lin.get(x, y));
                for k in 0..3 {
                    let ratio = colours
                        .iter()
                        .flat_map(|e| measured.iter().map(move |&m| e[k] / e[m]))
                        .fold(1.0f32, f32::max);
                    prop_assert!(
                        v[k] <= (frame.white * ratio).max(s[k]) * (1.0 + 1e-3),
                        "({x},{y}) codes {codes:?} {v:?} ratio {ratio}"
                    );
                }
            }
        }
    }
}

/// The property above is not empty: without the ledger some random frame's
/// estimate passes the bound.
#[test]
fn without_the_ledger_a_random_frame_passes_the_ceiling() {
    use proptest::strategy::ValueTree;
    use proptest::test_runner::TestRunner;
    let mut runner = TestRunner::deterministic();
    let p = FusionParams {
        ledger: None,
        ..Default::default()
    };
    let passed = (0..64).any(|_| {
        let c = case().new_tree(&mut runner).unwrap().current();
        let (sdr, lin, est, ev) = build(&c);
        let frame = Measured::new(&sdr, &lin, 1.0);
        let (out, rep) = fuse_with_lights(&frame, &est, &[], None, Some(&ev), &p).unwrap();
        let bound = ceiling_bound(&c, &ev, &rep);
        let over = out
            .pixels()
            .zip(lin.pixels())
            .any(|(v, s)| (0..3).any(|k| v[k] > bound[k].max(s[k]) * 1.01));
        over
    });
    assert!(
        passed,
        "no random frame's estimate passed the ceiling without the ledger"
    );
}

/// A frame `w` x `h` whose only clipped pixel is a sun of `power` at
/// direction (`u`, `v`) (fractions of the panorama), an estimate with the sun one
/// pixel off at the radiance that power fills in one pixel, and probes that saw
/// it (peak at their own size `probe`).
fn sun_frame(
    w: usize,
    h: usize,
    power: f64,
    probe: (usize, usize),
) -> (SdrImage, HdrImage, HdrImage, Evidence) {
    let (sx, sy) = ((0.3 * w as f64) as usize, (0.25 * h as f64) as usize);
    let sa = row_solid_angles(w, h);
    let mut codes = vec![100u8; w * h * 3];
    codes[3 * (sy * w + sx)..3 * (sy * w + sx) + 3].copy_from_slice(&[255; 3]);
    let lin = HdrImage::from_fn(w, h, |x, y| {
        if (x, y) == (sx, sy) {
            [1.0; 3]
        } else {
            [0.2; 3]
        }
    });
    let radiance = (power / sa[sy] as f64) as f32 + 1.0;
    let est = HdrImage::from_fn(w, h, |x, y| {
        if (x, y) == (sx + 1, sy) {
            [radiance; 3]
        } else {
            [0.2; 3]
        }
    });
    let probe_sa = row_solid_angles(probe.0, probe.1)[(0.25 * probe.1 as f64) as usize] as f64;
    let seen = super::ledger::ProbeEvidence {
        cells: vec![(pixel_to_dir(sx, sy, w, h), power)],
        peak: [(power / probe_sa) as f32 + 1.0; 3],
        size: probe,
        position: glam::Vec3::ZERO,
    };
    let pose = at_origin();
    let ev = Evidence::at_frame(&[&seen], &pose, w, h);
    (SdrImage::from_vec(w, h, codes).unwrap(), lin, est, ev)
}

#[test]
fn a_sun_one_pixel_wide_keeps_its_power_at_three_resolutions() {
    // A sun at 1e5 times the frame's grey, one pixel wide at every size; the
    // probes were taken at 256x128, so a 512x256 frame sees it 4x brighter than
    // their brightest pixel.
    let power = 1e5 * 0.2 * 6.8e-5;
    let mut irradiance = Vec::new();
    for (w, h) in [(128, 64), (256, 128), (512, 256)] {
        let (sdr, lin, est, ev) = sun_frame(w, h, power, (256, 128));
        let frame = Measured::new(&sdr, &lin, 1.0);
        for p in [ledger_off(), FusionParams::default(), ledger_on()] {
            let (out, rep) = fuse_with_lights(&frame, &est, &[], None, Some(&ev), &p).unwrap();
            let added = added_power(&out, &lin);
            assert!(
                (added - power).abs() < 0.05 * power,
                "{w}x{h} ledger {:?}: {added} vs {power}",
                p.ledger
            );
            assert_eq!(rep.blobs.len(), 1);
            if p.ledger.is_some() {
                irradiance.push(rep.irradiance.estimate);
            }
        }
    }
    let (a, b) = (irradiance[0], irradiance[1]);
    assert!(
        (a - b).abs() < 0.02 * b,
        "irradiance {a} at 128x64, {b} at 256x128"
    );
}

#[test]
fn a_probes_light_is_gathered_in_cells_that_keep_its_power_and_direction() {
    let (w, h) = (128, 64);
    // A window 20 x 10 pixels at 50 units and a one-pixel lamp at 4000.
    let img = HdrImage::from_fn(w, h, |x, y| {
        if (30..50).contains(&x) && (20..30).contains(&y) {
            [50.0; 3]
        } else if (x, y) == (100, 15) {
            [4000.0; 3]
        } else {
            [0.3; 3]
        }
    });
    let pose = at_origin();
    let pe = super::ledger::ProbeEvidence::new(&img, &pose, 1.0);
    let sa = row_solid_angles(w, h);
    let window: f64 = (20..30).map(|y| 20.0 * 49.0 * sa[y] as f64).sum();
    let lamp = 3999.0 * sa[15] as f64;
    let total: f64 = pe.cells.iter().map(|c| c.1).sum();
    assert!(
        (total - window - lamp).abs() < 1e-6 * total,
        "{total} vs {}",
        window + lamp
    );
    // The window spans several cells; the lamp is one cell, where it is.
    assert!(pe.cells.len() > 4);
    let d = pixel_to_dir(100, 15, w, h);
    let at_lamp: f64 = pe
        .cells
        .iter()
        .filter(|c| c.0.dot(d) > 0.9999)
        .map(|c| c.1)
        .sum();
    assert!((at_lamp - lamp).abs() < 1e-6 * lamp);
    assert_eq!(pe.peak, [4000.0; 3]);
}

#[test]
fn a_source_one_probe_sees_where_the_frame_measured_a_wall_adds_nothing_there() {
    // One probe saw a sun through a near opening at (90, 14); the frame, from
    // elsewhere, sees a wall there (measured, grey) and a clipped lamp at
    // (20, 20). The estimate copied the probe's sun onto the wall.
    let (w, h) = (128, 64);
    let lamp = |x: usize, y: usize| (19..=21).contains(&x) && (19..=21).contains(&y);
    let (sdr, lin) = super::tests::frame_with_lamp(w, h, (20, 20), 1);
    let est = HdrImage::from_fn(w, h, |x, y| {
        if (x, y) == (90, 14) {
            [5e4; 3]
        } else if lamp(x, y) {
            [30.0; 3]
        } else {
            [0.2; 3]
        }
    });
    let sa = row_solid_angles(w, h);
    let ev = Evidence {
        peak: [5e4; 3],
        seen: vec![
            SeenLight {
                dir: pixel_to_dir(90, 14, w, h),
                power: 5e4 * sa[14] as f64,
                probe: 0,
                at: glam::Vec3::ZERO,
            },
            SeenLight {
                dir: pixel_to_dir(20, 20, w, h),
                power: 29.0 * 9.0 * sa[20] as f64,
                probe: 1,
                at: glam::Vec3::ZERO,
            },
        ],
        walk: Vec::new(),
    };
    let frame = Measured::new(&sdr, &lin, 1.0);
    for p in [ledger_off(), FusionParams::default(), ledger_on()] {
        let (out, rep) = fuse_with_lights(&frame, &est, &[], None, Some(&ev), &p).unwrap();
        // The wall stays as the frame measured it.
        assert_eq!(out.get(90, 14), lin.get(90, 14));
        // The lamp keeps its power, booked to what the probes saw there: the
        // sun, 90 degrees away, is not booked to it.
        assert_eq!(rep.ledger.len(), 1);
        let lamp_power = 29.0 * 9.0 * sa[20] as f64;
        assert!(
            rep.ledger[0].budget < 1.01 * lamp_power,
            "{:?}",
            rep.ledger[0]
        );
        let added = added_power(&out, &lin);
        assert!(
            (added - lamp_power).abs() < 0.05 * lamp_power,
            "{added} vs {lamp_power}"
        );
    }
}

/// Fuses a walk of frames (identity poses, so frame axes are world axes) and
/// returns each frame's output and report, the walk holds given.
fn fuse_walk(
    frames: &[(SdrImage, HdrImage, HdrImage)],
    ev: &Evidence,
    holds: &[Vec<super::walk::Mend>],
) -> Vec<(HdrImage, FusionReport)> {
    frames
        .iter()
        .zip(holds)
        .map(|((sdr, lin, est), h)| {
            let ev = Evidence {
                walk: h.clone(),
                ..ev.clone()
            };
            let frame = Measured::new(sdr, lin, 1.0);
            fuse_with_lights(&frame, est, &[], None, Some(&ev), &FusionParams::default()).unwrap()
        })
        .collect()
}

fn walk_regions(reports: &[(HdrImage, FusionReport)]) -> Vec<Vec<super::walk::WalkRegion>> {
    reports
        .iter()
        .map(|(_, r)| {
            r.ledger
                .iter()
                .map(|e| super::walk::WalkRegion {
                    region: e.region,
                    dir: glam::Vec3::from_array(e.dir),
                    solid_angle: r.blobs[e.region].solid_angle_sr,
                    added: e.walk.map_or(e.added, |w| w.before),
                    supported: 0.0,
                })
                .collect()
        })
        .collect()
}

#[test]
fn one_wrong_frame_in_a_walk_is_mended_by_its_neighbours_and_a_lamp_coming_into_view_is_not() {
    use super::walk::{mends, WalkMode, WalkParams};
    let (w, h) = (64, 32);
    // A lamp of radiance 30 drifting one pixel per frame (5.6 degrees); it comes
    // into view at frame 2. The estimate of frame 4 holds 40x the lamp's light.
    let n = 8;
    let walk: Vec<(SdrImage, HdrImage, HdrImage)> = (0..n)
        .map(|t| {
            let lamp = (16 + t, 12);
            if t < 2 {
                let (sdr, lin) = frame_with_lamps(w, h, &[], 1);
                return (sdr, lin.clone(), lin);
            }
            let (sdr, lin) = frame_with_lamp(w, h, lamp, 1);
            let v = if t == 4 { 1200.0 } else { 30.0 };
            let est = HdrImage::from_fn(w, h, |x, y| {
                if x.abs_diff(lamp.0) <= 1 && y.abs_diff(lamp.1) <= 1 {
                    [v; 3]
                } else {
                    [0.2; 3]
                }
            });
            (sdr, lin, est)
        })
        .collect();
    let truth = |t: usize| {
        let (sdr, lin, _) = &walk[t];
        let est = HdrImage::from_fn(w, h, |x, y| {
            if x.abs_diff(16 + t) <= 1 && y.abs_diff(12) <= 1 {
                [30.0; 3]
            } else {
                [0.2; 3]
            }
        });
        (sdr.clone(), lin.clone(), est)
    };
    let ev = Evidence {
        peak: [5e3; 3],
        seen: vec![SeenLight {
            dir: pixel_to_dir(20, 12, w, h),
            power: 10.0,
            probe: 0,
            at: glam::Vec3::ZERO,
        }],
        walk: Vec::new(),
    };
    let none = vec![Vec::new(); n];
    let first = fuse_walk(&walk, &ev, &none);
    let wrong = added_power(&first[4].0, &walk[4].1);
    let right = {
        let t = fuse_walk(&[truth(4)], &ev, &none[..1]);
        added_power(&t[0].0, &walk[4].1)
    };
    // The ledger (on by default) holds the wrong frame to the 10 units the
    // probes measured, still about four times the lamp's power at the frame.
    assert!(wrong > 3.0 * right, "the wrong frame: {wrong} vs {right}");
    assert!(wrong <= 10.0 * 1.0001, "the ledger's budget: {wrong}");
    for mode in [WalkMode::TwoSided, WalkMode::Causal] {
        let p = WalkParams {
            mode,
            ..WalkParams::default()
        };
        let regions = walk_regions(&first);
        // Frames 0.1 m apart.
        let positions: Vec<glam::Vec3> = (0..regions.len())
            .map(|t| glam::Vec3::new(0.1 * t as f32, 0.0, 0.0))
            .collect();
        let holds = mends(&regions, &positions, &p);
        // Only the wrong frame is held; the lamp entering at frame 2 is not.
        for (t, h) in holds.iter().enumerate() {
            assert_eq!(h.is_empty(), t != 4, "{mode:?} frame {t}: {h:?}");
        }
        let second = fuse_walk(&walk, &ev, &holds);
        let mended = added_power(&second[4].0, &walk[4].1);
        // The neighbours carry the lamp's power: within 5% of the frame fused
        // with a right estimate.
        assert!(
            (mended / right - 1.0).abs() < 0.05,
            "{mode:?}: mended {mended} right {right}"
        );
        assert!(second[4].1.ledger.iter().any(|e| e.walk.is_some()));
        // The entering lamp has its power at once (no lag): frame 2 as fused alone.
        let alone = fuse_walk(&[truth(2)], &ev, &none[..1]);
        let at2 = added_power(&second[2].0, &walk[2].1);
        assert!((at2 / added_power(&alone[0].0, &walk[2].1) - 1.0).abs() < 1e-6);
        // Every other frame is as fused alone.
        for t in (0..n).filter(|&t| t != 4) {
            assert!(second[t].0 == first[t].0, "{mode:?} frame {t} changed");
        }
    }
}

#[test]
fn a_probes_evidence_is_the_same_list_every_time_it_is_gathered() {
    // A uniformly bright band: many cells of exactly the same power, whose
    // order only the gathering decides. Two gatherings (two maps, as two
    // processes would build) must give the same list, or sums over it differ
    // in their last bits from run to run.
    let (w, h) = (180, 90);
    let img = HdrImage::from_fn(w, h, |_, y| {
        if (40..50).contains(&y) {
            [8.0; 3]
        } else {
            [0.2; 3]
        }
    });
    let pose = at_origin();
    let a = super::ledger::ProbeEvidence::new(&img, &pose, 1.0);
    let b = super::ledger::ProbeEvidence::new(&img, &pose, 1.0);
    assert!(a.cells.len() > 100);
    assert_eq!(a.cells, b.cells);
}
