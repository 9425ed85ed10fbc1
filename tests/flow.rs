//! The flow and hybrid methods end to end on a synthetic walk.

use lumiprobe::pipeline::evaluate::{evaluate, BASELINE_PROBE};
use lumiprobe::pipeline::{run, Method, RunParams};
use lumiprobe::scene::Scene;
use lumiprobe::synth::{synthesize, SynthParams};

#[test]
fn flow_and_hybrid_beat_the_nearest_probe() {
    let tmp = tempfile::tempdir().unwrap();
    let p = SynthParams {
        width: 256,
        n_frames: 3,
        n_probes: 3,
        seed: 4,
        name: "t".into(),
        ..Default::default()
    };
    let dir = tmp.path().join("scene");
    synthesize(&p).write(&dir).unwrap();
    let s = Scene::load(&dir).unwrap();
    let mut preds = Vec::new();
    for (label, method, ablate) in [
        ("flow", Method::Flow, false),
        ("hybrid", Method::Hybrid, false),
        ("flow-ablation", Method::Flow, true),
    ] {
        let mut params = RunParams {
            method,
            ..Default::default()
        };
        params.flow.no_smoothness = ablate;
        let out = tmp.path().join(label);
        let rep = run(&s, &out, &params, &|_, _| {}).unwrap();
        for f in &rep.frames {
            let fr = f.flow.as_ref().expect("flow report");
            assert_eq!(f.probes.len(), 2);
            let total: f32 = fr.label_fractions.iter().sum();
            assert!((total - 1.0).abs() < 1e-4);
            assert!(fr.mean_confidence.iter().all(|c| (0.0..=1.0).contains(c)));
            assert!(
                fr.energy_history.windows(2).all(|w| w[1] <= w[0] + 1e-6),
                "energy rose: {:?}",
                fr.energy_history
            );
        }
        preds.push((label.to_string(), out));
    }
    let refs: Vec<(String, &std::path::Path)> = preds
        .iter()
        .map(|(l, d)| (l.clone(), d.as_path()))
        .collect();
    let ev = evaluate(&s, &refs).unwrap();
    let row = |l: &str| {
        ev.table
            .rows
            .iter()
            .find(|r| r.label == l)
            .unwrap()
            .mean
            .unwrap()
    };
    let base = row(BASELINE_PROBE);
    for l in ["flow", "hybrid"] {
        let m = row(l);
        assert!(
            m.psnr_tm > base.psnr_tm,
            "{l}: psnr {} vs {}",
            m.psnr_tm,
            base.psnr_tm
        );
        assert!(
            m.log_lum_rmse < base.log_lum_rmse,
            "{l}: rmse {} vs {}",
            m.log_lum_rmse,
            base.log_lum_rmse
        );
        assert_eq!(m.invalid_pixels, 0);
    }
}

#[test]
fn fusion_keeps_the_frame_and_restores_the_clipped_light() {
    use lumiprobe::pipeline::evaluate::BASELINE_SDR;
    let tmp = tempfile::tempdir().unwrap();
    let p = SynthParams {
        width: 256,
        n_frames: 3,
        n_probes: 3,
        seed: 8,
        name: "t".into(),
        ..Default::default()
    };
    let dir = tmp.path().join("scene");
    synthesize(&p).write(&dir).unwrap();
    let s = Scene::load(&dir).unwrap();
    let out = tmp.path().join("fusion");
    let params = RunParams {
        method: Method::Fusion,
        ..Default::default()
    };
    let rep = run(&s, &out, &params, &|_, _| {}).unwrap();
    for f in &rep.frames {
        let fu = f.fusion.as_ref().expect("fusion report");
        // The base cut carries the calibrated SDR frame as a label: it takes the
        // unclipped pixels and never the clipped ones.
        let fl = f.flow.as_ref().expect("base flow report");
        let sdr_share = *fl.label_fractions.last().unwrap();
        assert!(sdr_share > 0.8 && sdr_share < 1.0, "sdr label {sdr_share}");
        assert!(
            fu.sdr_fraction > 0.8 && fu.sdr_fraction < 1.0,
            "{}",
            fu.sdr_fraction
        );
        assert!(!fu.blobs.is_empty());
    }
    let ev = evaluate(&s, &[("fusion".to_string(), out.as_path())]).unwrap();
    let row = |l: &str| {
        ev.table
            .rows
            .iter()
            .find(|r| r.label == l)
            .unwrap()
            .mean
            .unwrap()
    };
    let (fu, sdr, probe) = (row("fusion"), row(BASELINE_SDR), row(BASELINE_PROBE));
    assert!(
        fu.irradiance_rel_err < 0.5 * sdr.irradiance_rel_err,
        "irradiance {} vs sdr {}",
        fu.irradiance_rel_err,
        sdr.irradiance_rel_err
    );
    assert!(
        fu.psnr_tm > probe.psnr_tm,
        "psnr {} vs {}",
        fu.psnr_tm,
        probe.psnr_tm
    );
    assert!(
        fu.log_lum_rmse < probe.log_lum_rmse,
        "log rmse {} vs probe {}",
        fu.log_lum_rmse,
        probe.log_lum_rmse
    );
}
