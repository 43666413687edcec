//! Vicon VSK skeletons (XML): `panoman_mocap::vsk::parse_vsk`.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz.vsk");
    if let Err(e) = panoman_mocap::vsk::parse_vsk(text, path) {
        panoman_fuzz::assert_names(&e, path);
    }
});
