//! Camera calibrations: `panoman_capture::{qualisys::parse_qca, toml_calib::parse_toml,
//! panoptic::parse_panoptic, opencv_yaml::parse_opencv_yaml}`. The first byte picks the
//! reader (mod 4); the rest is the file's text (for OpenCV YAML, `intri.yml` and `extri.yml`
//! split at the first line `#EXTRI`, or the same text for both).
#![no_main]
use libfuzzer_sys::fuzz_target;
use panoman_capture::{opencv_yaml, panoptic, qualisys, toml_calib};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    let Ok(text) = std::str::from_utf8(rest) else {
        return;
    };
    match pick % 4 {
        0 => {
            let path = Path::new("fuzz.qca.txt");
            if let Err(e) = qualisys::parse_qca(text, path, &Default::default()) {
                panoman_fuzz::assert_names(&e, path);
            }
        }
        1 => {
            let path = Path::new("fuzz.toml");
            if let Err(e) = toml_calib::parse_toml(text, path, &Default::default()) {
                panoman_fuzz::assert_names(&e, path);
            }
        }
        2 => {
            let path = Path::new("calibration_fuzz.json");
            if let Err(e) = panoptic::parse_panoptic(text, path, None) {
                panoman_fuzz::assert_names(&e, path);
            }
        }
        _ => {
            let (intri, extri) = text.split_once("\n#EXTRI\n").unwrap_or((text, text));
            let (pi, pe) = (Path::new("fuzz_intri.yml"), Path::new("fuzz_extri.yml"));
            if let Err(e) = opencv_yaml::parse_opencv_yaml(intri, pi, extri, pe, None) {
                let msg = e.to_string();
                assert!(
                    msg.contains("fuzz_intri.yml") || msg.contains("fuzz_extri.yml"),
                    "error names neither file: {msg}"
                );
            }
        }
    }
});
