//! Inputs the coverage-guided fuzzer (fuzz/, issue 17) crashed this crate's readers with:
//! each must now be a `Format` error naming the file, not a panic.

use std::path::Path;

use panoman_mocap::{MocapError, c3d};

fn data(name: &str) -> Vec<u8> {
    std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/fuzz")
            .join(name),
    )
    .unwrap()
}

/// A parameter-section group record with id -128 (0x80): `-id` overflowed `i8`.
#[test]
fn c3d_group_id_min_is_an_error() {
    let path = Path::new("c3d_group_id_min.c3d");
    match c3d::parse_c3d(&data("c3d_group_id_min.c3d"), path) {
        Err(e @ MocapError::Format { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("c3d_group_id_min.c3d"), "{msg}");
            assert!(msg.contains("id -128"), "{msg}");
        }
        other => panic!("expected a format error, got {other:?}"),
    }
}
