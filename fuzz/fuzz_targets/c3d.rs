//! C3D motion capture: `panoman_mocap::c3d::parse_c3d` (header, parameter section, points in
//! integer and float encodings).
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz.c3d");
    if let Err(e) = panoman_mocap::c3d::parse_c3d(data, path) {
        panoman_fuzz::assert_names(&e, path);
    }
});
