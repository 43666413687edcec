//! Procedural test and example shapes.

use crate::geom::{V3, normalize};
use std::collections::HashMap;

/// The unit icosphere: a regular icosahedron whose faces are split `subdiv` times into four
/// (edge midpoints pushed back onto the sphere). Faces are counter-clockwise seen from outside.
/// Sizes: `V = 10·4^s + 2`, `F = 20·4^s`; vertex order is deterministic (12 icosahedron
/// vertices, then midpoints in creation order).
pub fn icosphere(subdiv: usize) -> (Vec<V3>, Vec<[u32; 3]>) {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v: Vec<V3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|&p| normalize(p))
    .collect();
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdiv {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut nf = Vec::with_capacity(f.len() * 4);
        for &[a, b, c] in &f {
            let mut m = |p: u32, q: u32| -> u32 {
                *mid.entry((p.min(q), p.max(q))).or_insert_with(|| {
                    let (x, y) = (v[p as usize], v[q as usize]);
                    v.push(normalize([x[0] + y[0], x[1] + y[1], x[2] + y[2]]));
                    (v.len() - 1) as u32
                })
            };
            let (ab, bc, ca) = (m(a, b), m(b, c), m(c, a));
            nf.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        f = nf;
    }
    (v, f)
}
