//! PLY meshes and point clouds: `panoman_mesh::io::ply::{parse_ply, parse_ply_points}`
//! (ASCII and both binary encodings).
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz.ply");
    if let Err(e) = panoman_mesh::io::ply::parse_ply(data, path) {
        panoman_fuzz::assert_names(&e, path);
    }
    if let Err(e) = panoman_mesh::io::ply::parse_ply_points(data, path) {
        panoman_fuzz::assert_names(&e, path);
    }
});
