//! `.npy` arrays: `panoman_human::npy::{read_npy_f64, read_npy_i64, read_npy_points}`.
#![no_main]
use libfuzzer_sys::fuzz_target;
use panoman_human::npy;

fuzz_target!(|data: &[u8]| {
    let path = panoman_fuzz::scratch_file("fuzz.npy", data);
    if let Err(e) = npy::read_npy_f64(&path) {
        panoman_fuzz::assert_names(&e, &path);
    }
    let _ = npy::read_npy_i64(&path);
    let _ = npy::read_npy_points(&path);
});
