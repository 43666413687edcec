//! OpenPose / CMU Panoptic / TC-127 keypoint JSON:
//! `panoman_interchange::keypoints_in::parse_keypoints` (format detected from the keys; the
//! first input byte picks the unit and the person).
#![no_main]
use libfuzzer_sys::fuzz_target;
use panoman_interchange::keypoints_in::{ImportOptions, Unit, parse_keypoints};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Some((&pick, body)) = data.split_first() else {
        return;
    };
    let Ok(text) = std::str::from_utf8(body) else {
        return;
    };
    let options = ImportOptions {
        unit: [Unit::Centimetre, Unit::Metre, Unit::Millimetre][(pick % 3) as usize],
        person: ((pick >> 2) % 3) as usize,
        format: None,
    };
    let path = Path::new("fuzz-keypoints.json");
    if let Err(e) = parse_keypoints(text, path, &options) {
        panoman_fuzz::assert_names(&e, path);
    }
});
