//! safetensors bytes: `panoman_model::mlp::store::TensorStore::from_bytes`, then every typed
//! read of every tensor and the MLP / PCA-head readers on each name prefix.
#![no_main]
use libfuzzer_sys::fuzz_target;
use panoman_model::mlp::{Mlp, PcaHead, TensorStore};

fuzz_target!(|data: &[u8]| {
    let Ok(store) = TensorStore::from_bytes(data, "fuzz.safetensors") else {
        return;
    };
    let names: Vec<String> = store.names().map(str::to_string).collect();
    for name in &names {
        let shape = store.get(name).map(|t| t.shape.clone()).unwrap_or_default();
        let _ = store.f32_tensor(name, &shape);
        let _ = store.f64_tensor(name, &shape);
        let _ = store.u32_tensor(name, &shape);
        if let Some((prefix, _)) = name.rsplit_once('.') {
            let prefix = prefix.strip_suffix(".layer0").unwrap_or(prefix);
            let _ = Mlp::read(&store, prefix);
            let _ = PcaHead::read(&store, prefix);
        }
    }
    let _ = store.to_bytes();
});
