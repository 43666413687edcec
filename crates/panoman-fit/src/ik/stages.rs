/// TC-127 indices of the torso keypoints: neck, body_center, shoulders, hips.
pub(super) const TORSO_KEYPOINTS: [usize; 6] = [0, 2, 3, 6, 9, 12];

/// Bones of the `torso` stage.
pub(super) const TORSO_BONES: [&str; 9] = [
    "spine05",
    "spine04",
    "spine03",
    "spine02",
    "spine01",
    "clavicle.L",
    "clavicle.R",
    "shoulder01.L",
    "shoulder01.R",
];

/// Hand keypoints used by the `body` stage (wrist, thumb CMC, the four MCPs).
pub(super) const HAND_ROOTS: [usize; 6] = [0, 1, 5, 9, 13, 17];

/// Face keypoints used by the `body` stage (nose bridge, tip and base, eye corners, pupils).
pub(super) const FACE_RIGID: [usize; 9] = [27, 30, 33, 36, 39, 42, 45, 68, 69];
