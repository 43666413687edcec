//! A calibrated camera: pinhole intrinsics, OpenCV's five-coefficient distortion and a rigid
//! world → camera transform.
//!
//! Conventions (OpenCV's):
//! * camera frame: x right, y down, z forward (along the optical axis), metres;
//! * extrinsics world → camera: `x_cam = R·X + t`, so the camera centre is `C = −Rᵀ·t`;
//! * normalized coordinates `(x', y') = (x_cam/z_cam, y_cam/z_cam)`;
//! * distortion `[k1, k2, p1, p2, k3]` with `r² = x'² + y'²`,
//!   `x'' = x'·(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x'y' + p2 (r² + 2x'²)`,
//!   `y'' = y'·(1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y'²) + 2 p2 x'y'`;
//! * pixel `u = fx·x'' + skew·y'' + cx`, `v = fy·y'' + cy` (pixels, origin at the centre of
//!   the top-left pixel as in OpenCV).
//!
//! The image size is in pixels; it is `None` only where a calibration file does not carry it
//! (the OpenCV/EasyMocap YAML reader without a size argument).

use crate::error::{CaptureError, Result};
use panoman_mesh::geom::{M3, V3, add, cross, det, matvec, matvec_t, norm, scale, transpose};

/// Tolerance of [`Camera::validate`] on `RᵀR = I` (per entry) and `det R = 1`.
pub const ROTATION_TOLERANCE: f64 = 1e-6;

/// A calibrated pinhole camera with OpenCV distortion (see the module doc for the model).
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    /// Name (unique within a calibration).
    pub name: String,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Skew `K[0][1]`, pixels (0 for almost every camera).
    pub skew: f64,
    /// Distortion `[k1, k2, p1, p2, k3]` (OpenCV order), unitless.
    pub dist: [f64; 5],
    /// World → camera rotation, row-major.
    pub r: M3,
    /// World → camera translation, metres.
    pub t: V3,
    /// Image `[width, height]` in pixels; `None` when the file does not say.
    pub image_size: Option<[u32; 2]>,
    /// Whether the camera was enabled in its calibration (only Qualisys files mark cameras
    /// inactive; every other reader sets `true`).
    pub active: bool,
}

impl Camera {
    /// A camera from a row-major 3×3 intrinsic matrix `k` (9 values, the readers check the
    /// shape; `fx = k[0]`, `skew = k[1]`, `cx = k[2]`, `fy = k[4]`, `cy = k[5]`), distortion,
    /// world→camera `r`, `t` (metres), active. Not validated.
    pub(crate) fn from_intrinsic_matrix(
        name: String,
        k: &[f64],
        dist: [f64; 5],
        r: M3,
        t: V3,
        image_size: Option<[u32; 2]>,
    ) -> Camera {
        Camera {
            name,
            fx: k[0],
            fy: k[4],
            cx: k[2],
            cy: k[5],
            skew: k[1],
            dist,
            r,
            t,
            image_size,
            active: true,
        }
    }

    /// A camera without distortion or skew, active, from intrinsics, extrinsics and size.
    #[allow(clippy::too_many_arguments)]
    pub fn pinhole(
        name: impl Into<String>,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        r: M3,
        t: V3,
        image_size: Option<[u32; 2]>,
    ) -> Camera {
        Camera {
            name: name.into(),
            fx,
            fy,
            cx,
            cy,
            skew: 0.0,
            dist: [0.0; 5],
            r,
            t,
            image_size,
            active: true,
        }
    }

    /// The intrinsic matrix `K = [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]`.
    pub fn k(&self) -> M3 {
        [
            [self.fx, self.skew, self.cx],
            [0.0, self.fy, self.cy],
            [0.0, 0.0, 1.0],
        ]
    }

    /// Checks that every value is finite, `R` is a proper rotation (`RᵀR = I` per entry and
    /// `det R = 1` within [`ROTATION_TOLERANCE`]), the focal lengths are positive and the image
    /// size, when known, is positive. The error names the camera.
    pub fn validate(&self) -> Result<()> {
        self.problem()
            .map_err(|what| CaptureError::Invalid(format!("camera {:?}: {what}", self.name)))
    }

    /// What [`Camera::validate`] finds wrong, without the camera's name (for readers that
    /// name the camera their own way).
    pub(crate) fn problem(&self) -> std::result::Result<(), String> {
        let scalars = [
            ("fx", self.fx),
            ("fy", self.fy),
            ("cx", self.cx),
            ("cy", self.cy),
            ("skew", self.skew),
        ];
        for (n, v) in scalars {
            if !v.is_finite() {
                return Err(format!("{n} is not finite ({v})"));
            }
        }
        if self.dist.iter().any(|v| !v.is_finite()) {
            return Err(format!("distortion is not finite ({:?})", self.dist));
        }
        if self.t.iter().any(|v| !v.is_finite()) {
            return Err(format!("translation is not finite ({:?})", self.t));
        }
        if self.fx <= 0.0 || self.fy <= 0.0 {
            return Err(format!(
                "focal lengths must be positive (fx {}, fy {})",
                self.fx, self.fy
            ));
        }
        if let Some([w, h]) = self.image_size
            && (w == 0 || h == 0)
        {
            return Err(format!("image size {w}×{h} is not positive"));
        }
        rotation_error(&self.r)
    }

