//! The warp method on the evaluation data (`../shared/data`, or the folder named by
//! `LUMIPROBE_DATA`): a few frames of each scene, scored against ground truth.
//! When the data is not there the test fails.

#[path = "common/data.rs"]
mod data;
use lumiprobe::pipeline::evaluate::{evaluate, BASELINE_PROBE, BASELINE_SDR};
use lumiprobe::pipeline::{run, RunParams};
use lumiprobe::scene::Scene;

#[test]
fn warp_beats_the_nearest_probe_on_the_evaluation_scenes() {
    let data = data::shared_data();
    for name in ["kitchen", "flat", "outdoor"] {
        let mut scene = Scene::load(&data.join("scenes").join(name)).unwrap();
        // Every fourth frame keeps the test short.
        scene.frames = scene.frames.into_iter().step_by(4).collect();
        let tmp = tempfile::tempdir().unwrap();
        run(&scene, tmp.path(), &RunParams::default(), &|_, _| {}).unwrap();
        let ev = evaluate(&scene, &[("warp".into(), tmp.path())]).unwrap();
        let row = |l: &str| {
            ev.table
                .rows
                .iter()
                .find(|r| r.label == l)
                .unwrap()
                .mean
                .unwrap()
        };
        let (w, b, s) = (row("warp"), row(BASELINE_PROBE), row(BASELINE_SDR));
        assert!(
            w.psnr_tm > b.psnr_tm,
            "{name}: psnr {} vs {}",
            w.psnr_tm,
            b.psnr_tm
        );
        assert!(
            w.log_lum_rmse < b.log_lum_rmse,
            "{name}: log rmse {} vs {}",
            w.log_lum_rmse,
            b.log_lum_rmse
        );
        assert!(
            w.irradiance_rel_err < s.irradiance_rel_err,
            "{name}: irradiance {} vs sdr {}",
            w.irradiance_rel_err,
            s.irradiance_rel_err
        );
        assert_eq!(w.invalid_pixels, 0);
    }
}
