//! C3D reader and writer: the committed real excerpt, every processor × storage variant
//! written by our writer, analog skipping, and malformed input.

use std::path::{Path, PathBuf};

use panoman_mocap::MocapError;
use panoman_mocap::c3d::{
    C3dWriteOptions, Processor, Storage, dec_to_ieee, ieee_to_dec, parse_c3d, read_c3d, write_c3d,
};
use panoman_mocap::markers::{MarkerSequence, UpAxis, UpSource};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn excerpt() -> MarkerSequence {
    read_c3d(&data("nick_freeform_001_head.c3d"))
        .unwrap()
        .markers
}

/// Asserts `r` is a format error whose message names `name`.
fn assert_format_err<T: std::fmt::Debug>(r: Result<T, MocapError>, name: &str, needle: &str) {
    match r {
        Err(e @ MocapError::Format { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains(name), "`{msg}` does not name {name}");
            assert!(msg.contains(needle), "`{msg}` does not say `{needle}`");
        }
        other => panic!("expected a format error, got {other:?}"),
    }
}

#[test]
fn real_excerpt_facts() {
    let c = read_c3d(&data("nick_freeform_001_head.c3d")).unwrap();
    assert_eq!(c.processor, Processor::Intel);
    assert_eq!(c.storage, Storage::Float);
    assert_eq!(c.analog_words_per_frame, 0);
    assert_eq!(c.data_start, 9 * 512);
    assert_eq!(c.frame_bytes, 53 * 16);
    let m = &c.markers;
    assert_eq!((m.n_markers(), m.n_frames()), (53, 40));
    assert_eq!(m.rate_hz, 120.0);
    assert_eq!(m.first_frame, 1);
    assert_eq!(m.source_unit, "mm");
    assert_eq!(m.metres_per_unit, 0.001);
    // The file has no POINT:Y_SCREEN: the up axis is not stated.
    assert_eq!((m.up_axis, m.up_source), (None, UpSource::Unknown));
    assert_eq!(m.names[0], "Nick01:ARIEL");
    assert_eq!(m.names[52], "Nick01:RTOE");
    // Frame 0, ARIEL: little-endian floats at byte 4608 (checked with Python's struct).
    let p = m.get(0, 0).unwrap();
    let want = [-513.6526489257812, 1655.7030029296875, -559.1818237304688];
    for k in 0..3 {
        assert!((p[k] - want[k] * 0.001).abs() < 1e-15);
    }
    let q = m.get(39, 52).unwrap();
    assert!((q[1] - 13.866811752319336e-3).abs() < 1e-15);
    // Residual −1 samples: 73 in these 40 frames; CLAV (index 7) in all of them.
    assert_eq!(m.n_missing(), 73);
    assert!((0..40).all(|f| m.get(f, 7).is_none()));
    assert!(m.get(0, 18).is_none() && m.get(0, 40).is_none() && m.get(0, 6).is_some());
    assert_eq!(c.param("point", "frames").unwrap().first_f64(), Some(40.0));
    assert_eq!(
        c.param("SUBJECTS", "LABEL_PREFIXES").unwrap().strings(),
        ["Nick01:"]
    );
}

#[test]
fn strip_prefix_and_project_frame() {
    let mut m = excerpt();
    m.strip_subject_prefix().unwrap();
    assert_eq!(m.names[1], "LFHD");
    assert!(m.to_project_frame(None).is_err(), "up axis unknown");
    let z = m.to_project_frame(Some(UpAxis::Y)).unwrap();
    let (a, b) = (m.get(0, 0).unwrap(), z.get(0, 0).unwrap());
    // Rx(+90°): (x, y, z) ↦ (x, −z, y); the head marker is 1.66 m up either way.
    assert_eq!(b, [a[0], -a[2], a[1]]);
    assert!(b[2] > 1.5);
    assert_eq!(z.n_missing(), m.n_missing());
    let mut z = z;
    z.face_minus_y("LFHD", "RFHD", 0).unwrap();
    let (l, r) = (z.get(0, 1).unwrap(), z.get(0, 3).unwrap());
    assert!(l[0] - r[0] > 0.05 && (l[1] - r[1]).abs() < 1e-12);
}

/// A synthetic sequence with a missing sample; |values| ≤ 1.5 m fit int16 at 1/16 mm.
fn synthetic(up: Option<UpAxis>) -> MarkerSequence {
    let (nm, nf) = (3, 5);
    let mut positions = Vec::new();
    for f in 0..nf {
        for m in 0..nm {
            if (f, m) == (2, 1) {
                positions.push([f64::NAN; 3]);
            } else {
                let b = 0.1 * m as f64 + 0.01 * f as f64;
                positions.push([b - 1.2, 0.5 - b, 1.3 + b]);
            }
        }
    }
    MarkerSequence {
        names: vec!["A".into(), "LongerName".into(), "C".into()],
        rate_hz: 100.0,
        first_frame: 7,
        positions,
        source_unit: "mm".into(),
        metres_per_unit: 0.001,
        up_axis: up,
        up_source: if up.is_some() {
            UpSource::File
        } else {
            UpSource::Unknown
        },
    }
}

