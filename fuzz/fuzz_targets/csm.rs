//! Vicon CSM marker trajectories: `panoman_mocap::csm::parse_csm`.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz.csm");
    if let Err(e) = panoman_mocap::csm::parse_csm(text, path) {
        panoman_fuzz::assert_names(&e, path);
    }
});
