//! TC-127 keypoint JSON: `panoman_human::keypoints::KeypointsFile::parse`.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = panoman_human::keypoints::KeypointsFile::parse(text);
});
