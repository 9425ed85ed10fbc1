//! OpenEXR reader on arbitrary bytes.
#![no_main]
use libfuzzer_sys::fuzz_target;
use lumiprobe::image::io::exr;
use lumiprobe_fuzz::{check_image, IMAGE_LIMITS};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz.exr");
    check_image(name, &IMAGE_LIMITS, data.len(), || {
        exr::decode(data, name, &IMAGE_LIMITS)
    });
});
