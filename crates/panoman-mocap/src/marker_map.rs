//! Marker maps: marker name → a point on the template surface (triangle + barycentric
//! coordinates) and an offset along the surface normal (marker radius + skin, metres).
//!
//! Two forms, both JSON:
//! * a **marker set** ([`MarkerSetSpec`], `data/cmu53.json`, `data/plugin_gait43.json`):
//!   topology-free anatomical rules. Each marker is a ray from a rig bone head of the default
//!   identity at rest (or the point `t` of the way from it to the head of bone `to`, or to its
//!   own tail when `to` is absent), along `direction` in the template frame (+X the subject's
//!   left, −Y front, +Z up), to its first crossing of the template surface (the anchors lie
//!   inside the body). The offset is `marker_radius_m + skin_m` unless `offset_m` is given.
//! * a **placed map** ([`MarkerMap`]): the same markers resolved on one topology (what
//!   [`MarkerSetSpec::place`] returns and what a calibration writes, `marker_map.json`).
//!
//! [`read_marker_map`] reads either; [`default_set_for`] picks the shipped set that covers a
//! capture's marker names and otherwise lists the names no set knows.
use std::collections::BTreeMap;
use std::path::Path;

use panoman_human::params::ShapeParams;
use panoman_mesh::geom::{V3, add, cross, dot, norm, scale, sub};
use serde::{Deserialize, Serialize};

use crate::error::{MocapError, Result};

/// One marker of a [`MarkerSetSpec`]: where on the body it sits, as a rule on the rig.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MarkerSpec {
    /// Rig bone whose rest head anchors the ray.
    pub bone: String,
    /// Direction of the ray (template frame; any non-zero length).
    pub direction: V3,
    /// Bone toward whose head the anchor moves by `t`; `None`: toward `bone`'s own tail.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub to: Option<String>,
    /// Fraction of the way from `bone`'s head (0 = the head itself).
    #[serde(default)]
    pub t: f64,
    /// Offset along the normal (metres); `None`: the set's radius + skin.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset_m: Option<f64>,
    /// Anatomical landmark, for people editing the file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// A marker set: named anatomical rules (see the module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MarkerSetSpec {
    /// Set name (`cmu53`, `plugin_gait43`).
    pub name: String,
    /// What the set is and how its rules read.
    #[serde(default)]
    pub description: String,
    /// Marker radius (metres), part of the default offset.
    pub marker_radius_m: f64,
    /// Skin and soft tissue between the surface and the marker base (metres).
    pub skin_m: f64,
    /// The markers by name.
    pub markers: BTreeMap<String, MarkerSpec>,
}

/// A marker resolved on a topology.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlacedMarker {
    /// Marker name.
    pub name: String,
    /// Triangle of the template.
    pub triangle: u32,
    /// Barycentric coordinates in that triangle (sum 1).
    pub barycentric: V3,
    /// Offset of the marker centre along the outward normal (metres).
    pub offset_m: f64,
    /// The bone that anchored it (its body part; torso markers start the solve).
    pub bone: String,
}

/// A marker map on one topology (`marker_map.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MarkerMap {
    /// The marker set it came from.
    pub set: String,
    /// The template topology (`full`, `small`).
    pub topology: String,
    /// Vertex count of that topology.
    pub n_vertices: usize,
    /// The markers.
    pub markers: Vec<PlacedMarker>,
}

/// The shipped CMU-style 53-marker set (`data/cmu53.json`).
pub const CMU53_JSON: &str = include_str!("../data/cmu53.json");
/// The shipped Plug-in-Gait-like 43-marker set (`data/plugin_gait43.json`).
pub const PLUGIN_GAIT43_JSON: &str = include_str!("../data/plugin_gait43.json");

/// The shipped marker sets.
///
/// # Panics
/// Never for the shipped files (a test parses them).
pub fn default_sets() -> Vec<MarkerSetSpec> {
    [CMU53_JSON, PLUGIN_GAIT43_JSON]
        .iter()
        .map(|s| serde_json::from_str(s).expect("shipped marker sets parse"))
        .collect()
}

