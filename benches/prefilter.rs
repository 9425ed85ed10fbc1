//! Prefiltering speed for one 512x256 probe: SH projection, irradiance cube,
//! the full GGX specular chain at 128-texel faces, the split-sum BRDF table and
//! the whole `Prefiltered::from_env` call (which reuses a cached table). Best of
//! a few runs, on one thread and on every core. Run with
//! `cargo bench --bench prefilter [-- PROBE.exr]`; without a probe a synthetic sky
//! with a 3x3-texel sun at 1e6 times the median is used (the case that would show
//! fireflies without PDF-based source-mip selection).

#[path = "common/mod.rs"]
mod common;
use common::best_ms;

use lumiprobe::ibl::{
    brdf_lut, irradiance_cube, prefilter_specular, PrefilterOptions, Prefiltered, Sh9,
};
use lumiprobe::image::HdrImage;
use lumiprobe::sphere::pixel_to_dir;

fn sun_sky(w: usize, h: usize) -> HdrImage {
    let mut env = HdrImage::from_fn(w, h, |x, y| {
        let d = pixel_to_dir(x, y, w, h);
        let s = 1.0 + 0.4 * d.y;
        [s * 0.9, s, s * 1.15]
    });
    let (sx, sy) = (w * 150 / 256, h * 40 / 128);
    for y in sy..sy + 3 {
        for x in sx..sx + 3 {
            env.set(x, y, [1e6; 3]);
        }
    }
    env
}

fn main() {
    let arg = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let (env, what) = match &arg {
        Some(p) => match lumiprobe::image::io::read_hdr(std::path::Path::new(p)) {
            Ok(img) => (lumiprobe::sphere::resize(&img, 512, 256), p.clone()),
            Err(e) => {
                eprintln!("{e}");
                std::process::exit(2);
            }
        },
        None => (
            sun_sky(512, 256),
            "synthetic sky with a 1e6 sun".to_string(),
        ),
    };
    let opts = PrefilterOptions::default();
    let s = &opts.specular;
    println!("probe: {what}, 512x256");
    println!(
        "settings: specular {} mips, mip 0 {}x{} faces, {} GGX samples per texel; \
         irradiance {}x{} faces from order-2 SH; BRDF table {}x{}, {} samples per texel",
        s.mip_count,
        s.face_size,
        s.face_size,
        s.samples,
        opts.irradiance_face_size,
        opts.irradiance_face_size,
        opts.lut_size,
        opts.lut_size,
        opts.lut_samples
    );
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    for threads in [1, cores] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool");
        pool.install(|| {
            let runs = 3;
            let sh_ms = best_ms(runs, || {
                std::hint::black_box(Sh9::project(&env));
            });
            let sh = Sh9::project(&env);
            let irr_ms = best_ms(runs, || {
                std::hint::black_box(irradiance_cube(&sh, opts.irradiance_face_size));
            });
            let spec_ms = best_ms(runs, || {
                std::hint::black_box(prefilter_specular(&env, &opts.specular));
            });
            let lut_ms = best_ms(1, || {
                std::hint::black_box(brdf_lut(opts.lut_size, opts.lut_samples));
            });
            let _ = Prefiltered::from_env(&env, &opts); // warm the table cache
            let all_ms = best_ms(runs, || {
                std::hint::black_box(Prefiltered::from_env(&env, &opts).expect("valid env"));
            });
            println!(
                "{threads} thread(s): SH {sh_ms:.2} ms, irradiance cube {irr_ms:.2} ms, \
                 specular chain {spec_ms:.1} ms, BRDF table {lut_ms:.1} ms (once per process), \
                 from_env (table cached) {all_ms:.1} ms"
            );
        });
    }
}