    /// The world point `X` in the camera frame, `R·X + t` (metres).
    pub fn to_camera(&self, x: V3) -> V3 {
        add(matvec(&self.r, x), self.t)
    }

    /// The camera centre in the world, `C = −Rᵀ·t` (metres).
    pub fn centre(&self) -> V3 {
        scale(matvec_t(&self.r, self.t), -1.0)
    }

    /// Applies the distortion to normalized coordinates `(x', y')` → `(x'', y'')`.
    pub fn distort(&self, p: [f64; 2]) -> [f64; 2] {
        self.distort_with_jacobian(p).0
    }

    /// Distortion and its 2×2 Jacobian `∂(x'',y'')/∂(x',y')` (row-major).
    fn distort_with_jacobian(&self, p: [f64; 2]) -> ([f64; 2], [[f64; 2]; 2]) {
        let [k1, k2, p1, p2, k3] = self.dist;
        let [x, y] = p;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        // d radial / d r²
        let dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        let j = [
            [
                radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x,
                2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y,
            ],
            [
                2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y,
                radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x,
            ],
        ];
        ([xd, yd], j)
    }

    /// Distorted normalized coordinates → pixel: `u = fx x'' + skew y'' + cx`, `v = fy y'' + cy`.
    fn to_pixel(&self, d: [f64; 2]) -> [f64; 2] {
        [
            self.fx * d[0] + self.skew * d[1] + self.cx,
            self.fy * d[1] + self.cy,
        ]
    }

    /// Projects the world point `X` (metres) to a pixel; `None` when `X` is not in front of
    /// the camera (`z_cam ≤ 0`) or the result is not finite.
    pub fn project(&self, x: V3) -> Option<[f64; 2]> {
        let c = self.to_camera(x);
        if c[2] <= 0.0 || !c[2].is_finite() {
            return None;
        }
        let px = self.to_pixel(self.distort([c[0] / c[2], c[1] / c[2]]));
        (px[0].is_finite() && px[1].is_finite()).then_some(px)
    }

    /// [`Camera::project`] with the 2×3 Jacobian `∂(u,v)/∂X` (pixels per metre, row-major).
    pub fn project_with_jacobian(&self, x: V3) -> Option<([f64; 2], [[f64; 3]; 2])> {
        let c = self.to_camera(x);
        if c[2] <= 0.0 || !c[2].is_finite() {
            return None;
        }
        let iz = 1.0 / c[2];
        let n = [c[0] / c[2], c[1] / c[2]];
        let (d, jd) = self.distort_with_jacobian(n);
        let px = self.to_pixel(d);
        // ∂pixel/∂n = [[fx, skew], [0, fy]] · jd
        let jp = [
            [
                self.fx * jd[0][0] + self.skew * jd[1][0],
                self.fx * jd[0][1] + self.skew * jd[1][1],
            ],
            [self.fy * jd[1][0], self.fy * jd[1][1]],
        ];
        // ∂n/∂c = [[1/z, 0, −x/z²], [0, 1/z, −y/z²]]; ∂c/∂X = R.
        let mut jac = [[0.0; 3]; 2];
        for (row, jp_row) in jac.iter_mut().zip(jp.iter()) {
            let dc = [
                jp_row[0] * iz,
                jp_row[1] * iz,
                -(jp_row[0] * n[0] + jp_row[1] * n[1]) * iz,
            ];
            for (k, v) in row.iter_mut().enumerate() {
                *v = dc[0] * self.r[0][k] + dc[1] * self.r[1][k] + dc[2] * self.r[2][k];
            }
        }
        let ok = px.iter().chain(jac.iter().flatten()).all(|v| v.is_finite());
        ok.then_some((px, jac))
    }

