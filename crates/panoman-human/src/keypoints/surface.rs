//! Surface geometry on a rest mesh of the full template: plane sections, walks along them and
//! the loops and rings the face-landmark rules pick points on.

use super::*;

/// A polyline of a plane section (points on mesh edges).
#[derive(Clone, Debug)]
pub(super) struct Polyline {
    pub(super) pts: Vec<V3>,
    pub(super) closed: bool,
}

/// Geometric queries on a triangle mesh (positions + faces).
pub(super) struct Surface<'a> {
    pub(super) pos: &'a [V3],
    pub(super) faces: &'a [[u32; 3]],
}

pub(super) fn lerp(a: V3, b: V3, t: f64) -> V3 {
    [
        a[0] + t * (b[0] - a[0]),
        a[1] + t * (b[1] - a[1]),
        a[2] + t * (b[2] - a[2]),
    ]
}

pub(super) fn edge_key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

impl Surface<'_> {
    /// Closest point of the faces `subset` to `p`: the binding and the distance.
    pub(super) fn closest(&self, p: V3, subset: &[u32]) -> (Binding, f64) {
        let mut best = (f64::INFINITY, 0usize, [1.0, 0.0, 0.0]);
        for &f in subset {
            let t = self.faces[f as usize];
            let [a, b, c] = t.map(|v| self.pos[v as usize]);
            let w = closest_point_on_triangle(p, a, b, c);
            let q: V3 = std::array::from_fn(|k| w[0] * a[k] + w[1] * b[k] + w[2] * c[k]);
            let d = sub(q, p);
            let d2 = dot(d, d);
            if d2 < best.0 {
                best = (d2, f as usize, w);
            }
        }
        (
            Binding {
                tri: self.faces[best.1],
                bary: best.2,
            },
            best.0.sqrt(),
        )
    }

    /// First intersection (smallest `t > 0`) of the ray `o + t d` with the faces `subset`
    /// (Möller–Trumbore, both sides).
    pub(super) fn ray_hit(&self, o: V3, d: V3, subset: &[u32]) -> Option<(Binding, f64)> {
        let mut best: Option<(Binding, f64)> = None;
        for &f in subset {
            let t = self.faces[f as usize];
            let [a, b, c] = t.map(|v| self.pos[v as usize]);
            let e1 = sub(b, a);
            let e2 = sub(c, a);
            let pv = cross(d, e2);
            let det = dot(e1, pv);
            if det.abs() < 1e-18 {
                continue;
            }
            let inv = 1.0 / det;
            let tv = sub(o, a);
            let u = dot(tv, pv) * inv;
            if !(0.0..=1.0).contains(&u) {
                continue;
            }
            let qv = cross(tv, e1);
            let v = dot(d, qv) * inv;
            if v < 0.0 || u + v > 1.0 {
                continue;
            }
            let s = dot(e2, qv) * inv;
            if s > 0.0 && best.as_ref().is_none_or(|b| s < b.1) {
                best = Some((
                    Binding {
                        tri: t,
                        bary: [1.0 - u - v, u, v],
                    },
                    s,
                ));
            }
        }
        best
    }

    /// The section of the faces `subset` by the plane through `o` with normal `n`, as
    /// polylines (open where the subset ends). A vertex exactly on the plane counts as on
    /// the positive side.
    pub(super) fn section(&self, subset: &[u32], o: V3, n: V3) -> Vec<Polyline> {
        let side = |v: u32| dot(sub(self.pos[v as usize], o), n);
        let mut segs: Vec<[(u32, u32); 2]> = Vec::new();
        for &f in subset {
            let t = self.faces[f as usize];
            let s = t.map(|v| side(v) >= 0.0);
            let mut es = [(0, 0); 2];
            let mut k = 0;
            for i in 0..3 {
                if s[i] != s[(i + 1) % 3] {
                    es[k.min(1)] = edge_key(t[i], t[(i + 1) % 3]);
                    k += 1;
                }
            }
            if k == 2 {
                segs.push(es);
            }
        }
        let mut by_edge: HashMap<(u32, u32), Vec<usize>> = HashMap::new();
        for (i, s) in segs.iter().enumerate() {
            for e in s {
                by_edge.entry(*e).or_default().push(i);
            }
        }
        let point = |e: (u32, u32)| {
            let (da, db) = (side(e.0), side(e.1));
            lerp(
                self.pos[e.0 as usize],
                self.pos[e.1 as usize],
                da / (da - db),
            )
        };
        let mut used = vec![false; segs.len()];
        let mut out = Vec::new();
        for s0 in 0..segs.len() {
            if used[s0] {
                continue;
            }
            used[s0] = true;
            // Follow from one end, then (if open) from the other.
            let follow =
                |start_edge: (u32, u32), used: &mut Vec<bool>| -> (Vec<(u32, u32)>, bool) {
                    let mut chain = Vec::new();
                    let (mut cur, mut e) = (s0, start_edge);
                    loop {
                        let Some(&j) = by_edge[&e].iter().find(|&&j| j != cur) else {
                            return (chain, false);
                        };
                        if j == s0 {
                            return (chain, true);
                        }
                        if used[j] {
                            return (chain, false);
                        }
                        used[j] = true;
                        let e2 = if segs[j][0] == e {
                            segs[j][1]
                        } else {
                            segs[j][0]
                        };
                        chain.push(e2);
                        cur = j;
                        e = e2;
                    }
                };
            let (fwd, closed) = follow(segs[s0][1], &mut used);
            let mut edges: Vec<(u32, u32)> = Vec::new();
            if !closed {
                let (bwd, _) = follow(segs[s0][0], &mut used);
                edges.extend(bwd.into_iter().rev());
            }
            edges.push(segs[s0][0]);
            edges.push(segs[s0][1]);
            edges.extend(fwd);
            if closed {
                // The last edge pushed is the first one again.
                edges.pop();
            }
            out.push(Polyline {
                pts: edges.into_iter().map(point).collect(),
                closed,
            });
        }
        out
    }
}

