//! The full real captures (not in the repository): set `PANOMAN_REAL_MOCAP` to a directory
//! holding them (e.g. one made by `panoman_mocap::fetch::fetch_real_mocap`); without it
//! these tests return early and say so. Facts from `fixtures/real-mocap/README.md` of the
//! shared fixtures and issue 13.

use std::path::PathBuf;

use panoman_mocap::markers::UpAxis;
use panoman_mocap::{bvh, c3d, csm, vsk};

fn dir() -> Option<PathBuf> {
    let d = std::env::var_os("PANOMAN_REAL_MOCAP").map(PathBuf::from);
    if d.is_none() {
        eprintln!("PANOMAN_REAL_MOCAP not set: skipping the full real-capture checks");
    }
    d
}

#[test]
fn full_c3d() {
    let Some(d) = dir() else { return };
    let c = c3d::read_c3d(&d.join("nick_freeform_001.c3d")).unwrap();
    let m = &c.markers;
    assert_eq!((m.n_markers(), m.n_frames(), m.rate_hz), (53, 1101, 120.0));
    // "about 6.6 % of marker samples missing": 3874 of 58353.
    assert_eq!(m.n_missing(), 3874);
    assert!((m.missing_fraction() - 0.066).abs() < 0.001);
    // Y up: in frame 0 the head markers are ~1.6 m above the toe markers along Y.
    let mut m = m.clone();
    m.strip_subject_prefix().unwrap();
    let z = m.to_project_frame(Some(UpAxis::Y)).unwrap();
    let (h, t) = (
        z.marker_index("LFHD").unwrap(),
        z.marker_index("LTOE").unwrap(),
    );
    let f = (0..z.n_frames())
        .find(|&f| z.get(f, h).is_some() && z.get(f, t).is_some())
        .unwrap();
    let dz = z.get(f, h).unwrap()[2] - z.get(f, t).unwrap()[2];
    assert!((1.4..2.0).contains(&dz), "{dz}");
}

#[test]
fn full_csm_vsk_bvh() {
    let Some(d) = dir() else { return };
    let (m, _) = csm::read_csm(&d.join("ThomasFechten.csm")).unwrap();
    assert_eq!((m.n_markers(), m.n_frames(), m.rate_hz), (43, 2439, 120.0));
    // "A knee–ankle distance varies by 52 mm std on one side" (capture glitches).
    let std_mm = |a: &str, b: &str| {
        let (i, j) = (m.marker_index(a).unwrap(), m.marker_index(b).unwrap());
        let d: Vec<f64> = (0..m.n_frames())
            .filter_map(|f| Some((m.get(f, i)?, m.get(f, j)?)))
            .map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>().sqrt())
            .collect();
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / d.len() as f64).sqrt() * 1e3
    };
    let (l, r) = (std_mm("LKNE", "LANK"), std_mm("RKNE", "RANK"));
    eprintln!("knee–ankle distance std: left {l:.1} mm, right {r:.1} mm");
    assert!((l.max(r) - 52.0).abs() < 3.0 && l.min(r) < 20.0, "{l} {r}");
    let v = vsk::read_vsk(&d.join("Nick01.vsk")).unwrap();
    assert_eq!(v.markers.len(), 53);
    let b = bvh::read_bvh(&d.join("01_01.bvh")).unwrap();
    assert_eq!((b.joints.len(), b.n_frames()), (31, 2752));
    assert!((b.rate_hz() - 120.0).abs() < 1e-3);
}
