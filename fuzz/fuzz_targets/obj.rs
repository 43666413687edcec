//! OBJ meshes: `panoman_mesh::io::obj::parse_obj` (the text of any UTF-8 input).
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz.obj");
    if let Err(e) = panoman_mesh::io::obj::parse_obj(text, path) {
        panoman_fuzz::assert_names(&e, path);
    }
});
