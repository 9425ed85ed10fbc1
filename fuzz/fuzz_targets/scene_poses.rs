//! The scene description (`poses.json`) parser on arbitrary text, then the
//! nearest-probe query every method starts with.
#![no_main]
use libfuzzer_sys::fuzz_target;
use lumiprobe::scene::Scene;
use lumiprobe_fuzz::assert_names_file;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let root = Path::new("/nonexistent-fuzz-scene");
    let file = root.join("poses.json");
    match Scene::parse(text, root, &file) {
        Ok(s) => {
            assert!(!s.probes.is_empty());
            for f in &s.frames {
                assert!(f.pose.position.is_finite());
                let i = s.nearest_probe(f.pose.position);
                assert!(i < s.probes.len());
            }
            assert!(s.path_gain.is_finite() && s.path_gain > 0.0);
            s.response.validate().expect("a scene's response is usable");
        }
        Err(e) => assert_names_file(&e, &file),
    }
});
