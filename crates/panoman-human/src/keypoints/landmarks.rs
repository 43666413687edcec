//! The face landmarks (iBUG 300-W 68) picked on a rest mesh of the full template (module docs
//! of [`super`], "Face").

use super::surface::{
    Polyline, Surface, argmin_point, at_coord, first_local_max, first_silhouette, label_loop, lerp,
    quad_ring, sharpest_bend, split_arcs, walk_from,
};
use super::*;

/// Fraction of the alar half-width at which 31 and 35 sit.
pub const ALA_FRACTION: f64 = 0.9;

/// Quad ring (around the mouth opening) that follows the vermilion border in hm08.
pub const LIP_BORDER_RING: usize = 7;

/// Labels and face subsets of the head used by the landmark rules.
pub(super) struct HeadMesh<'a> {
    pub(super) surf: Surface<'a>,
    pub(super) template: &'a Template,
    pub(super) topo: Topology,
    pub(super) face_label: &'a [u8],
    pub(super) head: u8,
    /// Head skin faces (label `head`).
    pub(super) skin: Vec<u32>,
}

impl<'a> HeadMesh<'a> {
    pub(super) fn new(
        template: &'a Template,
        regions: &'a Regions,
        pos: &'a [V3],
    ) -> std::result::Result<HeadMesh<'a>, String> {
        let topo = Topology::build(pos.len(), &template.mesh.faces).map_err(|e| e.to_string())?;
        let head = label_id(regions, "head")?;
        let skin = (0..template.mesh.faces.len() as u32)
            .filter(|&f| regions.face_label[f as usize] == head)
            .collect();
        Ok(HeadMesh {
            surf: Surface {
                pos,
                faces: &template.mesh.faces,
            },
            template,
            topo,
            face_label: &regions.face_label,
            head,
            skin,
        })
    }

    pub(super) fn label_loop_points(
        &self,
        inner: &[u8],
    ) -> std::result::Result<(Vec<u32>, Vec<V3>), String> {
        let l = label_loop(&self.topo, self.face_label, inner, &[self.head])?;
        let p = l.iter().map(|&v| self.surf.pos[v as usize]).collect();
        Ok((l, p))
    }

    /// Section of the head skin by a plane.
    pub(super) fn section(&self, o: V3, n: V3) -> Vec<Polyline> {
        self.surf.section(&self.skin, o, n)
    }
}

pub(super) fn label_id(regions: &Regions, name: &str) -> std::result::Result<u8, String> {
    regions
        .label_names
        .iter()
        .position(|l| l == name)
        .map(|i| i as u8)
        .ok_or_else(|| format!("segmentation has no label `{name}`"))
}

/// The first skin point seen by an orthographic front camera at image position `(x, z)`:
/// the ray from 1 m in front of the face along +y.
pub(super) fn frontal_hit(h: &HeadMesh<'_>, x: f64, z: f64) -> Option<V3> {
    let (b, _) = h.surf.ray_hit([x, -1.0, z], [0.0, 1.0, 0.0], &h.skin)?;
    Some(b.eval(h.surf.pos))
}

