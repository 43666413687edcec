//! The camera model: Jacobian, undistortion, rays, centre, projection matrix, validation and
//! Rodrigues conversions.

mod common;

use common::{cloud, rig};
use panoman_capture::Camera;
use panoman_mesh::geom::{V3, cross, dot, norm, sub};

#[test]
fn jacobian_matches_central_differences() {
    let mut cams = rig();
    cams[1].skew = 3.0; // exercise the skew term too
    for cam in &cams {
        for p in cloud() {
            let (px, j) = cam.project_with_jacobian(p).unwrap();
            assert_eq!(px, cam.project(p).unwrap());
            let h = 1e-6;
            for k in 0..3 {
                let mut a = p;
                let mut b = p;
                a[k] += h;
                b[k] -= h;
                let (pa, pb) = (cam.project(a).unwrap(), cam.project(b).unwrap());
                for r in 0..2 {
                    let fd = (pa[r] - pb[r]) / (2.0 * h);
                    // Central differences: truncation O(h²·|∂³π|) plus rounding ~1e-13/h;
                    // entries are ~300 px/m here.
                    assert!(
                        (fd - j[r][k]).abs() < 1e-5 * (1.0 + j[r][k].abs()),
                        "{}: ∂{r}/∂X{k} analytic {} vs fd {fd}",
                        cam.name,
                        j[r][k]
                    );
                }
            }
        }
    }
}

#[test]
fn undistort_recovers_normalized_coordinates() {
    for cam in rig() {
        for p in cloud() {
            let c = cam.to_camera(p);
            let want = [c[0] / c[2], c[1] / c[2]];
            let got = cam.undistort_point(cam.project(p).unwrap()).unwrap();
            assert!(
                (got[0] - want[0]).abs() <= 1e-9 && (got[1] - want[1]).abs() <= 1e-9,
                "{}: {got:?} vs {want:?}",
                cam.name
            );
        }
        // The image corners too (strongest distortion).
        for px in [[0.0, 0.0], [1919.0, 0.0], [0.0, 1079.0], [1919.0, 1079.0]] {
            let n = cam.undistort_point(px).unwrap();
            let d = cam.distort(n);
            let back = [
                cam.fx * d[0] + cam.skew * d[1] + cam.cx,
                cam.fy * d[1] + cam.cy,
            ];
            assert!((back[0] - px[0]).abs() < 1e-8 && (back[1] - px[1]).abs() < 1e-8);
        }
    }
}

#[test]
fn ray_passes_through_the_point_and_centre_is_minus_rt_t() {
    for cam in rig() {
        let c = cam.centre();
        // centre = −Rᵀt  ⇔  R·C + t = 0
        assert!(norm(cam.to_camera(c)) < 1e-12);
        for p in cloud() {
            let (o, d) = cam.ray(cam.project(p).unwrap()).unwrap();
            assert!((norm(d) - 1.0).abs() < 1e-12);
            assert_eq!(o, c);
            let v = sub(p, o);
            // distance of p from the ray: |v × d|
            assert!(norm(cross(v, d)) < 1e-9, "{}", cam.name);
            assert!(dot(v, d) > 0.0);
        }
    }
}

#[test]
fn projection_matrix_projects_like_the_camera_without_distortion() {
    for mut cam in rig() {
        cam.dist = [0.0; 5];
        cam.skew = 1.5;
        let p = cam.projection_matrix();
        for x in cloud() {
            let h: Vec<f64> = (0..3)
                .map(|r| p[r][0] * x[0] + p[r][1] * x[1] + p[r][2] * x[2] + p[r][3])
                .collect();
            let want = cam.project(x).unwrap();
            assert!((h[0] / h[2] - want[0]).abs() < 1e-9 && (h[1] / h[2] - want[1]).abs() < 1e-9);
        }
    }
}

#[test]
fn points_behind_the_camera_do_not_project() {
    let cam = &rig()[0];
    let c = cam.centre();
    let axis = cam.r[2];
    let behind: V3 = [c[0] - axis[0], c[1] - axis[1], c[2] - axis[2]];
    assert!(cam.project(behind).is_none());
    assert!(cam.project_with_jacobian(behind).is_none());
    assert!(cam.project(c).is_none());
}

#[test]
fn validate_rejects_bad_cameras() {
    let good = rig()[0].clone();
    good.validate().unwrap();
    let mut bad: Vec<(Camera, &str)> = Vec::new();
    let mut c = good.clone();
    c.fx = -1.0;
    bad.push((c, "focal"));
    let mut c = good.clone();
    c.t[1] = f64::NAN;
    bad.push((c, "translation"));
    let mut c = good.clone();
    c.r[0][0] *= 1.001;
    bad.push((c, "orthonormal"));
    let mut c = good.clone();
    c.r[2] = [-c.r[2][0], -c.r[2][1], -c.r[2][2]]; // a reflection
    bad.push((c, "det"));
    let mut c = good.clone();
    c.image_size = Some([0, 1080]);
    bad.push((c, "image size"));
    let mut c = good.clone();
    c.dist[4] = f64::INFINITY;
    bad.push((c, "distortion"));
    for (c, what) in bad {
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains(what) && e.contains("cam01"), "{e}");
    }
    let mut c = good;
    c.image_size = None; // unknown size is accepted
    c.validate().unwrap();
}