/// The shipped set that has every name of `names`.
///
/// # Errors
/// [`MocapError::Invalid`] listing the names the closest set lacks.
pub fn default_set_for(names: &[String]) -> Result<MarkerSetSpec> {
    let mut best: Option<(usize, MarkerSetSpec)> = None;
    for s in default_sets() {
        let missing = names.iter().filter(|n| !s.markers.contains_key(*n)).count();
        if best.as_ref().is_none_or(|(m, _)| missing < *m) {
            best = Some((missing, s));
        }
    }
    let (_, set) = best.expect("two shipped sets");
    let unknown: Vec<&str> = names
        .iter()
        .filter(|n| !set.markers.contains_key(*n))
        .map(String::as_str)
        .collect();
    if unknown.is_empty() {
        Ok(set)
    } else {
        Err(MocapError::Invalid {
            what: format!(
                "no marker map for {} of the capture's markers: {} (closest shipped set `{}`; pass --marker-map)",
                unknown.len(),
                unknown.join(", "),
                set.name
            ),
        })
    }
}

/// Either form of a marker map file.
#[derive(Clone, Debug, PartialEq)]
pub enum MarkerMapFile {
    /// Anatomical rules.
    Set(MarkerSetSpec),
    /// Placed on a topology.
    Placed(MarkerMap),
}

/// Reads a marker set or a placed marker map (JSON).
///
/// # Errors
/// [`MocapError::Io`] / [`MocapError::Format`] naming the file.
pub fn read_marker_map(path: &Path) -> Result<MarkerMapFile> {
    let text = std::fs::read_to_string(path).map_err(|source| MocapError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let fmt = |what: String| MocapError::Format {
        path: path.to_path_buf(),
        what,
    };
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| fmt(e.to_string()))?;
    if v.get("topology").is_some() {
        let m: MarkerMap = serde_json::from_value(v).map_err(|e| fmt(e.to_string()))?;
        Ok(MarkerMapFile::Placed(m))
    } else {
        let s: MarkerSetSpec = serde_json::from_value(v).map_err(|e| fmt(e.to_string()))?;
        Ok(MarkerMapFile::Set(s))
    }
}

/// The template surface of a rig at rest (default identity) with its bones.
#[derive(Clone, Debug)]
pub struct RestTemplate {
    /// Topology name.
    pub topology: String,
    /// Triangles.
    pub faces: Vec<[u32; 3]>,
    /// Rest vertices (metres).
    pub vertices: Vec<V3>,
    /// Bone names.
    pub bone_names: Vec<String>,
    /// Rest bone heads.
    pub heads: Vec<V3>,
    /// Rest bone tails.
    pub tails: Vec<V3>,
    /// +1 when the faces' winding gives outward normals, −1 otherwise.
    pub normal_sign: f64,
}

impl RestTemplate {
    /// The rest template of a rig on the model's topology for `shape`.
    ///
    /// # Errors
    /// Invalid shape parameters.
    pub fn new(
        rig: &panoman_fit::LbsRig,
        faces: &[[u32; 3]],
        topology: &str,
        shape: &ShapeParams,
    ) -> Result<RestTemplate> {
        let id = rig
            .generator
            .identity(shape)
            .map_err(|e| MocapError::Invalid {
                what: format!("rig identity: {e}"),
            })?;
        let vertices = rig.map.map(rig.topology, id.rest_vertices());
        let normal_sign = outward_sign(faces, &vertices);
        Ok(RestTemplate {
            topology: topology.to_string(),
            faces: faces.to_vec(),
            vertices,
            bone_names: rig.generator.bone_names().to_vec(),
            heads: id.bone_heads().to_vec(),
            tails: id.bone_tails().to_vec(),
            normal_sign,
        })
    }

    fn bone(&self, name: &str) -> Result<usize> {
        self.bone_names
            .iter()
            .position(|b| b == name)
            .ok_or_else(|| MocapError::Invalid {
                what: format!("marker map: unknown rig bone `{name}`"),
            })
    }
}

