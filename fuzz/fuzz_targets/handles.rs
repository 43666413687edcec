//! Vertex-handle JSON: `panoman::read_handles` against a 1229-vertex topology (the small one).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = panoman_fuzz::scratch_file("handles.json", data);
    if let Err(e) = panoman::read_handles(&path, 1229) {
        panoman_fuzz::assert_names(&e, &path);
    }
});
