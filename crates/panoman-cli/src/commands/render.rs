//! `panoman render`: meshes side by side (shared scale) with optional keypoints, as a PNG.

use crate::render::{PALETTE, Rgb, Scene, View};
use anyhow::{Result, anyhow, bail};
use clap::Args;
use panoman_human::keypoints::{KeypointGroup as Group, keypoint_index};
use panoman_mesh::geom::{MAX_COORDINATE, is_in_bounds};
use panoman_mesh::io;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `panoman render`.
///
/// Example: `panoman render posed.obj fitted.obj --out cmp.png --view side` draws both meshes
/// side by side at one scale; `panoman render M.obj --keypoints K.json --out kp.png` adds the
/// keypoints of K.json as dots (body red, face green, left hand blue, right hand orange).
#[derive(Args, Debug)]
#[command(after_help = "Examples:\n  \
    panoman render posed.obj fitted.obj --out cmp.png --view side\n  \
    panoman render M.obj --keypoints K.json --out kp.png --width 800 --height 800\n\n\
    K.json: {\"units\": \"m\", \"keypoints\": {\"neck\": [x, y, z], \"face_30\": [x, y, z], ...}}\n\
    Keypoint colours: body red, feet purple, face green, left hand blue, right hand orange.")]
pub struct RenderArgs {
    /// Meshes to draw (.obj or .ply), left to right.
    #[arg(required = true)]
    pub meshes: Vec<PathBuf>,
    /// Output image (.png).
    #[arg(long)]
    pub out: PathBuf,
    /// Camera: `front` (looking at the character's front), `side` (its left profile) or `back`.
    #[arg(long, default_value = "front")]
    pub view: View,
    /// Keypoint files (`{"units": "m", "keypoints": {"neck": [x, y, z], …}}`), one per mesh in
    /// order; drawn on top of the corresponding mesh.
    #[arg(long, num_args = 1..)]
    pub keypoints: Vec<PathBuf>,
    /// Image width in pixels (default: 560 per mesh).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels.
    #[arg(long, default_value_t = 800)]
    pub height: u32,
}

/// Dot colour and radius (pixels) of a keypoint group.
fn style(g: Group) -> (Rgb, f64) {
    match g {
        Group::Body => ([220, 40, 40], 4.5),
        Group::Feet => ([150, 40, 190], 4.0),
        Group::Face => ([30, 150, 60], 2.0),
        Group::LeftHand => ([40, 90, 225], 2.5),
        Group::RightHand => ([240, 140, 0], 2.5),
    }
}

/// The group of a TC-133 keypoint name (the layout of `panoman_human::keypoints`), `None`
/// for an unknown name.
fn group_of(name: &str) -> Option<Group> {
    Some(Group::of(keypoint_index(name)?))
}

/// Reads a keypoint file: points grouped for drawing.
fn read_keypoints(path: &Path) -> Result<Vec<(Group, [f64; 3])>> {
    let err = |what: String| anyhow!("{}: {what}", path.display());
    let text = std::fs::read_to_string(path).map_err(|e| err(e.to_string()))?;
    let json: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| err(format!("invalid JSON: {e}")))?;
    let obj = json
        .as_object()
        .ok_or_else(|| err("expected a JSON object".into()))?;
    for key in obj.keys() {
        if !["units", "keypoints", "weights"].contains(&key.as_str()) {
            return Err(err(format!(
                "unknown key `{key}` (expected units, keypoints, weights)"
            )));
        }
    }
    if let Some(u) = obj.get("units")
        && u.as_str() != Some("m")
    {
        return Err(err(format!("units must be \"m\", found {u}")));
    }
    let kps = obj
        .get("keypoints")
        .and_then(|k| k.as_object())
        .ok_or_else(|| err("missing object `keypoints`".into()))?;
    let mut out = Vec::with_capacity(kps.len());
    for (name, v) in kps {
        let g = group_of(name).ok_or_else(|| err(format!("unknown keypoint `{name}`")))?;
        let p: Vec<f64> = v
            .as_array()
            .filter(|a| a.len() == 3)
            .map(|a| a.iter().filter_map(|x| x.as_f64()).collect())
            .unwrap_or_default();
        if p.len() != 3 || !is_in_bounds([p[0], p[1], p[2]]) {
            return Err(err(format!(
                "keypoint `{name}` must be [x, y, z] with finite numbers, found {v}"
            )));
        }
        out.push((g, [p[0], p[1], p[2]]));
    }
    Ok(out)
}

/// Runs `panoman render`.
pub fn run(a: RenderArgs) -> Result<()> {
    if a.keypoints.len() > a.meshes.len() {
        bail!(
            "{}: {} keypoint files for {} meshes (one per mesh at most)",
            a.keypoints[a.meshes.len()].display(),
            a.keypoints.len(),
            a.meshes.len()
        );
    }
    if a.height == 0 || a.height > 16384 || a.width.is_some_and(|w| w == 0 || w > 16384) {
        bail!(
            "{}: image size must be 1..=16384 pixels per side",
            a.out.display()
        );
    }
    crate::render::check_png_path(&a.out)?;
    let meshes = a
        .meshes
        .iter()
        .map(|p| {
            let m = io::read_mesh(p)?;
            m.check_basic()
                .map_err(|e| anyhow!("{}: {e}", p.display()))?;
            if let Some(i) = m.positions.iter().position(|q| !is_in_bounds(*q)) {
                bail!(
                    "{}: vertex {i} at {:?} is out of bounds (|coordinate| > {MAX_COORDINATE} m; \
                     meshes are in metres): nothing sensible to render",
                    p.display(),
                    m.positions[i]
                );
            }
            Ok(m)
        })
        .collect::<Result<Vec<_>>>()?;
    let keypoints = a
        .keypoints
        .iter()
        .map(|p| read_keypoints(p))
        .collect::<Result<Vec<_>>>()?;
    let width = a.width.unwrap_or(560 * a.meshes.len().min(8) as u32);
    let t = Instant::now();
    let mut scene = Scene::new(width, a.height);
    for (i, m) in meshes.iter().enumerate() {
        scene.add_mesh(m, PALETTE[i % PALETTE.len()]);
        if let Some(kps) = keypoints.get(i) {
            for g in Group::ALL {
                let pts: Vec<[f64; 3]> = kps
                    .iter()
                    .filter(|(h, _)| *h == g)
                    .map(|(_, p)| *p)
                    .collect();
                if !pts.is_empty() {
                    let (color, radius) = style(g);
                    scene.add_points(&pts, color, radius);
                }
            }
        }
    }
    let img = scene.render(a.view);
    let render_ms = t.elapsed().as_secs_f64() * 1e3;
    img.save_png(&a.out)?;
    println!(
        "{}: {}×{} px, {} mesh{}, {} view, rendered in {:.0} ms",
        a.out.display(),
        img.width,
        img.height,
        meshes.len(),
        if meshes.len() == 1 { "" } else { "es" },
        a.view,
        render_ms
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keypoint_groups() {
        assert_eq!(group_of("neck"), Some(Group::Body));
        assert_eq!(group_of("l_heel"), Some(Group::Feet));
        assert_eq!(group_of("face_69"), Some(Group::Face));
        assert_eq!(group_of("face_70"), None);
        assert_eq!(group_of("lhand_00"), Some(Group::LeftHand));
        assert_eq!(group_of("rhand_20"), Some(Group::RightHand));
        assert_eq!(group_of("rhand_2"), None);
        assert_eq!(group_of("elbow"), None);
    }
}
