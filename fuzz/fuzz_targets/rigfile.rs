//! The embedded LBS rig blob (`rig.postcard` in model files):
//! `panoman_human::rigfile::RigData::from_bytes`.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz-rig.safetensors");
    // Most inputs get the magic, so that the fuzzer spends its time in the decoder.
    let mut bytes = Vec::with_capacity(16 + data.len());
    if data.first().is_some_and(|b| b % 8 != 0) {
        bytes.extend_from_slice(panoman_human::rigfile::RIG_MAGIC);
        bytes.extend_from_slice(&data[1..]);
    } else {
        bytes.extend_from_slice(data);
    }
    if let Err(e) = panoman_human::rigfile::RigData::from_bytes(&bytes, path) {
        panoman_fuzz::assert_names(&e, path);
    }
});