/// The point of `polys` minimising `cost` among those accepted by `accept`: (polyline,
/// index).
pub(super) fn argmin_point(
    polys: &[Polyline],
    accept: impl Fn(V3) -> bool,
    cost: impl Fn(V3) -> f64,
) -> Option<(usize, usize)> {
    let mut best: Option<(f64, usize, usize)> = None;
    for (i, pl) in polys.iter().enumerate() {
        for (j, &p) in pl.pts.iter().enumerate() {
            if accept(p) {
                let c = cost(p);
                if best.is_none_or(|b| c < b.0) {
                    best = Some((c, i, j));
                }
            }
        }
    }
    best.map(|b| (b.1, b.2))
}

/// The points of a polyline from `start` onwards, in the direction in which `score` grows
/// at the first step (once around for closed polylines).
pub(super) fn walk_from(pl: &Polyline, start: usize, score: impl Fn(V3) -> f64) -> Vec<V3> {
    let n = pl.pts.len();
    let step = |i: usize, fwd: bool| -> Option<usize> {
        if fwd {
            if i + 1 < n {
                Some(i + 1)
            } else if pl.closed {
                Some(0)
            } else {
                None
            }
        } else if i > 0 {
            Some(i - 1)
        } else if pl.closed {
            Some(n - 1)
        } else {
            None
        }
    };
    let sf = step(start, true).map_or(f64::NEG_INFINITY, |j| score(pl.pts[j]));
    let sb = step(start, false).map_or(f64::NEG_INFINITY, |j| score(pl.pts[j]));
    let fwd = sf >= sb;
    let mut out = vec![pl.pts[start]];
    let mut i = start;
    while let Some(j) = step(i, fwd) {
        if j == start {
            break;
        }
        out.push(pl.pts[j]);
        i = j;
    }
    out
}

/// Index of the first local maximum of `f` along `pts`: the running maximum, once `f` has
/// dropped `hyst` below it (or at the end).
pub(super) fn first_local_max(pts: &[V3], f: impl Fn(V3) -> f64, hyst: f64) -> usize {
    let mut best = (f64::NEG_INFINITY, 0);
    for (i, &p) in pts.iter().enumerate() {
        let v = f(p);
        if v > best.0 {
            best = (v, i);
        } else if v < best.0 - hyst {
            break;
        }
    }
    best.1
}