impl MarkerSetSpec {
    /// Places the markers named in `names` (all of the set's when `None`) on `template`.
    /// `radius_m` overrides the set's marker radius (e.g. a VSK's).
    ///
    /// # Errors
    /// [`MocapError::Invalid`] for names the set lacks (listed), unknown bones, zero
    /// directions or a ray that misses the surface.
    pub fn place(
        &self,
        template: &RestTemplate,
        names: Option<&[String]>,
        radius_m: Option<f64>,
    ) -> Result<MarkerMap> {
        let all: Vec<String> = self.markers.keys().cloned().collect();
        let names = names.unwrap_or(&all);
        let unknown: Vec<&str> = names
            .iter()
            .filter(|n| !self.markers.contains_key(*n))
            .map(String::as_str)
            .collect();
        if !unknown.is_empty() {
            return Err(MocapError::Invalid {
                what: format!(
                    "marker set `{}` has no entry for: {}",
                    self.name,
                    unknown.join(", ")
                ),
            });
        }
        let radius = radius_m.unwrap_or(self.marker_radius_m);
        let mut markers = Vec::with_capacity(names.len());
        for name in names {
            let s = &self.markers[name];
            let b = template.bone(&s.bone)?;
            let end = match &s.to {
                Some(to) => template.heads[template.bone(to)?],
                None => template.tails[b],
            };
            let o = add(template.heads[b], scale(sub(end, template.heads[b]), s.t));
            let l = norm(s.direction);
            if !(l > 0.0 && l.is_finite()) {
                return Err(MocapError::Invalid {
                    what: format!("marker `{name}`: zero or non-finite direction"),
                });
            }
            let d = scale(s.direction, 1.0 / l);
            let (triangle, barycentric) = ray_first_hit(&template.faces, &template.vertices, o, d)
                .ok_or_else(|| MocapError::Invalid {
                    what: format!("marker `{name}`: its ray misses the template surface"),
                })?;
            markers.push(PlacedMarker {
                name: name.clone(),
                triangle,
                barycentric,
                offset_m: s.offset_m.unwrap_or(radius + self.skin_m),
                bone: s.bone.clone(),
            });
        }
        Ok(MarkerMap {
            set: self.name.clone(),
            topology: template.topology.clone(),
            n_vertices: template.vertices.len(),
            markers,
        })
    }
}

impl MarkerMap {
    /// Checks the map against a topology and returns, for each of `names`, its marker.
    ///
    /// # Errors
    /// [`MocapError::Invalid`]: another topology, triangles out of range, names missing
    /// (listed).
    pub fn select(&self, topology: &str, faces: usize, names: &[String]) -> Result<MarkerMap> {
        if self.topology != topology {
            return Err(MocapError::Invalid {
                what: format!(
                    "marker map is on the `{}` topology, the model's is `{topology}`",
                    self.topology
                ),
            });
        }
        if let Some(m) = self.markers.iter().find(|m| m.triangle as usize >= faces) {
            return Err(MocapError::Invalid {
                what: format!("marker `{}`: triangle {} out of range", m.name, m.triangle),
            });
        }
        let mut out = Vec::new();
        let mut unknown = Vec::new();
        for n in names {
            match self.markers.iter().find(|m| &m.name == n) {
                Some(m) => out.push(m.clone()),
                None => unknown.push(n.as_str()),
            }
        }
        if !unknown.is_empty() {
            return Err(MocapError::Invalid {
                what: format!("marker map has no entry for: {}", unknown.join(", ")),
            });
        }
        Ok(MarkerMap {
            markers: out,
            ..self.clone()
        })
    }
}

/// `Σ b_i x_{f_i}`.
pub fn surface_point(faces: &[[u32; 3]], x: &[V3], tri: u32, b: V3) -> V3 {
    let f = faces[tri as usize];
    let mut p = [0.0; 3];
    for k in 0..3 {
        p = add(p, scale(x[f[k] as usize], b[k]));
    }
    p
}

/// Area-weighted vertex normals (unit; `sign` flips them outward).
pub fn vertex_normals(faces: &[[u32; 3]], x: &[V3], sign: f64) -> Vec<V3> {
    panoman_mesh::measure::vertex_normals_of(faces, x)
        .into_iter()
        .map(|n| {
            if n == [0.0; 3] {
                [0.0, 0.0, 1.0]
            } else {
                scale(n, sign)
            }
        })
        .collect()
}

/// The interpolated unit normal at a surface point.
pub fn surface_normal(faces: &[[u32; 3]], normals: &[V3], tri: u32, b: V3) -> V3 {
    let n = surface_point(faces, normals, tri, b);
    let l = norm(n);
    if l > 0.0 { scale(n, 1.0 / l) } else { n }
}

/// The model positions of `map`'s markers on the mesh `x` (`faces`): each marker's surface
/// point plus its offset along the interpolated vertex normal (`normal_sign`: +1 when the
/// winding's normals point outward, see [`RestTemplate::normal_sign`]), metres.
pub fn model_markers(map: &MarkerMap, faces: &[[u32; 3]], x: &[V3], normal_sign: f64) -> Vec<V3> {
    let n = vertex_normals(faces, x, normal_sign);
    map.markers
        .iter()
        .map(|m| {
            let p = surface_point(faces, x, m.triangle, m.barycentric);
            let nn = surface_normal(faces, &n, m.triangle, m.barycentric);
            add(p, scale(nn, m.offset_m))
        })
        .collect()
}

