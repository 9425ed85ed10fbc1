//! COLMAP `images.txt` (the poses the localization stage reads back) on
//! arbitrary text.
#![no_main]
use libfuzzer_sys::fuzz_target;
use lumiprobe::capture::localize::parse_images_txt;
use lumiprobe_fuzz::assert_names_file;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let file = Path::new("model/images.txt");
    match parse_images_txt(text, file) {
        Ok(images) => {
            for im in &images {
                assert!(im.r_cw.is_finite(), "rotation not finite: {:?}", im.r_cw);
            }
        }
        Err(e) => assert_names_file(&e, file),
    }
});