/// First occluding-contour point along `pts` for a camera looking along `view`: walking
/// outward (`s` = image-plane coordinate growing), the first place where, over `window`
/// metres of arc, the curve moves away from the camera faster than it moves outward
/// (`Δs < tan_limit · Δdepth`), or where `s` drops `hyst` below its running maximum. Returns
/// the index of the largest `s` up to there.
pub(super) fn first_silhouette(
    pts: &[V3],
    s: impl Fn(V3) -> f64,
    view: V3,
    window: f64,
    tan_limit: f64,
    hyst: f64,
) -> usize {
    let n = pts.len();
    let mut best = (f64::NEG_INFINITY, 0usize);
    let mut j = 0usize;
    let mut arc_j = 0.0;
    let mut arc_i = 0.0;
    for i in 0..n {
        if i > 0 {
            arc_i += norm(sub(pts[i], pts[i - 1]));
        }
        let si = s(pts[i]);
        if si > best.0 {
            best = (si, i);
        } else if si < best.0 - hyst {
            return best.1;
        }
        if j < i {
            j = i;
            arc_j = arc_i;
        }
        while j + 1 < n && arc_j - arc_i < window {
            arc_j += norm(sub(pts[j + 1], pts[j]));
            j += 1;
        }
        if arc_j - arc_i < window {
            break;
        }
        let ds = s(pts[j]) - si;
        let dd = dot(sub(pts[j], pts[i]), view);
        if dd > 0.0 && ds < tan_limit * dd {
            // The contour lies between i and j: the largest s there.
            let mut b = (si, i);
            for (k, &p) in pts.iter().enumerate().take(j + 1).skip(i) {
                if s(p) > b.0 {
                    b = (s(p), k);
                }
            }
            return if b.0 >= best.0 { b.1 } else { best.1 };
        }
    }
    best.1
}

/// Index of the sharpest concave bend of the curve `pts` in the plane spanned by `u`
/// (depth) and `v` (up): the point `i` minimising the signed turn
/// `(d1 × d2) / (|d1| |d2|)` of the chords `d1 = p_i − p_j`, `d2 = p_k − p_i` spanning `half`
/// metres of arc on each side. Concave = the curve turns from moving along `+u` towards
/// `−v`.
pub(super) fn sharpest_bend(pts: &[V3], half: f64, u: V3, v: V3) -> usize {
    let n = pts.len();
    let mut arc = vec![0.0; n];
    for i in 1..n {
        arc[i] = arc[i - 1] + norm(sub(pts[i], pts[i - 1]));
    }
    let mut best = (f64::INFINITY, 0usize);
    for i in 0..n {
        if arc[i] < half || arc[n - 1] - arc[i] < half {
            continue;
        }
        let j = arc
            .partition_point(|&a| a <= arc[i] - half)
            .saturating_sub(1);
        let k = arc.partition_point(|&a| a < arc[i] + half).min(n - 1);
        let d1 = sub(pts[i], pts[j]);
        let d2 = sub(pts[k], pts[i]);
        let (a1, b1) = (dot(d1, u), dot(d1, v));
        let (a2, b2) = (dot(d2, u), dot(d2, v));
        let den = ((a1 * a1 + b1 * b1) * (a2 * a2 + b2 * b2)).sqrt();
        if den <= 0.0 {
            continue;
        }
        let turn = (a1 * b2 - b1 * a2) / den;
        if turn < best.0 {
            best = (turn, i);
        }
    }
    best.1
}

/// The first point of the polyline `pts` where coordinate `axis` crosses `value` (linear
/// interpolation); the nearest end point if it never does.
pub(super) fn at_coord(pts: &[V3], axis: usize, value: f64) -> V3 {
    for w in pts.windows(2) {
        let (a, b) = (w[0][axis], w[1][axis]);
        if (a - value) * (b - value) <= 0.0 && a != b {
            return lerp(w[0], w[1], (value - a) / (b - a));
        }
        if a == value {
            return w[0];
        }
    }
    let first = pts[0];
    let last = pts[pts.len() - 1];
    if (first[axis] - value).abs() <= (last[axis] - value).abs() {
        first
    } else {
        last
    }
}