/// Rest positions of the 68 300-W landmarks on `pos` (a rest mesh of the full template),
/// by the rules in the module docs.
pub(super) fn face_landmark_positions(
    h: &HeadMesh<'_>,
    regions: &Regions,
) -> std::result::Result<Vec<V3>, String> {
    let mut lm = vec![[f64::NAN; 3]; 68];
    let pos = h.surf.pos;

    // Eyes: the lid margins are the loops between the head skin and the eye sockets.
    let (_, eye_r) = h.label_loop_points(&[label_id(regions, "eye_cavity.R")?])?;
    let (_, eye_l) = h.label_loop_points(&[label_id(regions, "eye_cavity.L")?])?;
    let (ru, rl) = split_arcs(&eye_r);
    let (lu, ll) = split_arcs(&eye_l);
    {
        // Right eye (−x): 36 outer (smallest x) … 39 inner.
        let (o, i) = (ru[0], ru[ru.len() - 1]);
        let at = |arc: &[V3], t: f64| at_coord(arc, 0, o[0] + t * (i[0] - o[0]));
        lm[36] = o;
        lm[37] = at(&ru, 1.0 / 3.0);
        lm[38] = at(&ru, 2.0 / 3.0);
        lm[39] = i;
        lm[40] = at(&rl, 2.0 / 3.0);
        lm[41] = at(&rl, 1.0 / 3.0);
        // Left eye (+x): 42 inner (smallest x) … 45 outer.
        let (i, o) = (lu[0], lu[lu.len() - 1]);
        let at = |arc: &[V3], t: f64| at_coord(arc, 0, i[0] + t * (o[0] - i[0]));
        lm[42] = i;
        lm[43] = at(&lu, 1.0 / 3.0);
        lm[44] = at(&lu, 2.0 / 3.0);
        lm[45] = o;
        lm[46] = at(&ll, 2.0 / 3.0);
        lm[47] = at(&ll, 1.0 / 3.0);
    }
    let eye_z = (lm[36][2] + lm[39][2] + lm[42][2] + lm[45][2]) / 4.0;
    // Mouth: the opening is the loop between the skin and the mouth cavity (inner lips);
    // the vermilion border is the LIP_BORDER_RING-th quad ring around it (outer lips).
    let (mouth_loop, mouth) = h.label_loop_points(&[label_id(regions, "mouth_cavity")?])?;
    let (mu, ml) = split_arcs(&mouth);
    let (c0, c1) = (mu[0], mu[mu.len() - 1]);
    let mid_x = 0.5 * (c0[0] + c1[0]);
    lm[60] = c0;
    lm[64] = c1;
    let at = |arc: &[V3], t: f64| at_coord(arc, 0, c0[0] + t * (c1[0] - c0[0]));
    lm[61] = at(&mu, 0.25);
    lm[62] = at_coord(&mu, 0, mid_x);
    lm[63] = at(&mu, 0.75);
    lm[65] = at(&ml, 0.75);
    lm[66] = at_coord(&ml, 0, mid_x);
    lm[67] = at(&ml, 0.25);
    let head_quad = |q: usize| h.face_label[2 * q] == h.head && h.face_label[2 * q + 1] == h.head;
    let ring = quad_ring(h.template, pos, head_quad, &mouth_loop, LIP_BORDER_RING);
    if ring.len() < 8 {
        return Err(format!("lip border ring has {} vertices", ring.len()));
    }
    let (ou, ol) = split_arcs(&ring);
    let (o0, o1) = (ou[0], ou[ou.len() - 1]);
    lm[48] = o0;
    lm[54] = o1;
    // Cupid's bow: the highest points of the upper border on each side; 51 on the midline.
    let peak = |lo: f64, hi: f64| -> V3 {
        ou.iter()
            .copied()
            .filter(|p| p[0] > lo && p[0] < hi)
            .max_by(|a, b| a[2].total_cmp(&b[2]))
            .unwrap_or([f64::NAN; 3])
    };
    lm[50] = peak(o0[0], mid_x);
    lm[52] = peak(mid_x, o1[0]);
    lm[51] = at_coord(&ou, 0, mid_x);
    lm[49] = at_coord(&ou, 0, 0.5 * (o0[0] + lm[50][0]));
    lm[53] = at_coord(&ou, 0, 0.5 * (o1[0] + lm[52][0]));
    lm[57] = at_coord(&ol, 0, mid_x);
    lm[58] = at_coord(&ol, 0, lm[50][0]);
    lm[56] = at_coord(&ol, 0, lm[52][0]);
    lm[59] = at_coord(&ol, 0, lm[49][0]);
    lm[55] = at_coord(&ol, 0, lm[53][0]);
    let mouth_z = 0.5 * (lm[62][2] + lm[66][2]);
    let mouth_y = 0.5 * (lm[62][1] + lm[66][1]);

    nose(h, [mid_x, mouth_y, mouth_z], eye_z, &mut lm)?;
    jaw(h, [mid_x, mouth_y, mouth_z], eye_z, &mut lm)?;
    brows(h, (&ru, &lu), &mut lm)?;

    if let Some(k) = lm.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
        return Err(format!("face landmark {k} could not be placed"));
    }
    Ok(lm)
}

