//! The Exif exposure reader (JPEG APP1 / TIFF IFDs) on arbitrary bytes.
#![no_main]
use libfuzzer_sys::fuzz_target;
use lumiprobe::capture::exif::parse;
use lumiprobe_fuzz::assert_names_file;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz.jpg");
    match parse(data, name) {
        Ok(e) => {
            // Rationals with a non-zero denominator are always finite; whether
            // a time is usable (positive) is checked by the merge, not here.
            for v in [e.exposure_time_s, e.f_number].into_iter().flatten() {
                assert!(v.is_finite(), "rational {v}");
            }
        }
        Err(e) => assert_names_file(&e, name),
    }
});