/// The closed loop of vertices between faces labelled `inner` and faces labelled `outer`
/// (each a set of labels), as an ordered vertex cycle.
pub(super) fn label_loop(
    topo: &Topology,
    face_label: &[u8],
    inner: &[u8],
    outer: &[u8],
) -> std::result::Result<Vec<u32>, String> {
    let mut nbr: HashMap<u32, Vec<u32>> = HashMap::new();
    for (e, ef) in topo.edge_faces.iter().enumerate() {
        if ef[1] == panoman_mesh::topology::NONE {
            continue;
        }
        let (l0, l1) = (face_label[ef[0] as usize], face_label[ef[1] as usize]);
        if (inner.contains(&l0) && outer.contains(&l1))
            || (inner.contains(&l1) && outer.contains(&l0))
        {
            let [a, b] = topo.edges[e];
            nbr.entry(a).or_default().push(b);
            nbr.entry(b).or_default().push(a);
        }
    }
    if nbr.is_empty() {
        return Err("no boundary between the labels".into());
    }
    if let Some((v, n)) = nbr.iter().find(|(_, n)| n.len() != 2) {
        return Err(format!(
            "boundary vertex {v} has {} boundary edges",
            n.len()
        ));
    }
    let start = *nbr.keys().min().unwrap_or(&0);
    let mut cycle = vec![start];
    let mut prev = start;
    let mut cur = nbr[&start][0];
    while cur != start {
        cycle.push(cur);
        let n = &nbr[&cur];
        let next = if n[0] == prev { n[1] } else { n[0] };
        prev = cur;
        cur = next;
        if cycle.len() > nbr.len() {
            return Err("boundary is not a simple loop".into());
        }
    }
    if cycle.len() != nbr.len() {
        return Err(format!(
            "boundary has several loops ({} of {} vertices in the first)",
            cycle.len(),
            nbr.len()
        ));
    }
    Ok(cycle)
}

/// Splits a closed loop of points at its smallest-x and largest-x points into the upper
/// and lower arcs, both running from the smallest-x to the largest-x point.
pub(super) fn split_arcs(pts: &[V3]) -> (Vec<V3>, Vec<V3>) {
    let n = pts.len();
    let imin = (0..n)
        .min_by(|&a, &b| pts[a][0].total_cmp(&pts[b][0]))
        .unwrap_or(0);
    let imax = (0..n)
        .max_by(|&a, &b| pts[a][0].total_cmp(&pts[b][0]))
        .unwrap_or(0);
    let mut a1 = vec![pts[imin]];
    let mut i = imin;
    while i != imax {
        i = (i + 1) % n;
        a1.push(pts[i]);
    }
    let mut a2 = vec![pts[imin]];
    let mut i = imin;
    while i != imax {
        i = (i + n - 1) % n;
        a2.push(pts[i]);
    }
    let mean_z = |a: &[V3]| a.iter().map(|p| p[2]).sum::<f64>() / a.len() as f64;
    if mean_z(&a1) >= mean_z(&a2) {
        (a1, a2)
    } else {
        (a2, a1)
    }
}

/// Vertices at quad-graph distance exactly `k` from `start`, walking only over the quads
/// accepted by `quad_ok`, ordered by angle around their centroid in the frontal (x, z)
/// plane.
pub(super) fn quad_ring(
    template: &Template,
    pos: &[V3],
    quad_ok: impl Fn(usize) -> bool,
    start: &[u32],
    k: usize,
) -> Vec<V3> {
    let n = pos.len();
    let mut adj: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (q, quad) in template.quads.iter().enumerate() {
        if !quad_ok(q) {
            continue;
        }
        for s in 0..4 {
            let (a, b) = (quad[s], quad[(s + 1) % 4]);
            adj[a as usize].push(b);
            adj[b as usize].push(a);
        }
    }
    let mut dist = vec![usize::MAX; n];
    let mut front: Vec<u32> = start.to_vec();
    for &v in start {
        dist[v as usize] = 0;
    }
    for d in 1..=k {
        let mut next = Vec::new();
        for &v in &front {
            for &u in &adj[v as usize] {
                if dist[u as usize] == usize::MAX {
                    dist[u as usize] = d;
                    next.push(u);
                }
            }
        }
        front = next;
    }
    let ring: Vec<V3> = front.iter().map(|&v| pos[v as usize]).collect();
    let m = ring.len().max(1) as f64;
    let c = [
        ring.iter().map(|p| p[0]).sum::<f64>() / m,
        0.0,
        ring.iter().map(|p| p[2]).sum::<f64>() / m,
    ];
    let mut ring = ring;
    ring.sort_by(|a, b| {
        let ta = (a[2] - c[2]).atan2(a[0] - c[0]);
        let tb = (b[2] - c[2]).atan2(b[0] - c[0]);
        ta.total_cmp(&tb)
    });
    ring
}
