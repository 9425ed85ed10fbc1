//! Radiance RGBE (.hdr) reader on arbitrary bytes.
#![no_main]
use libfuzzer_sys::fuzz_target;
use lumiprobe::image::io::rgbe;
use lumiprobe_fuzz::{check_image, IMAGE_LIMITS};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz.hdr");
    check_image(name, &IMAGE_LIMITS, data.len(), || {
        rgbe::decode(data, name, &IMAGE_LIMITS)
    });
});