    /// Pixel → undistorted normalized coordinates `[x', y']` (the point `(x', y', 1)` in the
    /// camera frame), by Newton's method on the distortion, converged to `|distort(p) − p''|
    /// ≤ 1e-12`. `None` when the iteration does not converge (a pixel outside the region where
    /// the distortion is invertible) or the pixel is not finite.
    pub fn undistort_point(&self, pixel: [f64; 2]) -> Option<[f64; 2]> {
        let yd = (pixel[1] - self.cy) / self.fy;
        let xd = (pixel[0] - self.cx - self.skew * yd) / self.fx;
        if !(xd.is_finite() && yd.is_finite()) {
            return None;
        }
        let target = [xd, yd];
        let mut p = target;
        for _ in 0..100 {
            let (d, j) = self.distort_with_jacobian(p);
            let e = [d[0] - target[0], d[1] - target[1]];
            if e[0].abs() <= 1e-12 && e[1].abs() <= 1e-12 {
                // One more step polishes to rounding level at no risk.
                let step = solve2(&j, e)?;
                let q = [p[0] - step[0], p[1] - step[1]];
                let eq = self.distort(q);
                let better = (eq[0] - target[0]).hypot(eq[1] - target[1]) <= e[0].hypot(e[1]);
                return Some(if better { q } else { p });
            }
            let step = solve2(&j, e)?;
            // Damp steps that would leave the basin (large distortion far off-centre).
            let mut s = 1.0;
            let e_norm = e[0].hypot(e[1]);
            loop {
                let q = [p[0] - s * step[0], p[1] - s * step[1]];
                let dq = self.distort(q);
                let eq = (dq[0] - target[0]).hypot(dq[1] - target[1]);
                if eq < e_norm || s < 1e-6 {
                    p = q;
                    break;
                }
                s *= 0.5;
            }
            if !(p[0].is_finite() && p[1].is_finite()) {
                return None;
            }
        }
        None
    }

    /// The viewing ray of a pixel: `(centre, unit direction)` in the world (metres). `None`
    /// where [`Camera::undistort_point`] is.
    pub fn ray(&self, pixel: [f64; 2]) -> Option<(V3, V3)> {
        let [x, y] = self.undistort_point(pixel)?;
        let d = matvec_t(&self.r, [x, y, 1.0]);
        Some((self.centre(), scale(d, 1.0 / norm(d))))
    }

    /// The 3×4 extrinsic matrix `[R | t]`: maps homogeneous world points to the camera frame,
    /// i.e. to *undistorted normalized* coordinates after division by the third row.
    pub fn extrinsic_matrix(&self) -> [[f64; 4]; 3] {
        let mut p = [[0.0; 4]; 3];
        for (row, (r, t)) in p.iter_mut().zip(self.r.iter().zip(self.t)) {
            row[..3].copy_from_slice(r);
            row[3] = t;
        }
        p
    }

    /// The 3×4 projection matrix `P = K·[R | t]`: maps homogeneous world points to
    /// *undistorted* pixels (for DLT on pixels undistorted with `K`).
    pub fn projection_matrix(&self) -> [[f64; 4]; 3] {
        let e = self.extrinsic_matrix();
        let k = self.k();
        let mut p = [[0.0; 4]; 3];
        for (r, row) in p.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = (0..3).map(|i| k[r][i] * e[i][c]).sum();
            }
        }
        p
    }
}

/// Solves the 2×2 system `J·s = e`; `None` when singular.
fn solve2(j: &[[f64; 2]; 2], e: [f64; 2]) -> Option<[f64; 2]> {
    let d = j[0][0] * j[1][1] - j[0][1] * j[1][0];
    if d.abs() < 1e-300 || !d.is_finite() {
        return None;
    }
    Some([
        (j[1][1] * e[0] - j[0][1] * e[1]) / d,
        (j[0][0] * e[1] - j[1][0] * e[0]) / d,
    ])
}

/// `Err(what)` unless `r` is a proper rotation within [`ROTATION_TOLERANCE`].
pub(crate) fn rotation_error(r: &M3) -> std::result::Result<(), String> {
    if r.iter().flatten().any(|v| !v.is_finite()) {
        return Err("rotation is not finite".into());
    }
    let rtr = panoman_mesh::geom::matmul(&transpose(r), r);
    let mut worst = 0.0f64;
    for (i, row) in rtr.iter().enumerate() {
        for (j, v) in row.iter().enumerate() {
            let want = if i == j { 1.0 } else { 0.0 };
            worst = worst.max((v - want).abs());
        }
    }
    if worst > ROTATION_TOLERANCE {
        return Err(format!(
            "rotation is not orthonormal (max |RᵀR − I| = {worst:.3e})"
        ));
    }
    let d = det(r);
    if (d - 1.0).abs() > ROTATION_TOLERANCE {
        return Err(format!("rotation has det {d} (want 1)"));
    }
    Ok(())
}

/// The unit vector `a × b / |a × b|` (helper for building rotations in tests and tools).
pub fn unit_cross(a: V3, b: V3) -> V3 {
    let c = cross(a, b);
    scale(c, 1.0 / norm(c))
}

/// The world → camera rotation of a camera at `centre` looking at `target`, with image "up"
/// (−y of the camera) as close as possible to `up` (OpenCV frame: x right, y down, z forward).
pub fn look_at(centre: V3, target: V3, up: V3) -> M3 {
    let z = panoman_mesh::geom::normalize(panoman_mesh::geom::sub(target, centre));
    let x = unit_cross(z, up);
    let y = cross(z, x);
    [x, y, z]
}
