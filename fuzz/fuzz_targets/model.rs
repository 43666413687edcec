//! Model files: `TensorStore::from_bytes` + `PanoManModel::from_store`, i.e.
//! `PanoManModel::load` without the file read (shapes, dtypes, index ranges, finiteness,
//! topology hash, the embedded rig).
#![no_main]
use libfuzzer_sys::fuzz_target;
use panoman_model::mlp::TensorStore;
use panoman_model::model::PanoManModel;

fuzz_target!(|data: &[u8]| {
    let Ok(store) = TensorStore::from_bytes(data, "fuzz-model.safetensors") else {
        return;
    };
    let _ = PanoManModel::from_store(&store);
});
