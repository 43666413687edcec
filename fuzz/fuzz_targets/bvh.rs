//! BVH hierarchies and motion: `panoman_mocap::bvh::parse_bvh`.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz.bvh");
    if let Err(e) = panoman_mocap::bvh::parse_bvh(text, path) {
        panoman_fuzz::assert_names(&e, path);
    }
});
