//! Exposure-bracket merging (`lumiprobe::capture`): response recovery after
//! Debevec & Malik 1997 on a synthetic bracket of a known HDR image and a known
//! response, the merge's edge cases, the Exif reader on the dataset's JPEGs, and
//! (ignored, run by hand) the evaluation on the dataset against OpenCV and
//! Luminance HDR.

use lumiprobe::capture::debevec::{recover, RecoverOptions, ResponseCurve, CODES};
use lumiprobe::capture::merge::{merge, Exposure, MergeOptions, BLACK, SATURATED};
use lumiprobe::capture::{exif, run_merge, MergeArgs};
use lumiprobe::image::{luminance, HdrImage, SdrImage};
use lumiprobe::tonemap::Response;
use std::path::{Path, PathBuf};

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data");

/// Deterministic Gaussian noise (xorshift64* + Box–Muller).
struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let v = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d);
        ((v >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn gauss(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    }
}

/// A known HDR panorama with ~7 decades of range: textured walls, a gradient
/// sky, two lamps and a sun that clips in every bracket.
fn known_hdr(w: usize, h: usize) -> HdrImage {
    let sun = glam::Vec3::new(0.4, 0.5, -0.77).normalize();
    let lamp = glam::Vec3::new(-0.6, 0.7, 0.39).normalize();
    HdrImage::from_fn(w, h, |x, y| {
        let d = lumiprobe::sphere::pixel_to_dir(x, y, w, h);
        let tex = 1.0 + 0.8 * ((x as f32 * 0.31).sin() * (y as f32 * 0.23).cos());
        let mut c = if d.y > 0.0 {
            let s = 0.5 + 3.0 * d.y;
            [0.6 * s, 0.8 * s, 1.2 * s]
        } else {
            // Floor from very dark (0.002) to mid, in bands.
            let band = 10f32.powf(-2.7 + 2.7 * ((x / 16) % 8) as f32 / 7.0);
            [band * tex, 0.9 * band * tex, 0.7 * band * tex]
        };
        if d.dot(lamp) > 0.995 {
            c = [300.0, 260.0, 200.0];
        }
        if d.dot(sun) > 0.9995 {
            c = [4e5, 3.8e5, 3.5e5];
        }
        c
    })
}

/// `known_hdr` with the sky replaced by a horizontal log ramp over three decades
/// (0.3 to 300 times the sky colour). `known_hdr` alone shows a -3..+3 EV bracket
/// no code above ~125 (red), ~140 (green), ~165 (blue) except the lamps, which
/// have one radiance and so give two narrow clusters of codes whose spread is
/// only noise: a response cannot be recovered where the scene does not show it.
/// With the ramp every code of every channel is observed.
fn ramp_hdr(w: usize, h: usize) -> HdrImage {
    let base = known_hdr(w, h);
    HdrImage::from_fn(w, h, |x, y| {
        let i = y * w + x;
        let p = &base.data()[3 * i..3 * i + 3];
        let d = lumiprobe::sphere::pixel_to_dir(x, y, w, h);
        if d.y > 0.0 && p[0] < 100.0 {
            let s = 10f32.powf(-0.5 + 3.0 * (x as f32 + 0.5) / w as f32);
            [0.6 * s, 0.8 * s, 1.2 * s]
        } else {
            [p[0], p[1], p[2]]
        }
    })
}

/// Standard deviation of the noise `shoot` adds at exposure `x`.
fn noise_sigma(x: f64) -> f64 {
    0.002 + 0.01 * x.sqrt()
}

/// The first code whose exposure is at least twice the camera noise there: below
/// it a code says more about the noise than about the response (for the
/// documented response the noise floor 0.002 alone is the exposure of code 16),
/// and no recovery from data can tell `f⁻¹` from noise.
fn first_code_above_noise(resp: &Response) -> usize {
    (1..256)
        .find(|&z| {
            let x = resp.decode(z as f32 / 255.0) as f64;
            x >= 2.0 * noise_sigma(x)
        })
        .unwrap()
}

/// The camera: `x = gain t E`, Gaussian noise `0.002 + 0.01 sqrt(x)`, response,
/// 8-bit rounding (as in the dataset, without JPEG).
fn shoot(hdr: &HdrImage, resp: &Response, gain: f64, t: f64, rng: &mut Rng) -> SdrImage {
    let data = hdr
        .data()
        .iter()
        .map(|&e| {
            let x = gain * t * e as f64;
            let x = x + noise_sigma(x) * rng.gauss();
            let c = resp.encode(x.max(0.0) as f32) as f64;
            (c * 255.0).round().clamp(0.0, 255.0) as u8
        })
        .collect();
    SdrImage::from_vec(hdr.width(), hdr.height(), data).unwrap()
}

fn bracket(hdr: &HdrImage, resp: &Response, evs: &[i32], seed: u64) -> Vec<Exposure> {
    let mut rng = Rng(seed);
    evs.iter()
        .map(|&ev| {
            let t = 2f64.powi(ev) / 60.0;
            Exposure {
                name: PathBuf::from(format!("ev{ev:+}.png")),
                image: shoot(hdr, resp, 0.6, t, &mut rng),
                time_s: t,
            }
        })
        .collect()
}

fn documented() -> Response {
    Response::RationalGamma {
        scale: 1.08,
        knee: 0.08,
        gamma: 2.2,
    }
}

/// A response unlike the documented one: sRGB with a soft shoulder.
fn other_response() -> Response {
    let lin: Vec<f32> = (0..256)
        .map(|z| {
            let c = z as f32 / 255.0;
            let s = Response::Srgb.decode(c);
            s * (1.0 + 0.6 * s * s)
        })
        .collect();
    Response::Table { linear: lin }
}

/// RMS over codes 10..=245 and channels of ln(recovered) − ln(true), after the
/// best constant offset (the recovered curve's scale is arbitrary).
fn curve_rms(curve: &ResponseCurve, resp: &Response) -> f64 {
    curve_rms_from(curve, resp, 10)
}

/// [`curve_rms`] over codes `z0..=245`.
fn curve_rms_from(curve: &ResponseCurve, resp: &Response, z0: usize) -> f64 {
    let mut d = Vec::new();
    for c in 0..3 {
        for z in z0..=245 {
            let truth = (resp.decode(z as f32 / 255.0) as f64).ln();
            d.push(curve.g[c][z] - truth);
        }
    }
    let m = d.iter().sum::<f64>() / d.len() as f64;
    (d.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / d.len() as f64).sqrt()
}

/// Log10-luminance RMSE over pixels where `mask`, after the median scale.
fn log_rmse_masked(pred: &HdrImage, gt: &HdrImage, mask: impl Fn(usize) -> bool) -> f64 {
    let mut r: Vec<f64> = Vec::new();
    for (i, (p, g)) in pred.pixels().zip(gt.pixels()).enumerate() {
        if mask(i) {
            r.push((luminance(g) as f64).ln() - (luminance(p) as f64).ln());
        }
    }
    let mut s = r.clone();
    s.sort_by(f64::total_cmp);
    let med = s[s.len() / 2];
    (r.iter().map(|v| (v - med).powi(2)).sum::<f64>() / r.len() as f64).sqrt()
        / std::f64::consts::LN_10
}

#[test]
fn recovers_a_known_response_and_hdr() {
    let hdr = ramp_hdr(256, 128);
    for (name, resp) in [("documented", documented()), ("other", other_response())] {
        let exps = bracket(&hdr, &resp, &[-3, -2, -1, 0, 1, 2, 3], 7);
        let images: Vec<&SdrImage> = exps.iter().map(|e| &e.image).collect();
        let times: Vec<f64> = exps.iter().map(|e| e.time_s).collect();
        let rec = recover(&images, &times, &RecoverOptions::default()).unwrap();
        for c in 0..3 {
            assert!(
                rec.curve.g[c].windows(2).all(|p| p[1] >= p[0]),
                "{name}: not monotone"
            );
            assert!(rec.curve.g[c].iter().all(|v| v.is_finite()));
            assert!(rec.equations[c] > 2 * 256, "{name}: {:?}", rec.equations);
        }
        // Over the codes the camera's noise lets any method measure.
        let z0 = first_code_above_noise(&resp);
        let err = curve_rms_from(&rec.curve, &resp, z0);
        let off = rec.curve.g[1][128] - (resp.decode(128.0 / 255.0) as f64).ln();
        for z in [
            1usize, 3, 5, 10, 15, 20, 30, 50, 80, 128, 180, 220, 240, 250, 254,
        ] {
            let t = (resp.decode(z as f32 / 255.0) as f64).ln();
            println!(
                "  z {z:3}: {:+.3} {:+.3} {:+.3}",
                rec.curve.g[0][z] - t - off,
                rec.curve.g[1][z] - t - off,
                rec.curve.g[2][z] - t - off
            );
        }
        println!(
            "{name}: response RMS error {err:.4} ln over codes {z0}..=245 ({:.4} over 10..=245), \
             residual {:?}",
            curve_rms(&rec.curve, &resp),
            rec.rms_residual
        );
        assert!(err < 0.05, "{name}: response RMS error {err}");

        let merged = merge(&exps, &rec.curve, &MergeOptions::default()).unwrap();
        // Compare where the true radiance is measurable (not clipped at -3 EV, not
        // under the noise floor at +3 EV).
        let lo = 0.02 / (0.6 * 8.0 / 60.0);
        let hi = 0.9 / (0.6 * 0.125 / 60.0);
        let gt = &hdr;
        let in_range = |i: usize| {
            let p = &gt.data()[3 * i..3 * i + 3];
            p.iter().all(|&v| v as f64 > lo && (v as f64) < hi)
        };
        let e = log_rmse_masked(&merged.image, gt, in_range);
        // The same merge with the true response: the noise floor of the merge
        // itself, which the recovered curve should hardly add to.
        let exact = merge(
            &exps,
            &ResponseCurve::from_response(&resp),
            &MergeOptions::default(),
        )
        .unwrap();
        let e_true = log_rmse_masked(&exact.image, gt, in_range);
        println!("{name}: HDR log10 RMSE {e:.4} (true response: {e_true:.4})");
        assert!(
            e < e_true + 0.003 && e < 0.04,
            "{name}: HDR log10 RMSE {e} vs {e_true}"
        );
        // The sun is flagged and reported as a lower bound.
        assert!(merged.report.clipped_fraction > 0.0);
        assert!(merged.flags.iter().any(|f| f & SATURATED != 0));
    }
}

#[test]
fn lambda_extremes_give_finite_monotone_curves() {
    let hdr = known_hdr(128, 64);
    let exps = bracket(&hdr, &documented(), &[-2, 0, 2], 3);
    let images: Vec<&SdrImage> = exps.iter().map(|e| &e.image).collect();
    let times: Vec<f64> = exps.iter().map(|e| e.time_s).collect();
    for lambda in [0.0, 1e-3, 10.0, 1e6, 1e12] {
        let rec = recover(
            &images,
            &times,
            &RecoverOptions {
                lambda,
                samples: 300,
                seed: 5,
            },
        )
        .unwrap_or_else(|e| panic!("lambda {lambda}: {e}"));
        for c in 0..3 {
            let g = &rec.curve.g[c];
            assert!(g.iter().all(|v| v.is_finite()), "lambda {lambda}");
            assert!(g.windows(2).all(|p| p[1] >= p[0]), "lambda {lambda}");
            assert_eq!(g[128], 0.0);
        }
        println!(
            "lambda {lambda}: fixes {:?}, curve error {:.3}",
            rec.monotone_fixes,
            curve_rms(&rec.curve, &documented())
        );
    }
    let bad = RecoverOptions {
        lambda: -1.0,
        ..Default::default()
    };
    assert!(recover(&images, &times, &bad).is_err());
}

#[test]
fn curve_saves_loads_and_linearises() {
    let dir = tempfile::tempdir().unwrap();
    let hdr = known_hdr(128, 64);
    let exps = bracket(&hdr, &documented(), &[-2, 0, 2], 11);
    let images: Vec<&SdrImage> = exps.iter().map(|e| &e.image).collect();
    let times: Vec<f64> = exps.iter().map(|e| e.time_s).collect();
    let rec = recover(&images, &times, &RecoverOptions::default()).unwrap();
    let p = dir.path().join("curve.json");
    rec.curve.save(&p).unwrap();
    let back = ResponseCurve::load(&p).unwrap();
    for c in 0..3 {
        for z in 0..CODES {
            assert!((back.g[c][z] - rec.curve.g[c][z]).abs() < 1e-12);
        }
    }
    assert_eq!(back.samples, rec.curve.samples);
    // A linearised frame matches the merge of that frame alone.
    let lin = back.linearize(&exps[1].image, exps[1].time_s).unwrap();
    let one = merge(&exps[1..2], &back, &MergeOptions::default()).unwrap();
    for (a, b) in lin.data().iter().zip(one.image.data()) {
        assert!((a - b).abs() <= 1e-5 * a.abs().max(1e-6), "{a} vs {b}");
    }
    // The single-channel view is a valid Response table.
    assert!(back.to_table(1).validate().is_ok());
    // Broken files are errors naming the file.
    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, r#"{"g": [[0.0]], "lambda": 1, "samples": 2}"#).unwrap();
    let e = ResponseCurve::load(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.json"), "{e}");
}

#[test]
fn order_duplicates_and_single_exposures() {
    let hdr = known_hdr(128, 64);
    let curve = ResponseCurve::documented();
    let exps = bracket(&hdr, &documented(), &[-2, 0, 2], 21);
    let sorted = merge(&exps, &curve, &MergeOptions::default()).unwrap();
    let mut shuffled = vec![exps[2].clone(), exps[0].clone(), exps[1].clone()];
    let unsorted = merge(&shuffled, &curve, &MergeOptions::default()).unwrap();
    assert_eq!(sorted.image, unsorted.image);
    assert_eq!(sorted.report.frames, unsorted.report.frames);
    assert!(unsorted.report.frames[0].time_s < unsorted.report.frames[2].time_s);

    // A duplicated frame: accepted, warned about, and nearly the same result.
    shuffled.push(exps[1].clone());
    let dup = merge(&shuffled, &curve, &MergeOptions::default()).unwrap();
    assert!(dup
        .report
        .warnings
        .iter()
        .any(|w| w.contains("same exposure time")));
    let e = log_rmse_masked(&dup.image, &sorted.image, |_| true);
    assert!(e < 0.02, "{e}");
    let rec_dup = {
        let images: Vec<&SdrImage> = shuffled.iter().map(|e| &e.image).collect();
        let times: Vec<f64> = shuffled.iter().map(|e| e.time_s).collect();
        recover(&images, &times, &RecoverOptions::default())
    };
    assert!(rec_dup.is_ok());

    // One exposure: a linearisation (given curve), but no recovery.
    let single = merge(&exps[1..2], &curve, &MergeOptions::default()).unwrap();
    let lin = curve.linearize(&exps[1].image, exps[1].time_s).unwrap();
    assert_eq!(single.image.width(), 128);
    for (a, b) in single.image.data().iter().zip(lin.data()) {
        assert!((a - b).abs() <= 1e-5 * b.abs().max(1e-6));
    }
    let e = recover(
        &[&exps[1].image],
        &[exps[1].time_s],
        &RecoverOptions::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("two different exposure times"), "{e}");
    let same_time = recover(
        &[&exps[0].image, &exps[1].image],
        &[0.01, 0.01],
        &RecoverOptions::default(),
    );
    assert!(same_time.is_err());
}

#[test]
fn invalid_times_and_sizes_are_errors_naming_the_file() {
    let hdr = known_hdr(64, 32);
    let curve = ResponseCurve::documented();
    let exps = bracket(&hdr, &documented(), &[-1, 1], 2);
    for bad in [0.0, -0.01, f64::NAN, f64::INFINITY] {
        let mut v = exps.clone();
        v[1].time_s = bad;
        v[1].name = PathBuf::from("broken_time.jpg");
        let e = merge(&v, &curve, &MergeOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("broken_time.jpg"), "{bad}: {e}");
    }
    let mut v = exps.clone();
    v[0].image = SdrImage::new(32, 16);
    v[0].name = PathBuf::from("small.jpg");
    let e = merge(&v, &curve, &MergeOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("small.jpg") && e.contains("same size"), "{e}");
    assert!(merge(&[], &curve, &MergeOptions::default()).is_err());
}

#[test]
fn saturated_and_black_sets() {
    let curve = ResponseCurve::documented();
    let (w, h) = (64, 32);
    let mk = |v: u8, t: f64, n: &str| Exposure {
        name: PathBuf::from(n),
        image: SdrImage::from_vec(w, h, vec![v; w * h * 3]).unwrap(),
        time_s: t,
    };
    // Saturated everywhere: the darkest frame's value, flagged, with a warning.
    let sat = merge(
        &[mk(255, 0.01, "a.jpg"), mk(255, 0.001, "b.jpg")],
        &curve,
        &MergeOptions::default(),
    )
    .unwrap();
    let want = (curve.g[0][255].exp() / 0.001) as f32;
    assert!(sat
        .image
        .data()
        .iter()
        .all(|&v| (v - want).abs() <= 1e-5 * want));
    assert_eq!(sat.report.saturated_pixels, w * h);
    assert!((sat.report.clipped_fraction - 1.0).abs() < 1e-9);
    assert!((sat.report.clipped_light_share - 1.0).abs() < 1e-9);
    assert!(sat.flags.iter().all(|f| f & SATURATED != 0));
    assert!(sat
        .report
        .warnings
        .iter()
        .any(|m| m.contains("every pixel is saturated")));
    // Black everywhere: the brightest frame's value (an upper bound), flagged.
    let black = merge(
        &[mk(0, 0.01, "a.jpg"), mk(0, 0.001, "b.jpg")],
        &curve,
        &MergeOptions::default(),
    )
    .unwrap();
    let want = (curve.g[1][0].exp() / 0.01) as f32;
    assert!(black
        .image
        .data()
        .iter()
        .all(|&v| (v - want).abs() <= 1e-5 * want));
    assert_eq!(black.report.black_pixels, w * h);
    assert!(black.flags.iter().all(|f| f & BLACK != 0));
    // Recovery on a saturated set is an error, not garbage.
    let a = mk(255, 0.01, "a.jpg");
    let b = mk(255, 0.001, "b.jpg");
    assert!(recover(
        &[&a.image, &b.image],
        &[0.01, 0.001],
        &RecoverOptions::default()
    )
    .is_err());
}

#[test]
fn clipped_sun_is_reported_as_a_lower_bound() {
    let hdr = known_hdr(256, 128);
    let exps = bracket(&hdr, &documented(), &[-3, 0, 3], 9);
    let m = merge(
        &exps,
        &ResponseCurve::documented(),
        &MergeOptions::default(),
    )
    .unwrap();
    let r = &m.report;
    assert!(r.equirect);
    // The true share of light and sphere of the pixels the merge flagged.
    let (w, h) = (256, 128);
    let (mut area, mut clip_area, mut light, mut clip_light) = (0.0, 0.0, 0.0, 0.0);
    for y in 0..h {
        let da = lumiprobe::sphere::pixel_solid_angle(y, w, h) as f64;
        for x in 0..w {
            let l = luminance(hdr.get(x, y)) as f64 * da;
            area += da;
            light += l;
            if m.flags[y * w + x] & SATURATED != 0 {
                clip_area += da;
                clip_light += l;
            }
        }
    }
    println!("{}", r.summary());
    assert!((r.clipped_fraction - clip_area / area).abs() < 1e-9);
    let true_share = clip_light / light;
    assert!(r.clipped_light_share > 0.0);
    assert!(
        r.clipped_light_share <= true_share + 1e-6,
        "{r:?} vs {true_share}"
    );
    assert!(true_share > 0.5, "the sun should dominate: {true_share}");
    assert!(r
        .warnings
        .iter()
        .any(|w| w.contains("clip even at the darkest")));
    assert!(r.summary().contains("of the light"));
}

/// A bracket of `hdr` from `evs` (EV, 2^ev/60 s) with the documented response
/// and gain 0.6, with the camera noise of [`shoot`] or, when `noisy` is false,
/// only 8-bit rounding.
fn bracket_with(hdr: &HdrImage, evs: &[i32], noisy: bool, seed: u64) -> Vec<Exposure> {
    let resp = documented();
    let mut rng = Rng(seed);
    evs.iter()
        .map(|&ev| {
            let t = 2f64.powi(ev) / 60.0;
            let image = if noisy {
                shoot(hdr, &resp, 0.6, t, &mut rng)
            } else {
                let data = hdr
                    .data()
                    .iter()
                    .map(|&e| {
                        let c = resp.encode((0.6 * t * e as f64) as f32) as f64;
                        (c * 255.0).round().clamp(0.0, 255.0) as u8
                    })
                    .collect();
                SdrImage::from_vec(hdr.width(), hdr.height(), data).unwrap()
            };
            Exposure {
                name: PathBuf::from(format!("ev{ev:+}.png")),
                image,
                time_s: t,
            }
        })
        .collect()
}

/// A textured mid-grey patch: radiance 6.25 ± 30%, i.e. codes around 140 at
/// +2 EV and pure read noise at -8 EV and below.
fn grey_patch(w: usize, h: usize) -> HdrImage {
    HdrImage::from_fn(w, h, |x, y| {
        let v = 6.25 * (1.0 + 0.3 * ((x as f32 * 0.7).sin() * (y as f32 * 0.9).cos()));
        [v, v, v]
    })
}

const WIDE_EVS: [i32; 8] = [-12, -10, -8, -6, -4, -2, 0, 2];

#[test]
fn tiny_sun_with_jpeg_softened_codes_is_at_least_the_clamp() {
    let hdr = grey_patch(64, 32);
    let mut exps = bracket_with(&hdr, &[-6, -4, -2, 0], false, 1);
    let curve = ResponseCurve::documented();
    let (w, t_min) = (64, exps[0].time_s);
    let put = |e: &mut Exposure, x: usize, y: usize, rgb: [u8; 3]| {
        let mut data = e.image.data().to_vec();
        data[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&rgb);
        e.image = SdrImage::from_vec(w, 32, data).unwrap();
    };
    // A 1-px sun: clipped in the darkest frame, read 248..254 by JPEG in the
    // brighter ones.
    let sun = [
        [255, 255, 252],
        [254, 249, 251],
        [250, 253, 248],
        [252, 248, 254],
    ];
    // Its rim: measured in the darkest frame, softened codes afterwards.
    let rim = [
        [185, 180, 170],
        [254, 252, 251],
        [247, 241, 245],
        [255, 255, 255],
    ];
    for (j, e) in exps.iter_mut().enumerate() {
        put(e, 10, 10, sun[j]);
        put(e, 40, 20, rim[j]);
    }
    let flat = MergeOptions {
        equirect: Some(false),
    };
    let m = merge(&exps, &curve, &flat).unwrap();
    let px = |x: usize, y: usize| m.image.get(x, y);
    for c in 0..3 {
        let clamp = curve.g[c][255].exp() / t_min;
        let v = px(10, 10)[c] as f64;
        assert!(
            v >= clamp * (1.0 - 1e-6),
            "sun channel {c}: {v} < clamp {clamp}"
        );
        let want = curve.g[c][rim[0][c] as usize].exp() / t_min;
        let v = px(40, 20)[c] as f64;
        assert!(
            (v / want - 1.0).abs() < 1e-5,
            "rim channel {c}: {v} vs {want}"
        );
    }
    assert!(m.flags[10 * w + 10] & SATURATED != 0);
    assert!(m.flags[20 * w + 40] & SATURATED == 0);
    assert_eq!(m.flags.iter().filter(|&&f| f & SATURATED != 0).count(), 1);
    // The report's light share is the sun's share of the merged light.
    let l_sun = luminance(px(10, 10)) as f64;
    let total: f64 = m.image.pixels().map(|p| luminance(p) as f64).sum();
    let share = m.report.clipped_light_share;
    assert!(
        (share - l_sun / total).abs() < 1e-6,
        "{share} vs {}",
        l_sun / total
    );
    assert!(share > 0.2, "{share}");
    // Any weighted mean of the softened codes (what hat weights, zero only at
    // 255, would give) lies below their largest value: far below the clamp.
    let softened_max = exps
        .iter()
        .map(|e| e.image.data()[3 * (10 * w + 10) + 1])
        .zip(&exps)
        .filter(|(z, _)| *z < 255)
        .map(|(z, e)| (curve.g[1][z as usize] - e.time_s.ln()).exp())
        .fold(0.0f64, f64::max);
    assert!(softened_max < 0.5 * px(10, 10)[1] as f64);
}

#[test]
fn dark_noisy_codes_do_not_bias_a_mid_grey_patch() {
    let hdr = grey_patch(64, 32);
    let exps = bracket_with(&hdr, &WIDE_EVS, true, 17);
    // The -8..-12 EV frames see only read noise: codes spread over 0..~30.
    let dark = exps[0].image.data();
    assert!(dark.iter().filter(|&&z| z >= 10).count() > dark.len() / 4);
    let curve = ResponseCurve::documented();
    let m = merge(&exps, &curve, &MergeOptions::default()).unwrap();
    for c in 0..3 {
        let r: Vec<f64> = m
            .image
            .pixels()
            .zip(hdr.pixels())
            .map(|(p, g)| (p[c] as f64 / (0.6 * g[c] as f64)).ln())
            .collect();
        let med = median(r.clone());
        let rms = (r.iter().map(|v| v * v).sum::<f64>() / r.len() as f64).sqrt();
        println!(
            "channel {c}: median ln(merged/true) {med:+.4}, rms {rms:.4}, floor {:?}",
            m.report.noise_floor
        );
        assert!(med.abs() < 0.02 && rms < 0.05, "channel {c}: {med} {rms}");
    }
    // The floor is measured on the bracket: the camera's read noise (0.002, the
    // exposure of code 16) puts it a little above code 16; without noise there
    // is none to speak of.
    for f in m.report.noise_floor {
        assert!((14..=40).contains(&f), "{:?}", m.report.noise_floor);
    }
    assert!(m.report.summary().contains("noise floor"));
    let clean = bracket_with(&hdr, &WIDE_EVS, false, 17);
    let mc = merge(&clean, &curve, &MergeOptions::default()).unwrap();
    assert!(
        mc.report.noise_floor.iter().all(|&f| f <= 4),
        "{:?}",
        mc.report.noise_floor
    );
}

#[test]
fn wide_noisy_bracket_recovers_the_top_and_the_floor() {
    let hdr = ramp_hdr(256, 128);
    let exps = bracket_with(&hdr, &WIDE_EVS, true, 23);
    let images: Vec<&SdrImage> = exps.iter().map(|e| &e.image).collect();
    let times: Vec<f64> = exps.iter().map(|e| e.time_s).collect();
    let rec = recover(&images, &times, &RecoverOptions::default()).unwrap();
    println!("floor {:?}", rec.noise_floor);
    for f in rec.noise_floor {
        assert!((14..=40).contains(&f), "{:?}", rec.noise_floor);
    }
    let resp = documented();
    let z0 = rec.noise_floor.iter().copied().max().unwrap() as usize + 1;
    let err = curve_rms_from(&rec.curve, &resp, z0);
    // The top, where the clamp value of a clipped source comes from, after the
    // offset of the mid codes.
    for c in 0..3 {
        let off: f64 = (100..=160)
            .map(|z| rec.curve.g[c][z] - (resp.decode(z as f32 / 255.0) as f64).ln())
            .sum::<f64>()
            / 61.0;
        let top = rec.curve.g[c][255] - off;
        println!("channel {c}: g(255) error {top:+.3}, curve error {err:.4} over {z0}..=245");
        assert!(top.abs() < 0.1, "channel {c}: g(255) off by {top}");
    }
    assert!(err < 0.05, "{err}");
    let m = merge(&exps, &rec.curve, &MergeOptions::default()).unwrap();
    // Where some frame measures the pixel: log luminance close to the truth.
    let lo = 0.02 / (0.6 * 4.0 / 60.0);
    let hi = 0.9 / (0.6 * 2f64.powi(-12) / 60.0);
    let e = log_rmse_masked(&m.image, &hdr, |i| {
        let p = &hdr.data()[3 * i..3 * i + 3];
        p.iter().all(|&v| v as f64 > lo && (v as f64) < hi)
    });
    println!("HDR log10 RMSE {e:.4}");
    assert!(e < 0.02, "{e}");
}

/// A dataset bracket; its absence fails the test.
fn dataset_file(rel: &str) -> Option<PathBuf> {
    let p = Path::new(DATA).join(rel);
    assert!(
        p.exists(),
        "{} is missing: the shared evaluation data (../shared/data) must be beside the repository",
        p.display()
    );
    Some(p)
}

#[test]
fn exif_of_the_dataset_jpegs() {
    let Some(dir) = dataset_file("scenes/kitchen/probes/probe_00") else {
        return;
    };
    for ev in -3..=3 {
        let p = dir.join(format!("ev{ev:+}.jpg"));
        let e = exif::read_exposure(&p).unwrap();
        let want = 2f64.powi(ev) / 60.0;
        let t = e.exposure_time_s.unwrap();
        assert!(
            (t / want - 1.0).abs() < 1e-6,
            "{}: {t} vs {want}",
            p.display()
        );
        assert_eq!(e.f_number, Some(2.2));
        assert_eq!(e.iso, Some(100));
    }
    let e = exif::read_exposure(&dir.join("wide/ev-12.jpg")).unwrap();
    let want = 2f64.powi(-12) / 60.0;
    assert!((e.exposure_time_s.unwrap() / want - 1.0).abs() < 1e-6);
    // A missing file is an I/O error naming it.
    let e = exif::read_exposure(&dir.join("nope.jpg"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("nope.jpg"), "{e}");
}

#[test]
fn cli_merges_files_with_exif_or_given_times() {
    let tmp = tempfile::tempdir().unwrap();
    // Synthetic PNGs need --times.
    let hdr = known_hdr(128, 64);
    let exps = bracket(&hdr, &documented(), &[-2, 0, 2], 4);
    let mut paths = Vec::new();
    for e in &exps {
        let p = tmp.path().join(&e.name);
        lumiprobe::image::io::write_sdr(&p, &e.image).unwrap();
        paths.push(p);
    }
    let out = tmp.path().join("out.exr");
    let mut args = MergeArgs {
        brackets: paths.clone(),
        out: out.clone(),
        times: None,
        response: "recover".into(),
        save_response: Some(tmp.path().join("curve.json")),
        lambda: 10.0,
        samples: 500,
    };
    let e = run_merge(&args, true).unwrap_err().to_string();
    assert!(e.contains("ev-2.png") && e.contains("--times"), "{e}");
    args.times = Some(exps.iter().map(|e| e.time_s).collect());
    let r = run_merge(&args, true).unwrap();
    assert_eq!(r.frames.len(), 3);
    assert!(lumiprobe::image::io::read_hdr(&out).is_ok());
    // The saved curve can be reused.
    args.response = tmp.path().join("curve.json").display().to_string();
    args.save_response = None;
    run_merge(&args, true).unwrap();
    args.times = Some(vec![0.01, 0.0, 0.02]);
    let e = run_merge(&args, true).unwrap_err().to_string();
    assert!(e.contains("ev+0.png"), "{e}");
    args.times = Some(vec![0.01]);
    assert!(run_merge(&args, true).is_err());

    // Dataset JPEGs: times from Exif.
    let Some(dir) = dataset_file("scenes/kitchen/probes/probe_00") else {
        return;
    };
    let brackets: Vec<PathBuf> = (-3..=3)
        .map(|ev| dir.join(format!("ev{ev:+}.jpg")))
        .collect();
    let args = MergeArgs {
        brackets,
        out: tmp.path().join("kitchen.exr"),
        times: None,
        response: "recover".into(),
        save_response: None,
        lambda: 10.0,
        samples: 2000,
    };
    let r = run_merge(&args, true).unwrap();
    assert_eq!(r.frames.len(), 7);
    assert!((r.frames[0].time_s - 1.0 / 480.0).abs() < 1e-9);
}

// ---------------------------------------------------------------------------
// Evaluation on the dataset (ignored; run by hand, see `evaluate_dataset`).
// ---------------------------------------------------------------------------

/// Scores of one merge against the dataset's ground truth.
#[derive(Clone, Copy, Default)]
struct Score {
    ll_true: f64,
    irr_true: f64,
    ll_clamp: f64,
    irr_clamp: f64,
    /// Response error, RMS of ln x over codes 10..=245 after the image's scale.
    curve_same: f64,
    /// Response error after the curve's own best offset (shape only).
    curve_shape: f64,
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let m = v.len() / 2;
    *v.select_nth_unstable_by(m, f64::total_cmp).1
}

/// Scores `pred` (any scale) against `gt` and against `gt` clamped per channel at
/// `esat`. The scale is the median of ln(L_gt / L_pred) over `mask` pixels.
/// `curve` is the tool's linear exposure per code (relative); `x = k * curve`
/// with `k = gain * s / t0` is compared with the documented response. That
/// assumes the tool writes `curve(z) / t` in seconds; when `same_scale` is false
/// (luminance-hdr-cli rescales its output by a constant per bracket set) only the
/// curve's shape is scored and the same-scale error is NaN (printed n/a).
#[allow(clippy::too_many_arguments)]
fn score(
    pred: &HdrImage,
    gt: &HdrImage,
    mask: &[bool],
    esat: f64,
    curve: Option<&[[f64; 256]; 3]>,
    same_scale: bool,
    gain: f64,
    t0: f64,
) -> Score {
    let mut r = Vec::new();
    for (i, (p, g)) in pred.pixels().zip(gt.pixels()).enumerate() {
        let (lp, lg) = (luminance(p) as f64, luminance(g) as f64);
        if mask[i] && lp > 0.0 && lg > 0.0 && lp.is_finite() {
            r.push(lg.ln() - lp.ln());
        }
    }
    let s = median(r).exp();
    let s = if s.is_finite() { s } else { 1.0 };
    let mut scaled = pred.clone();
    for v in scaled.data_mut() {
        *v = (*v as f64 * s) as f32;
    }
    let mut clamped = gt.clone();
    for v in clamped.data_mut() {
        *v = v.min(esat as f32);
    }
    let mt = lumiprobe::eval::compare(&scaled, gt).unwrap();
    let mc = lumiprobe::eval::compare(&scaled, &clamped).unwrap();
    let (mut curve_same, mut curve_shape) = (f64::NAN, f64::NAN);
    if let Some(lin) = curve {
        let truth = documented();
        let mut d = Vec::new();
        for ch in lin {
            for z in 10..=245 {
                let t = (truth.decode(z as f32 / 255.0) as f64).ln();
                d.push((gain * s * ch[z] / t0).ln() - t);
            }
        }
        let n = d.len() as f64;
        let mean = d.iter().sum::<f64>() / n;
        if same_scale {
            curve_same = (d.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
        }
        curve_shape = (d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    }
    Score {
        ll_true: mt.log_lum_rmse,
        irr_true: mt.irradiance_rel_err,
        ll_clamp: mc.log_lum_rmse,
        irr_clamp: mc.irradiance_rel_err,
        curve_same,
        curve_shape,
    }
}

/// A tool's response file from `scripts/merge_compare.py`.
fn read_curve_json(p: &Path) -> Option<[[f64; 256]; 3]> {
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(p).ok()?).ok()?;
    let mut out = [[0.0; 256]; 3];
    for (c, ch) in v["linear"].as_array()?.iter().enumerate().take(3) {
        for (z, x) in ch.as_array()?.iter().enumerate().take(256) {
            out[c][z] = x.as_f64()?;
        }
    }
    Some(out)
}

fn env_or<T: std::str::FromStr>(k: &str, d: T) -> T {
    std::env::var(k)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(d)
}

/// Merges every probe of the three scenes with both bracket sets and scores
/// lumiprobe's merge (recovered response; the documented response as a
/// reference row) and, when present, OpenCV's and Luminance HDR's merges written
/// by `scripts/merge_compare.py`:
///
/// ```text
/// /usr/bin/python3 scripts/merge_compare.py --out /tmp/merge_eval
/// MERGE_EVAL_DIR=/tmp/merge_eval \
///   cargo test --release --test merge evaluate_dataset -- --ignored --nocapture
/// ```
///
/// `MERGE_EVAL_LAMBDA`, `MERGE_EVAL_SAMPLES` and `MERGE_EVAL_SCENES` override the
/// recovery settings and the scene list.
#[test]
#[ignore]
fn evaluate_dataset() {
    let ext = PathBuf::from(env_or("MERGE_EVAL_DIR", "/tmp/merge_eval".to_string()));
    let lambda = env_or(
        "MERGE_EVAL_LAMBDA",
        lumiprobe::capture::debevec::DEFAULT_LAMBDA,
    );
    let samples = env_or(
        "MERGE_EVAL_SAMPLES",
        lumiprobe::capture::debevec::DEFAULT_SAMPLES,
    );
    let scenes = env_or("MERGE_EVAL_SCENES", "kitchen,flat,outdoor".to_string());
    let tools = ["lumiprobe", "lumiprobe-documented", "opencv", "luminance"];
    // (scene, set, tool) -> scores of the probes.
    let mut table: Vec<(String, &str, &str, Vec<Score>)> = Vec::new();
    let mut times_ms = Vec::new();
    let mut report_lines = Vec::new();
    for scene in scenes.split(',') {
        let dir = Path::new(DATA).join("scenes").join(scene);
        let Ok(text) = std::fs::read_to_string(dir.join("poses.json")) else {
            println!("note: {} absent; skipping", dir.display());
            continue;
        };
        let poses: serde_json::Value = serde_json::from_str(&text).unwrap();
        let gain = poses["camera"]["bracket_gain_at_0ev"].as_f64().unwrap();
        let t0 = poses["camera"]["bracket_base_exposure_time_s"]
            .as_f64()
            .unwrap();
        for (key, set) in [("brackets", "std"), ("brackets_wide", "wide")] {
            let mut rows: Vec<Vec<Score>> = vec![Vec::new(); tools.len()];
            for probe in poses["probes"].as_array().unwrap() {
                let id = probe["id"].as_str().unwrap();
                let files: Vec<PathBuf> = probe[key]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|b| dir.join(b["file"].as_str().unwrap()))
                    .collect();
                let gt = lumiprobe::image::io::read_hdr(&dir.join(probe["hdr"].as_str().unwrap()))
                    .unwrap();
                let t_start = std::time::Instant::now();
                let exps = lumiprobe::capture::cli::load_exposures(&files, None).unwrap();
                let images: Vec<&SdrImage> = exps.iter().map(|e| &e.image).collect();
                let times: Vec<f64> = exps.iter().map(|e| e.time_s).collect();
                let opts = RecoverOptions {
                    lambda,
                    samples,
                    ..Default::default()
                };
                let rec = recover(&images, &times, &opts).unwrap();
                let merged = merge(&exps, &rec.curve, &MergeOptions::default()).unwrap();
                times_ms.push(t_start.elapsed().as_secs_f64() * 1e3);
                {
                    // The truth's share of light in the pixels the merge flagged.
                    let (gw, gh) = (gt.width(), gt.height());
                    let (mut light, mut flagged) = (0.0f64, 0.0f64);
                    for y in 0..gh {
                        let da = lumiprobe::sphere::pixel_solid_angle(y, gw, gh) as f64;
                        for x in 0..gw {
                            let l = luminance(gt.get(x, y)) as f64 * da;
                            light += l;
                            if merged.flags[y * gw + x] & SATURATED != 0 {
                                flagged += l;
                            }
                        }
                    }
                    report_lines.push(format!(
                        "{scene} {id} {set}: clipped at the darkest frame: {:.4}% of the sphere, >= {:.1}% of the light (truth in those pixels: {:.1}%); monotone fixes {:?}; noise floor (recovery / merge) {:?} / {:?}",
                        100.0 * merged.report.clipped_fraction,
                        100.0 * merged.report.clipped_light_share,
                        100.0 * flagged / light.max(f64::MIN_POSITIVE),
                        rec.monotone_fixes,
                        rec.noise_floor,
                        merged.report.noise_floor
                    ));
                }
                let tmin = times.iter().cloned().fold(f64::INFINITY, f64::min);
                let esat = t0 / (gain * tmin);
                let (w, h) = (gt.width(), gt.height());
                let mask: Vec<bool> = (0..w * h)
                    .map(|i| {
                        exps.iter().any(|e| {
                            e.image.data()[3 * i..3 * i + 3]
                                .iter()
                                .all(|&z| (20..=235).contains(&z))
                        })
                    })
                    .collect();
                let lin = |c: &ResponseCurve| {
                    let mut o = [[0.0; 256]; 3];
                    for (ch, g) in o.iter_mut().zip(&c.g) {
                        for (v, gz) in ch.iter_mut().zip(g) {
                            *v = gz.exp();
                        }
                    }
                    o
                };
                let l = lin(&rec.curve);
                let out = ext.join("lumiprobe").join(scene);
                if std::fs::create_dir_all(&out).is_ok() {
                    let _ = lumiprobe::image::io::write_hdr(
                        &out.join(format!("{id}_{set}.exr")),
                        &merged.image,
                    );
                    let _ = rec.curve.save(&out.join(format!("{id}_{set}_curve.json")));
                }
                rows[0].push(score(
                    &merged.image,
                    &gt,
                    &mask,
                    esat,
                    Some(&l),
                    true,
                    gain,
                    t0,
                ));
                let doc = ResponseCurve::documented();
                let md = merge(&exps, &doc, &MergeOptions::default()).unwrap();
                let l = lin(&doc);
                rows[1].push(score(&md.image, &gt, &mask, esat, Some(&l), true, gain, t0));
                for (k, tool) in [(2, "opencv"), (3, "luminance")] {
                    let base = ext.join(tool).join(scene).join(format!("{id}_{set}"));
                    let exr = base.with_extension("exr");
                    if let Ok(img) = lumiprobe::image::io::read_hdr(&exr) {
                        let mut img = img;
                        img.repair_invalid();
                        let crf =
                            read_curve_json(&PathBuf::from(format!("{}_crf.json", base.display())));
                        let same = tool != "luminance";
                        rows[k].push(score(&img, &gt, &mask, esat, crf.as_ref(), same, gain, t0));
                    }
                }
            }
            for (k, tool) in tools.iter().enumerate() {
                if !rows[k].is_empty() {
                    table.push((scene.to_string(), set, tool, rows[k].clone()));
                }
            }
        }
    }
    for l in &report_lines {
        println!("{l}");
    }
    println!(
        "\nlambda {lambda}, samples {samples}; lumiprobe load+recover+merge: mean {:.0} ms per probe",
        times_ms.iter().sum::<f64>() / times_ms.len().max(1) as f64
    );
    println!("\n| scene | set | tool | n | logL RMSE (true) | irr err (true) | logL RMSE (clamped) | irr err (clamped) | curve err (same scale) | curve err (shape) |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let mean = |s: &[Score], f: fn(&Score) -> f64| s.iter().map(f).sum::<f64>() / s.len() as f64;
    let fmt_curve = |v: f64| {
        if v.is_nan() {
            "n/a".to_string()
        } else {
            format!("{v:.3}")
        }
    };
    for (scene, set, tool, s) in &table {
        println!(
            "| {scene} | {set} | {tool} | {} | {:.4} | {:.2}% | {:.4} | {:.2}% | {} | {} |",
            s.len(),
            mean(s, |x| x.ll_true),
            100.0 * mean(s, |x| x.irr_true),
            mean(s, |x| x.ll_clamp),
            100.0 * mean(s, |x| x.irr_clamp),
            fmt_curve(mean(s, |x| x.curve_same)),
            fmt_curve(mean(s, |x| x.curve_shape)),
        );
    }
    // Issue 6's acceptance criteria on the wide set, against the clamped truth:
    // lumiprobe below OpenCV in irradiance error and log-luminance RMSE, and an
    // irradiance error of at most 5%.
    println!("\n| scene | irr err: lumiprobe vs opencv | logL RMSE: lumiprobe vs opencv | irr err <= 5% | met |");
    println!("|---|---|---|---|---|");
    let find = |scene: &str, tool: &str| {
        table
            .iter()
            .find(|(sc, set, t, _)| sc == scene && *set == "wide" && *t == tool)
            .map(|r| r.3.clone())
    };
    for scene in scenes.split(',') {
        let (Some(lp), Some(cv)) = (find(scene, "lumiprobe"), find(scene, "opencv")) else {
            continue;
        };
        let (il, ic) = (mean(&lp, |x| x.irr_clamp), mean(&cv, |x| x.irr_clamp));
        let (ll, lc) = (mean(&lp, |x| x.ll_clamp), mean(&cv, |x| x.ll_clamp));
        let met = il < ic && ll < lc && il <= 0.05;
        println!(
            "| {scene} | {:.2}% vs {:.2}% | {ll:.4} vs {lc:.4} | {} | {} |",
            100.0 * il,
            100.0 * ic,
            if il <= 0.05 { "yes" } else { "no" },
            if met { "yes" } else { "**no**" }
        );
    }
}
