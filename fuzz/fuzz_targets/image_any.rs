//! The format-sniffing readers `decode_hdr` and `decode_sdr` (what `read_hdr`
//! and `read_sdr` call after reading the file). The first byte picks the file
//! name's extension (the fallback when the magic is not recognised); the rest
//! is the file.
//!
//! The limit is 2^24 pixels (192 MiB as float RGB), not the default 2^28: a
//! few dozen bytes of old-style RLE Radiance, or a JPEG whose scan is cut
//! short, legitimately decode to the largest image the limit allows, and the
//! default's 3 GiB does not fit the 2 GiB the fuzzer runs in. The memory bound
//! is checked as in the single-format targets.
#![no_main]
use libfuzzer_sys::fuzz_target;
use lumiprobe::image::io::{decode_hdr, decode_sdr, Limits};
use lumiprobe_fuzz::check_image;
use std::path::Path;

const NAMES: [&str; 8] = [
    "fuzz.exr", "fuzz.hdr", "fuzz.pfm", "fuzz.png", "fuzz.jpg", "fuzz.PIC", "fuzz", "fuzz.txt",
];

fuzz_target!(|data: &[u8]| {
    let Some((&k, bytes)) = data.split_first() else {
        return;
    };
    let name = Path::new(NAMES[k as usize % NAMES.len()]);
    let limits = Limits {
        max_pixels: 1 << 24,
    };
    check_image(name, &limits, bytes.len(), || {
        decode_hdr(bytes, name, &limits)
    });
    check_image(name, &limits, bytes.len(), || {
        decode_sdr(bytes, name, &limits)
    });
});
