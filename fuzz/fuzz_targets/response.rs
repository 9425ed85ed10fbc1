//! The camera-response readers: the text form (`srgb`, `gamma G`, the formula;
//! used by manifests and poses.json) and the JSON curve file written by
//! `lumiprobe merge --save-response` (`ResponseCurve::load`). The first byte
//! picks the reader.
#![no_main]
use libfuzzer_sys::fuzz_target;
use lumiprobe::capture::debevec::ResponseCurve;
use lumiprobe::tonemap::Response;
use lumiprobe_fuzz::{assert_names_file, scratch};

fuzz_target!(|data: &[u8]| {
    let Some((&k, rest)) = data.split_first() else {
        return;
    };
    if k & 1 == 0 {
        let Ok(text) = std::str::from_utf8(rest) else {
            return;
        };
        if let Some(r) = Response::parse(text) {
            // A parsed response is a usable one.
            if let Err(e) = r.validate() {
                panic!("Response::parse({text:?}) accepted an invalid curve: {e}");
            }
            let _ = r.decode_lut();
        }
    } else {
        let path = scratch().join("curve.json");
        std::fs::write(&path, rest).unwrap();
        match ResponseCurve::load(&path) {
            Ok(c) => {
                c.validate(&path).expect("a loaded curve validates");
                for ch in 0..3 {
                    assert!(c.linear(ch, 0) >= 0.0);
                }
            }
            Err(e) => assert_names_file(&e, &path),
        }
    }
});
