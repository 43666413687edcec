//! Shared fixtures: a four-camera rig with distortion around a capture volume, a point cloud,
//! a deterministic normal generator and projection comparisons.
#![allow(dead_code)]

use panoman_capture::Camera;
use panoman_capture::camera::look_at;
use panoman_mesh::geom::{V3, matvec, scale};

/// Four cameras on a 3.5 m circle, 1.6 m high, looking at (0, 0, 1) (Z up), each with its own
/// intrinsics and a moderate OpenCV distortion (monotone over the image).
pub fn rig() -> Vec<Camera> {
    let mut cams = Vec::new();
    for i in 0..4 {
        let a = 0.3 + i as f64 * std::f64::consts::FRAC_PI_2 + 0.1 * i as f64;
        let centre = [3.5 * a.cos(), 3.5 * a.sin(), 1.6 + 0.1 * i as f64];
        let r = look_at(centre, [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]);
        let t = scale(matvec(&r, centre), -1.0);
        let mut c = Camera::pinhole(
            format!("cam{:02}", i + 1),
            1100.0 + 20.0 * i as f64,
            1105.0 + 15.0 * i as f64,
            955.0 + 3.0 * i as f64,
            545.0 - 2.0 * i as f64,
            r,
            t,
            Some([1920, 1080]),
        );
        c.dist = [
            -0.2 + 0.02 * i as f64,
            0.05,
            0.001,
            -0.0005 * i as f64,
            0.01 * (i % 2) as f64,
        ];
        cams.push(c);
    }
    cams
}

/// A deterministic cloud of 27 points in a 1 m cube centred on (0, 0, 1).
pub fn cloud() -> Vec<V3> {
    let mut pts = Vec::new();
    for i in 0..3 {
        for j in 0..3 {
            for k in 0..3 {
                pts.push([
                    -0.5 + 0.5 * i as f64 + 0.01 * k as f64,
                    -0.5 + 0.5 * j as f64 - 0.02 * i as f64,
                    0.5 + 0.5 * k as f64 + 0.03 * j as f64,
                ]);
            }
        }
    }
    pts
}

/// Largest pixel distance between the projections of `pts` by paired cameras (panics when a
/// point projects in one and not the other, or the lists differ in length).
pub fn max_px_diff(a: &[Camera], b: &[Camera], pts: &[V3]) -> f64 {
    assert_eq!(a.len(), b.len(), "camera counts differ");
    let mut worst = 0.0f64;
    for (ca, cb) in a.iter().zip(b) {
        for &p in pts {
            let pa = ca.project(p).expect("point in front of camera a");
            let pb = cb.project(p).expect("point in front of camera b");
            worst = worst.max((pa[0] - pb[0]).hypot(pa[1] - pb[1]));
        }
    }
    worst
}

/// Deterministic standard normal samples (64-bit LCG + Box–Muller).
pub struct Normal(u64);

impl Normal {
    pub fn new(seed: u64) -> Normal {
        Normal(seed)
    }
    fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    pub fn sample(&mut self) -> f64 {
        let u1 = self.uniform();
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// A temporary directory unique to the test (removed by the caller when it wants).
pub fn temp_dir(tag: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("panoman-capture-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}
