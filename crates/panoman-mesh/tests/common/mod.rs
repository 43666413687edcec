//! Test meshes and a deterministic RNG shared by the kernel tests.
#![allow(dead_code)]

use panoman_mesh::geom::V3;
pub use panoman_mesh::shapes::icosphere;

/// SplitMix64: small, deterministic, good enough for test data.
pub struct Rng(pub u64);
impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in [a, b).
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.uniform()
    }
    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
    pub fn vec3(&mut self) -> V3 {
        [self.normal(), self.normal(), self.normal()]
    }
}

/// A smooth, strongly non-rigid deformation of the unit sphere: anisotropic scale, a twist about
/// z, a bend and bumps (keeps the surface embedded).
pub fn deform(p: V3) -> V3 {
    let [x, y, z] = p;
    let (x, y, z) = (1.3 * x, 0.8 * y, 1.1 * z + 0.2 * x * x);
    let a = 1.2 * z;
    let (s, c) = a.sin_cos();
    let (x, y) = (c * x - s * y, s * x + c * y);
    let bump = 1.0 + 0.08 * (3.0 * x).sin() * (2.0 * y).cos();
    [x * bump + 0.3, y * bump - 0.1, z * bump + 0.05 * x]
}

/// A flat grid (open mesh) of (n+1)² vertices, slightly bent.
pub fn grid(n: usize) -> (Vec<V3>, Vec<[u32; 3]>) {
    let mut v = Vec::new();
    for i in 0..=n {
        for j in 0..=n {
            let (x, y) = (i as f64 / n as f64, j as f64 / n as f64);
            v.push([x, y, 0.3 * (x * 2.0).sin() * y]);
        }
    }
    let id = |i: usize, j: usize| (i * (n + 1) + j) as u32;
    let mut f = Vec::new();
    for i in 0..n {
        for j in 0..n {
            f.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            f.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    (v, f)
}
