//! Inputs the fuzz campaign (fuzz/, issue 17) flagged in this crate's readers: each must be
//! a `Format` error naming the file, never a panic or an allocation sized by a lying header.

use std::path::PathBuf;

use panoman_human::HumanError;
use panoman_human::dataset::Dataset;
use panoman_human::npy;

fn scratch(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("panoman-fuzzreg-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn npy_bytes(descr: &str, shape: &str, data: &[u8]) -> Vec<u8> {
    let mut h = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    while (10 + h.len() + 1) % 64 != 0 {
        h.push(' ');
    }
    h.push('\n');
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend((h.len() as u16).to_le_bytes());
    b.extend(h.as_bytes());
    b.extend(data);
    b
}

fn assert_format_error<T: std::fmt::Debug>(r: panoman_human::Result<T>, file: &str, what: &str) {
    match r {
        Err(e @ HumanError::Format { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains(file), "{msg}");
            assert!(msg.contains(what), "{msg}");
        }
        other => panic!("expected a format error, got {other:?}"),
    }
}

/// A shape whose element count overflows `usize` (was an arithmetic-overflow panic).
#[test]
fn npy_shape_product_overflow_is_an_error() {
    let dir = scratch("npy");
    let p = dir.join("overflow.npy");
    std::fs::write(
        &p,
        npy_bytes("<f8", "(4294967296, 4294967296, 4294967296)", b""),
    )
    .unwrap();
    assert_format_error(npy::read_npy_f64(&p), "overflow.npy", "too large");
    let p = dir.join("lying.npy");
    std::fs::write(&p, npy_bytes("<f8", "(100000000000, 3)", &[0; 24])).unwrap();
    assert_format_error(npy::read_npy_points(&p), "lying.npy", "needs");
    let _ = std::fs::remove_dir_all(&dir);
}

fn write_json(dir: &std::path::Path, meta: serde_json::Value) {
    std::fs::write(dir.join("dataset.json"), meta.to_string()).unwrap();
    std::fs::write(dir.join("dataset.safetensors"), b"").unwrap();
}

fn meta(n_rows: u64, n_id: u64, n_v: u64, train: &[u32]) -> serde_json::Value {
    serde_json::json!({
        "format": "panoman-dataset", "format_version": 1,
        "n_rows": n_rows, "n_identities": n_id,
        "topology": {"hash": "0123456789abcdef", "n_vertices": n_v},
        "theta": {"bones": ["spine05"]},
        "split": {"train": train, "held_out": []},
    })
}

/// `n_identities` far beyond what the split lists (was a ~1 PB allocation).
#[test]
fn dataset_lying_identity_count_is_an_error() {
    let dir = scratch("ds-ids");
    write_json(&dir, meta(1, 1_000_000_000_000_000, 3, &[0]));
    assert_format_error(
        Dataset::open(&dir),
        "dataset.json",
        "split lists 1 identities",
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// An identity listed 257 times (was a u8 counter overflow panic).
#[test]
fn dataset_repeated_split_identity_is_an_error() {
    let dir = scratch("ds-rep");
    let train = vec![0u32; 257];
    write_json(&dir, meta(1, 257, 3, &train));
    assert_format_error(Dataset::open(&dir), "dataset.json", "partition");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Zero rows and a huge vertex count (was an unbounded row-buffer allocation).
#[test]
fn dataset_without_rows_is_an_error() {
    let dir = scratch("ds-empty");
    write_json(&dir, meta(0, 1, 1 << 40, &[0]));
    assert_format_error(Dataset::open(&dir), "dataset.json", "n_rows");
    let _ = std::fs::remove_dir_all(&dir);
}
