//! The 8-bit reader (PNG and JPEG through the `image` crate, after the crate's
//! own structure walk) on arbitrary bytes; the magic picks the decoder as it
//! does in `decode_sdr`, else the first byte does.
#![no_main]
use libfuzzer_sys::fuzz_target;
use lumiprobe::image::io::{ldr, Format};
use lumiprobe_fuzz::{check_image, IMAGE_LIMITS};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let format = match Format::sniff(data) {
        Some(f @ (Format::Png | Format::Jpeg)) => f,
        _ if data.first().is_some_and(|b| b & 1 == 1) => Format::Jpeg,
        _ => Format::Png,
    };
    let name = Path::new(if format == Format::Png {
        "fuzz.png"
    } else {
        "fuzz.jpg"
    });
    check_image(name, &IMAGE_LIMITS, data.len(), || {
        ldr::decode(data, name, format, &IMAGE_LIMITS)
    });
});
