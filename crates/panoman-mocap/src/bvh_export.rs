//! The rig's skeletal motion as BVH (`panoman mocap export`): one joint per rig bone, at the
//! bone's rest head, with identity rest orientations, so that each joint's world rotation
//! is the bone's skinning rotation `T_c` and its world position the posed bone head.
//!
//! Units: metres (offsets and root positions); rotations in degrees with channels
//! `Zrotation Yrotation Xrotation` (`R = Rz·Ry·Rx`), the root also `Xposition Yposition
//! Zposition`. Leaf bones carry their tail as `End Site`.
use panoman_human::generator::Identity;
use panoman_human::params::PoseParams;
use panoman_mesh::geom::{V3, matmul, sub, transpose};

use crate::bvh::{Bvh, BvhJoint, Channel};
use crate::error::{MocapError, Result};
use panoman_mesh::rotation::euler_xyz_deg_of;

/// The BVH of `poses` of `identity` (see the module docs), `frame_time_s` seconds apart.
///
/// # Errors
/// [`MocapError::Invalid`]: no poses, a non-positive frame time, a pose that does not fit
/// the rig, or a rig whose bones are not ordered parents first.
pub fn rig_motion_bvh(identity: &Identity, poses: &[PoseParams], frame_time_s: f64) -> Result<Bvh> {
    let inv = |what: String| MocapError::Invalid { what };
    if poses.is_empty() {
        return Err(inv("no poses to export".into()));
    }
    if !(frame_time_s > 0.0 && frame_time_s.is_finite()) {
        return Err(inv(format!("frame time {frame_time_s} s must be > 0")));
    }
    let g = identity.generator();
    let names = g.bone_names();
    let parents = g.bone_parents();
    let heads = identity.bone_heads();
    let tails = identity.bone_tails();
    let mut joints = Vec::with_capacity(names.len());
    for (c, name) in names.iter().enumerate() {
        if parents[c].is_some_and(|p| p >= c) {
            return Err(inv(format!("rig bone `{name}` comes before its parent")));
        }
        let has_child = parents.contains(&Some(c));
        let rot = vec![Channel::Zrotation, Channel::Yrotation, Channel::Xrotation];
        let (offset, channels) = match parents[c] {
            None => (
                [0.0; 3],
                [
                    vec![Channel::Xposition, Channel::Yposition, Channel::Zposition],
                    rot,
                ]
                .concat(),
            ),
            Some(p) => (sub(heads[c], heads[p]), rot),
        };
        joints.push(BvhJoint {
            name: name.clone(),
            parent: parents[c],
            offset,
            channels,
            end_site: (!has_child).then(|| sub(tails[c], heads[c])),
        });
    }
    let mut motion = Vec::with_capacity(poses.len() * (3 + 3 * names.len()));
    for (f, pose) in poses.iter().enumerate() {
        pose.validate(names)
            .map_err(|e| inv(format!("pose {f}: {e}")))?;
        let posed = identity.pose(pose);
        for (c, parent) in parents.iter().enumerate() {
            let q = posed.skin[c].m;
            let local = match *parent {
                None => {
                    motion.extend_from_slice(&posed.bone_heads[c]);
                    q
                }
                Some(p) => matmul(&transpose(&posed.skin[p].m), &q),
            };
            let [x, y, z] = euler_xyz_deg_of(&local);
            motion.extend_from_slice(&[z, y, x]);
        }
    }
    Ok(Bvh {
        joints,
        frame_time_s,
        motion,
    })
}

/// The posed bone heads of `pose` (metres), in rig order: what the BVH's joints reproduce.
pub fn posed_bone_heads(identity: &Identity, pose: &PoseParams) -> Vec<V3> {
    identity.pose(pose).bone_heads
}