/// The nose landmarks 27–35 (module docs): the midline profile through the mouth centre's
/// x, `mouth = [x, y, z]` of the mouth centre, `eye_z` the eye corners' mean height; reads
/// the upper lip's 51, writes `lm[27..36]`.
fn nose(
    h: &HeadMesh<'_>,
    [mid_x, mouth_y, mouth_z]: V3,
    eye_z: f64,
    lm: &mut [V3],
) -> std::result::Result<(), String> {
    // Nose: the midline profile (section x = mid_x).
    let ex = [1.0, 0.0, 0.0];
    let profile = h.section([mid_x, 0.0, 0.0], ex);
    let (pi, ti) = argmin_point(
        &profile,
        |p| p[2] > mouth_z && p[2] < eye_z && p[1] < mouth_y + 0.02,
        |p| p[1],
    )
    .ok_or("no midline profile between mouth and eyes")?;
    let tip = profile[pi].pts[ti];
    lm[30] = tip;
    let up = walk_from(&profile[pi], ti, |p| p[2]);
    let nasion = up[first_local_max(&up, |p| p[1], 1e-3)];
    lm[27] = nasion;
    let bridge: Vec<V3> = up
        .iter()
        .copied()
        .take_while(|p| p[2] <= nasion[2] + 1e-12)
        .collect();
    lm[28] = at_coord(&bridge, 2, nasion[2] + (tip[2] - nasion[2]) / 3.0);
    lm[29] = at_coord(&bridge, 2, nasion[2] + 2.0 * (tip[2] - nasion[2]) / 3.0);
    // Lower nose: in vertical sections (planes x = const), walking down from the height
    // of the tip, the sharpest concave bend above the upper lip (the junction of the
    // columella or the ala with the lip).
    let lip_top = lm[51][2];
    let nose_bottom = |x: f64| -> std::result::Result<V3, String> {
        let sec = h.section([x, 0.0, 0.0], ex);
        let (a, b) = argmin_point(&sec, |p| (p[2] - tip[2]).abs() < 3e-3, |p| p[1])
            .ok_or("no section of the nose")?;
        let down = walk_from(&sec[a], b, |p| -p[2]);
        let down: Vec<V3> = down.into_iter().take_while(|p| p[2] > lip_top).collect();
        Ok(down[sharpest_bend(&down, 1.5e-3, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])])
    };
    let subnasale = nose_bottom(mid_x)?;
    lm[33] = subnasale;
    // Alae: in the horizontal section a third of the way from the subnasale up to the tip,
    // walking out from the front of the nose (at most 2.5 cm), the outer end of the
    // outermost chord steeper than 45° towards the back: the alar occluding contour seen
    // from the front.
    let z_ala = subnasale[2] + (tip[2] - subnasale[2]) / 3.0;
    let horiz = h.section([0.0, 0.0, z_ala], [0.0, 0.0, 1.0]);
    let mut ala = [0.0; 2];
    for (k, sign) in [(0usize, -1.0f64), (1, 1.0)] {
        let (a, b) = argmin_point(&horiz, |p| (p[0] - mid_x).abs() < 3e-3, |p| p[1])
            .ok_or("no section across the nose")?;
        let out: Vec<V3> = walk_from(&horiz[a], b, |p| sign * p[0])
            .into_iter()
            .take_while(|p| (p[0] - mid_x).abs() < 0.025)
            .collect();
        let steep = out
            .windows(2)
            .rposition(|w| {
                let dx = (w[1][0] - w[0][0]).abs();
                let dy = w[1][1] - w[0][1];
                dy > 0.0 && dy >= dx && dy > 1e-5
            })
            .ok_or("no alar contour")?;
        ala[k] = out[steep + 1][0];
    }
    // 31/35 at 90 % of the alar half-width; 32/34 where the frontal view ray through the
    // image midpoint of 31–33 (33–35) meets the skin first.
    lm[31] = nose_bottom(mid_x + ALA_FRACTION * (ala[0] - mid_x))?;
    lm[35] = nose_bottom(mid_x + ALA_FRACTION * (ala[1] - mid_x))?;
    for (k, a, b) in [(32usize, 31usize, 33usize), (34, 35, 33)] {
        let (x, z) = (0.5 * (lm[a][0] + lm[b][0]), 0.5 * (lm[a][2] + lm[b][2]));
        lm[k] = frontal_hit(h, x, z).ok_or("no skin in front of the nostrils")?;
    }
    Ok(())
}

