//! The 8-bit reader (PNG and JPEG through the `image` crate, after the crate's
//! own structure walk) on arbitrary bytes; the magic picks the decoder as it
//! does in `decode_sdr`, else the first byte does.
#![no_main]
use libfuzzer_sys::fuzz_target;
use lumiprobe::image::io::ldr;
use lumiprobe_fuzz::fixtures::ldr_format;
use lumiprobe_fuzz::{check_image, IMAGE_LIMITS};

fuzz_target!(|data: &[u8]| {
    let (format, name) = ldr_format(data);
    check_image(name, &IMAGE_LIMITS, data.len(), || {
        ldr::decode(data, name, format, &IMAGE_LIMITS)
    });
});
