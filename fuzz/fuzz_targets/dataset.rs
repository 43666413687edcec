//! Datasets: `panoman_human::dataset::Dataset::open` on a folder holding `dataset.json` (the
//! input up to the first `\n#SAFETENSORS#\n`) and `dataset.safetensors` (the rest).
#![no_main]
use libfuzzer_sys::fuzz_target;

const SEP: &[u8] = b"\n#SAFETENSORS#\n";

fuzz_target!(|data: &[u8]| {
    let (json, st) = match data.windows(SEP.len()).position(|w| w == SEP) {
        Some(i) => (&data[..i], &data[i + SEP.len()..]),
        None => (data, &[][..]),
    };
    let jpath = panoman_fuzz::scratch_file("dataset.json", json);
    panoman_fuzz::scratch_file("dataset.safetensors", st);
    let dir = jpath.parent().unwrap();
    let _ = panoman_human::dataset::Dataset::open(dir);
});