/// +1 when the winding's normals point away from the centroid on average, else −1 (the
/// [`RestTemplate::normal_sign`] of a closed mesh).
pub fn outward_sign(faces: &[[u32; 3]], x: &[V3]) -> f64 {
    let c = x.iter().fold([0.0; 3], |a, p| {
        add(a, scale(*p, 1.0 / x.len().max(1) as f64))
    });
    let s: f64 = faces
        .iter()
        .map(|f| {
            let [a, b, cc] = f.map(|i| x[i as usize]);
            let m = scale(add(add(a, b), cc), 1.0 / 3.0);
            dot(cross(sub(b, a), sub(cc, a)), sub(m, c))
        })
        .sum();
    if s >= 0.0 { 1.0 } else { -1.0 }
}

/// The first triangle a ray `o + t d` (t > 0) crosses, with the barycentric coordinates.
pub fn ray_first_hit(faces: &[[u32; 3]], x: &[V3], o: V3, d: V3) -> Option<(u32, V3)> {
    let mut best: Option<(f64, u32, V3)> = None;
    for (i, f) in faces.iter().enumerate() {
        let [a, b, c] = f.map(|k| x[k as usize]);
        let (e1, e2) = (sub(b, a), sub(c, a));
        let p = cross(d, e2);
        let det = dot(e1, p);
        if det.abs() < 1e-14 {
            continue;
        }
        let s = sub(o, a);
        let u = dot(s, p) / det;
        let q = cross(s, e1);
        let v = dot(d, q) / det;
        let t = dot(e2, q) / det;
        if u < 0.0 || v < 0.0 || u + v > 1.0 || t <= 0.0 {
            continue;
        }
        if best.is_none_or(|(bt, _, _)| t < bt) {
            best = Some((t, i as u32, [1.0 - u - v, u, v]));
        }
    }
    best.map(|(_, i, b)| (i, b))
}

/// The closest point of triangle `(a, b, c)` to `p`, as barycentric coordinates.
pub fn closest_on_triangle(p: V3, a: V3, b: V3, c: V3) -> V3 {
    // Ericson, Real-Time Collision Detection §5.1.5.
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return [0.0, 1.0, 0.0];
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return [1.0 - v, v, 0.0];
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return [0.0, 0.0, 1.0];
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return [1.0 - w, 0.0, w];
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return [0.0, 1.0 - w, w];
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    [1.0 - v - w, v, w]
}

/// The closest surface point to `p` among the triangles with a vertex within `radius` of
/// `p` (all triangles when none is): `(triangle, barycentric)`.
pub fn closest_point(faces: &[[u32; 3]], x: &[V3], p: V3, radius: f64) -> (u32, V3) {
    let r2 = radius * radius;
    let near = |f: &[u32; 3]| {
        f.iter().any(|&i| {
            let d = sub(x[i as usize], p);
            dot(d, d) < r2
        })
    };
    let all = 0..faces.len() as u32;
    closest_point_among(
        faces,
        x,
        p,
        all.clone().filter(|&t| near(&faces[t as usize])),
    )
    .or_else(|| closest_point_among(faces, x, p, all))
    .unwrap_or((0, [1.0, 0.0, 0.0]))
}

/// The closest surface point to `p` among the triangles `candidates`:
/// `(triangle, barycentric)`; `None` when there are none.
pub fn closest_point_among(
    faces: &[[u32; 3]],
    x: &[V3],
    p: V3,
    candidates: impl IntoIterator<Item = u32>,
) -> Option<(u32, V3)> {
    let mut best: Option<(f64, u32, V3)> = None;
    for t in candidates {
        let [a, b, c] = faces[t as usize].map(|k| x[k as usize]);
        let bc = closest_on_triangle(p, a, b, c);
        let q = add(add(scale(a, bc[0]), scale(b, bc[1])), scale(c, bc[2]));
        let d = sub(q, p);
        let d2 = dot(d, d);
        if best.is_none_or(|(e, _, _)| d2 < e) {
            best = Some((d2, t, bc));
        }
    }
    best.map(|(_, t, bc)| (t, bc))
}