/// The jaw landmarks 0–16 (module docs) about the mouth centre `centre` up to the eye
/// corners' height `eye_z`.
fn jaw(h: &HeadMesh<'_>, centre: V3, eye_z: f64, lm: &mut [V3]) -> std::result::Result<(), String> {
    // Jaw: the face's occluding contour seen from the front, traced by planes through the
    // view axis and rays from the mouth centre; 17 points at equal frontal arc length from
    // the eye-corner height on the right (0) over the chin (8) to the left (16).
    let contour = |theta: f64| -> Option<V3> {
        let r = [theta.sin(), 0.0, -theta.cos()];
        let n = [theta.cos(), 0.0, theta.sin()];
        let sec = h.section(centre, n);
        let s = |p: V3| dot(sub(p, centre), r);
        let (a, b) = argmin_point(&sec, |p| (0.028..0.034).contains(&s(p)), |p| p[1])?;
        let out = walk_from(&sec[a], b, s);
        Some(out[first_silhouette(&out, s, [0.0, 1.0, 0.0], 3e-3, 0.36, 2e-3)])
    };
    let mut sides: Vec<Vec<V3>> = Vec::new();
    for sign in [-1.0f64, 1.0] {
        let mut pts = Vec::new();
        for deg in 0..=170 {
            let Some(p) = contour(sign * (deg as f64).to_radians()) else {
                continue;
            };
            if p[2] >= eye_z {
                if let Some(&q) = pts.last() {
                    let q: V3 = q;
                    let t = (eye_z - q[2]) / (p[2] - q[2]);
                    pts.push(lerp(q, p, t));
                }
                break;
            }
            pts.push(p);
        }
        if pts.len() < 10 {
            return Err("jaw contour not found".into());
        }
        sides.push(pts);
    }
    for (side, pts) in sides.iter().enumerate() {
        let mut arc = vec![0.0];
        for w in pts.windows(2) {
            let d = [w[1][0] - w[0][0], w[1][2] - w[0][2]];
            arc.push(arc[arc.len() - 1] + (d[0] * d[0] + d[1] * d[1]).sqrt());
        }
        let total = arc[arc.len() - 1];
        for k in 0..=8 {
            let target = total * k as f64 / 8.0;
            let i = arc.partition_point(|&a| a < target).clamp(1, pts.len() - 1);
            let t = (target - arc[i - 1]) / (arc[i] - arc[i - 1]).max(1e-15);
            let p = lerp(pts[i - 1], pts[i], t.clamp(0.0, 1.0));
            let idx = if side == 0 { 8 - k } else { 8 + k };
            lm[idx] = p;
        }
    }
    Ok(())
}

/// The brow landmarks 17–26 (module docs) above the eyes (`ru`, `lu`: the upper lid arcs of
/// the right and the left eye; reads the eye corners 36, 39, 42, 45).
fn brows(
    h: &HeadMesh<'_>,
    (ru, lu): (&[V3], &[V3]),
    lm: &mut [V3],
) -> std::result::Result<(), String> {
    let ex = [1.0, 0.0, 0.0];
    // Brows: vertical sections above the eyes; walking up from the upper lid (or the eye
    // corner's height beyond the corners), the sharpest convex bend (the superior orbital
    // rim, where the lid sulcus turns into the forehead) within 4 cm, measured over ±4 mm.
    let brow = |x: f64, z0: f64| -> std::result::Result<V3, String> {
        let sec = h.section([x, 0.0, 0.0], ex);
        let (a, b) = argmin_point(&sec, |p| (p[2] - z0).abs() < 3e-3, |p| p[1])
            .ok_or("no section above the eye")?;
        let up: Vec<V3> = walk_from(&sec[a], b, |p| p[2])
            .into_iter()
            .take_while(|p| p[2] < z0 + 0.04)
            .collect();
        Ok(up[sharpest_bend(&up, 4e-3, [0.0, 0.0, 1.0], [0.0, -1.0, 0.0])])
    };
    for (first, o, i, upper) in [(17usize, lm[36], lm[39], ru), (22, lm[45], lm[42], lu)] {
        let w = i[0] - o[0];
        // Outer end a third of an eye width beyond the outer corner, inner end a tenth
        // inside the inner corner.
        let xs: Vec<f64> = (0..5)
            .map(|k| {
                let t = k as f64 / 4.0;
                let (xo, xi) = (o[0] - w / 3.0, i[0] + w / 10.0);
                xo + t * (xi - xo)
            })
            .collect();
        for (k, &x) in xs.iter().enumerate() {
            let inside = (x - o[0]) * (x - i[0]) < 0.0;
            let z0 = if inside {
                at_coord(upper, 0, x)[2]
            } else {
                o[2]
            };
            let p = brow(x, z0)?;
            // 17..21 run outer → inner on the right; 22..26 inner → outer on the left.
            let idx = if first == 17 { 17 + k } else { 26 - k };
            lm[idx] = p;
        }
    }
    Ok(())
}

/// The 68 iBUG 300-W landmarks as surface points of the head skin, picked on `rest` (a rest
/// mesh of the full template; the module docs give the rules).
///
/// # Errors
/// One line if a rule finds no answer (e.g. a mesh without eye or mouth openings).
pub fn face_landmarks(template: &Template, regions: &Regions, rest: &[V3]) -> Result<Vec<Binding>> {
    face_landmarks_msg(template, regions, rest).map_err(HumanError::Invalid)
}

/// [`face_landmarks`] with the message as a `String`.
pub(super) fn face_landmarks_msg(
    template: &Template,
    regions: &Regions,
    rest: &[V3],
) -> std::result::Result<Vec<Binding>, String> {
    let h = HeadMesh::new(template, regions, rest)?;
    let lm = face_landmark_positions(&h, regions)?;
    Ok(lm.iter().map(|&p| h.surf.closest(p, &h.skin).0).collect())
}