#[test]
fn writer_round_trip_all_byte_orders_and_storages() {
    let s = synthetic(Some(UpAxis::Z));
    for processor in [Processor::Intel, Processor::Dec, Processor::Mips] {
        for storage in [Storage::Float, Storage::Integer { scale: 0.0625 }] {
            for analog_channels in [0, 3] {
                let opts = C3dWriteOptions {
                    processor,
                    storage,
                    unit: "mm".into(),
                    analog_channels,
                };
                let bytes = write_c3d(&s, &opts).unwrap();
                let c = parse_c3d(&bytes, Path::new("mem.c3d")).unwrap();
                assert_eq!(c.processor, processor);
                assert_eq!(c.storage, storage);
                assert_eq!(c.analog_words_per_frame, analog_channels as usize);
                let m = &c.markers;
                assert_eq!(m.names, s.names);
                assert_eq!((m.n_frames(), m.first_frame, m.rate_hz), (5, 7, 100.0));
                assert_eq!((m.up_axis, m.up_source), (Some(UpAxis::Z), UpSource::File));
                assert_eq!(m.n_missing(), 1);
                assert!(m.get(2, 1).is_none());
                // f32 storage: relative 2⁻²⁴ of ≤ 1.5 m; int16: half a count (1/32 mm).
                let tol = match storage {
                    Storage::Float => 1.5 * 6e-8,
                    Storage::Integer { .. } => 0.03125e-3 + 1e-12,
                };
                for f in 0..5 {
                    for k in 0..3 {
                        if let (Some(a), Some(b)) = (s.get(f, k), m.get(f, k)) {
                            for d in 0..3 {
                                assert!((a[d] - b[d]).abs() <= tol, "{processor:?} {storage:?}");
                            }
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn byte_orders_differ_on_disk() {
    let s = synthetic(None);
    let w = |processor| {
        let o = C3dWriteOptions {
            processor,
            ..Default::default()
        };
        write_c3d(&s, &o).unwrap()
    };
    let (i, d, m) = (w(Processor::Intel), w(Processor::Dec), w(Processor::Mips));
    assert_eq!(&i[2..4], &[3, 0]);
    assert_eq!(&m[2..4], &[0, 3]);
    assert_ne!(i[512..], d[512..]);
    // Same layout, so the same length.
    assert_eq!(i.len(), d.len());
}

#[test]
fn dec_float_conversion() {
    // VAX F 1.0 = 0.5 · 2¹: exponent 129, stored as the word 0x4080 first.
    assert_eq!(dec_to_ieee([0x80, 0x40, 0, 0]), 1.0);
    assert_eq!(dec_to_ieee([0x80, 0xC0, 0, 0]), -1.0);
    assert_eq!(dec_to_ieee([0, 0, 0, 0]), 0.0);
    for v in [120.0f32, -0.001, 1655.703, 3.0e30, -7.25e-20] {
        assert_eq!(dec_to_ieee(ieee_to_dec(v).unwrap()), v);
    }
    assert!(ieee_to_dec(f32::NAN).is_err());
    assert!(ieee_to_dec(f32::MAX).is_err());
}

#[test]
fn truncated_at_many_offsets() {
    let bytes = std::fs::read(data("nick_freeform_001_head.c3d")).unwrap();
    let mut n_checked = 0;
    let mut cut = 0;
    while cut < bytes.len() {
        let r = parse_c3d(&bytes[..cut], Path::new("cut.c3d"));
        assert_format_err(r, "cut.c3d", "");
        n_checked += 1;
        cut += if cut < 5000 { 37 } else { 997 };
    }
    assert!(n_checked > 100);
    assert_format_err(
        parse_c3d(&bytes[..bytes.len() - 1], Path::new("cut.c3d")),
        "cut.c3d",
        "truncated point data",
    );
    // And every written variant, cut anywhere, errors without panicking.
    let w = write_c3d(&synthetic(None), &C3dWriteOptions::default()).unwrap();
    for cut in 0..w.len() {
        assert!(parse_c3d(&w[..cut], Path::new("w.c3d")).is_err());
    }
}

#[test]
fn lying_header_is_an_error_not_an_allocation() {
    let mut b = std::fs::read(data("nick_freeform_001_head.c3d")).unwrap();
    b[8..10].copy_from_slice(&65534u16.to_le_bytes()); // last frame
    assert_format_err(
        parse_c3d(&b, Path::new("lie.c3d")),
        "lie.c3d",
        "65534 frames",
    );
}

#[test]
fn zero_frames_zero_markers_and_bad_headers() {
    let b = std::fs::read(data("nick_freeform_001_head.c3d")).unwrap();
    let mut z = b.clone();
    z[6..8].copy_from_slice(&5u16.to_le_bytes()); // first frame 5
    z[8..10].copy_from_slice(&4u16.to_le_bytes()); // last 4 < first 5
    assert_format_err(parse_c3d(&z, Path::new("z.c3d")), "z.c3d", "zero frames");

    let mut s = synthetic(None);
    s.names.clear();
    s.positions.clear();
    assert!(write_c3d(&s, &C3dWriteOptions::default()).is_err());
    // Zero points in a written file: patch header and POINT:USED.
    let w = write_c3d(&synthetic(None), &C3dWriteOptions::default()).unwrap();
    let c = parse_c3d(&w, Path::new("w.c3d")).unwrap();
    let mut w0 = w.clone();
    w0[2..4].copy_from_slice(&0u16.to_le_bytes());
    let used = c.param("POINT", "USED").unwrap().data_offset;
    w0[used..used + 2].copy_from_slice(&0u16.to_le_bytes());
    assert_format_err(
        parse_c3d(&w0, Path::new("w0.c3d")),
        "w0.c3d",
        "zero 3D points",
    );
    // Header/parameter disagreement.
    let mut w1 = w.clone();
    w1[2..4].copy_from_slice(&2u16.to_le_bytes());
    assert_format_err(parse_c3d(&w1, Path::new("w1.c3d")), "w1.c3d", "POINT:USED");

    let mut k = b.clone();
    k[1] = 0x51;
    assert_format_err(parse_c3d(&k, Path::new("k.c3d")), "k.c3d", "not a C3D file");
    let mut p = b.clone();
    p[512 + 3] = 99;
    assert_format_err(
        parse_c3d(&p, Path::new("p.c3d")),
        "p.c3d",
        "processor type 99",
    );
    assert_format_err(
        parse_c3d(&b[..100], Path::new("s.c3d")),
        "s.c3d",
        "512-byte",
    );
}

#[test]
fn nan_coordinates_not_flagged_missing_are_an_error() {
    let mut b = std::fs::read(data("nick_freeform_001_head.c3d")).unwrap();
    let at = 4608 + 3 * 848 + 5 * 16; // frame 3, marker 5, X
    b[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    assert_format_err(
        parse_c3d(&b, Path::new("nan.c3d")),
        "nan.c3d",
        "frame 3, point 5",
    );
    // With the residual −1 as well, it is a missing sample.
    b[at + 12..at + 16].copy_from_slice(&(-1.0f32).to_le_bytes());
    let c = parse_c3d(&b, Path::new("nan.c3d")).unwrap();
    assert!(c.markers.get(3, 5).is_none());
}

#[test]
fn integer_storage_overflow_is_refused_by_the_writer() {
    let o = C3dWriteOptions {
        storage: Storage::Integer { scale: 0.01 },
        ..Default::default()
    };
    // 1.2 m = 1200 mm = 120000 counts > 32767.
    let e = write_c3d(&synthetic(None), &o).unwrap_err();
    assert!(e.to_string().contains("int16"), "{e}");
}

#[test]
fn more_than_255_markers_use_labels2() {
    let (nm, nf) = (300, 2);
    let seq = MarkerSequence {
        names: (0..nm).map(|i| format!("M{i:03}")).collect(),
        rate_hz: 50.0,
        first_frame: 1,
        positions: (0..nm * nf).map(|i| [i as f64 * 1e-3, 0.0, 1.0]).collect(),
        source_unit: "mm".into(),
        metres_per_unit: 0.001,
        up_axis: None,
        up_source: UpSource::Unknown,
    };
    for processor in [Processor::Intel, Processor::Mips] {
        let o = C3dWriteOptions {
            processor,
            ..Default::default()
        };
        let c = parse_c3d(&write_c3d(&seq, &o).unwrap(), Path::new("big.c3d")).unwrap();
        assert_eq!(c.param("POINT", "LABELS").unwrap().strings().len(), 255);
        assert_eq!(c.param("POINT", "LABELS2").unwrap().strings().len(), 45);
        assert_eq!(c.markers.names, seq.names);
        // 599 mm is exact in f32.
        assert!((c.markers.get(1, 299).unwrap()[0] - 0.599).abs() < 1e-15);
    }
}
