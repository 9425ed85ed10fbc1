//! PFM reader on arbitrary bytes.
#![no_main]
use libfuzzer_sys::fuzz_target;
use lumiprobe::image::io::pfm;
use lumiprobe_fuzz::{check_image, IMAGE_LIMITS};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz.pfm");
    check_image(name, &IMAGE_LIMITS, data.len(), || {
        pfm::decode(data, name, &IMAGE_LIMITS)
    });
});
