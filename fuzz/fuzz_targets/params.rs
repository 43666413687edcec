//! Model parameter JSON: `panoman_model::model::Params::read`, validated against the small
//! example model (`$PANOMAN_FUZZ_MODEL`, default `<tmp>/panoman-examples/small.safetensors`,
//! which the test suite builds). Without a model file only the JSON parse is fuzzed.
#![no_main]
use libfuzzer_sys::fuzz_target;
use panoman_model::model::{PanoManModel, Params};
use std::sync::OnceLock;

fn model() -> Option<&'static PanoManModel> {
    static M: OnceLock<Option<PanoManModel>> = OnceLock::new();
    M.get_or_init(|| {
        let path = std::env::var_os("PANOMAN_FUZZ_MODEL")
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|| std::env::temp_dir().join("panoman-examples/small.safetensors"));
        match PanoManModel::load(&path) {
            Ok(m) => Some(m),
            Err(e) => {
                eprintln!("params target: no model ({e}); fuzzing the JSON parse only");
                None
            }
        }
    })
    .as_ref()
}

fuzz_target!(|data: &[u8]| {
    let path = panoman_fuzz::scratch_file("params.json", data);
    match model() {
        Some(m) => {
            if let Err(e) = Params::read(&path, m) {
                panoman_fuzz::assert_names(&e, &path);
            }
        }
        None => {
            let _ = serde_json::from_slice::<Params>(data);
        }
    }
});
