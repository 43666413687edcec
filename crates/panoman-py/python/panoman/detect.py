"""Offline 2D keypoint detector: videos (or image folders), one per camera, → OpenPose JSON.

Usage (the detector's own environment, ``scripts/detect-setup.sh`` → ``target/detect``)::

    target/detect/bin/python crates/panoman-py/python/panoman/detect.py \\
        --videos DIR --out DIR [--frames N] [--start K] [--every S] \\
        [--masks] [--mask-scale 0.25] [--cameras cam01,cam02] [--roi roi.json]

    # overlay mode: composite a fitted mesh's silhouettes and keypoints over the videos
    target/detect/bin/python crates/panoman-py/python/panoman/detect.py \\
        --overlay DIR --videos DIR [--video-scale 0.5] [--cameras cam01,cam02]

or ``python -m panoman.detect ...`` where the package is installed. This file is
self-contained: it imports nothing from ``panoman`` (the Rust CLI embeds it and runs it as a
plain script), and numpy, OpenCV and mediapipe are imported inside the functions that use
them, so ``import panoman.detect`` works without them (the table and mapping functions too).

**Detector.** The pinned detector is ``mediapipe==0.10.14`` (PyPI wheel, Apache-2.0), its
Holistic solution with ``model_complexity=1``, ``static_image_mode=False`` (video tracking:
the same person is kept over time when a bystander is visible), ``smooth_landmarks=True``,
``refine_face_landmarks=True`` (iris centres) and ``enable_segmentation`` with ``--masks``.
That release carries the Holistic models inside the wheel, so it runs offline; later
mediapipe releases download models at run time and cannot. ``model_complexity=1`` is the one
pose model in the wheel: 0 (lite) and 2 (heavy) are downloaded from storage.googleapis.com on
first use and fail offline. mediapipe 0.10.14 predates numpy 2 and needs
opencv-contrib-python and protobuf < 5, hence its own virtual environment
(``scripts/detect-setup.sh`` pins numpy 1.26.4 and the rest).

Holistic follows one person: the one its pose detector picks in the first frame (then
tracked). That need not be the subject: with two people in view, cameras can follow
different people. Check the output (or the masks) for scenes with bystanders, and detect
such a camera again with ``--roi``.

**Regions of interest** (``--roi FILE``): only inside a box per frame, to make Holistic follow
the person in it. ``FILE`` (JSON)::

    {"cameras": {"cam03": {"boxes": {"0": [x0, y0, x1, y1], "1": [...], ...}}, ...}}

gives per camera and frame (the source's own 0-based frame number, as in the output's file
names) a box in full-resolution pixels (``x0 ≤ x1``, ``y0 ≤ y1``; it may reach outside the
image). Only the cameras named in ``FILE`` are detected (``--cameras`` restricts them
further; a name not in ``FILE`` is an error); frames are selected as without it. A selected
frame with a box: the box is enlarged by 25 % of its width / height on each side
(:data:`ROI_MARGIN`), clamped to the image and rounded outwards to whole pixels
(:func:`roi_crop`); that crop is pasted, unscaled, at the centre of a black canvas of a fixed
size per camera, the largest crop width × the largest crop height among the camera's boxes
(:func:`roi_canvas`, :func:`roi_offset`), so that the one Holistic instance per camera (video
mode, as without ``--roi``) always sees images of one size at the full resolution. Every
landmark (body, hands, face) is mapped back to full-image pixels (:func:`roi_point`: a pure
translation); a point outside the crop (in the padding) is not found, ``0 0 0``. The mask:
the canvas's segmentation inside the crop pasted into a full-size zero mask, then
``--mask-scale`` as without ``--roi``. A frame without a box, or whose enlarged box lies
entirely outside the image: nothing is detected, ``"people": []`` and an all-zero mask.
``--out`` is handled as without ``--roi`` (a new folder, or an earlier output, which is replaced
as a whole: to redo one camera of a detection folder, write into a new folder and move the
camera's sub-folder over).

**Input.** ``--videos DIR`` holds one video per camera (``*.mp4``, ``*.avi``, ``*.mov``; the
camera name is the file's stem) and/or one sub-folder of images per camera (``*.png``,
``*.jpg``, ``*.jpeg``, in sorted order; the camera name is the folder's name; folders without
images are ignored). Frames ``K, K+S, K+2S, …`` are detected (``--start K``, ``--every S``),
at most ``N`` per camera (``--frames N``); frame numbers are those of the source (0-based).

**Output** (``--out DIR``, written atomically: built in a hidden sibling folder and renamed
into place at the end; an existing ``DIR`` is replaced only if it is empty or an earlier
output, i.e. holds ``detections.json``):

* ``DIR/<cam>/<cam>_<frame:012d>_keypoints.json``: OpenPose JSON, ``{"version": 1.3,
  "people": [{"person_id": [-1], "pose_keypoints_2d": [75], "face_keypoints_2d": [210],
  "hand_left_keypoints_2d": [63], "hand_right_keypoints_2d": [63]}]}``: ``x y c`` triples,
  pixels of the full image (x right, y down). A point not found, or outside the image, is
  ``0 0 0``; a group not found is an empty list; a frame where nothing is found has
  ``"people": []``. At most one person (Holistic tracks one).
* with ``--masks``: ``DIR/<cam>/<cam>_<frame:012d>_mask.png``, 8-bit grey: the person
  segmentation probability resized by ``--mask-scale`` (area interpolation) and thresholded at
  0.5 → 0 / 255 (all 0 when no person is found).
* ``DIR/detections.json``: the detector, per camera its ``name``, ``source`` (absolute path),
  ``frames`` (written), ``fps`` (of the source; ``null`` for images), ``width``, ``height``
  and the number of frames where the body, left hand, right hand and face were found;
  ``seconds_per_frame`` (wall time, decoding and writing included, over all cameras) and
  ``mask_scale`` (``null`` without ``--masks``). With ``--roi``, each camera also has ``roi``
  (the ``FILE``'s absolute path), ``roi_frames`` (the written frames that had a box inside the
  image) and ``roi_canvas`` (``[width, height]`` of Holistic's input; ``null`` when no box).

Errors (a missing folder, no cameras, an unknown ``--cameras`` name, a video or image that
cannot be decoded, zero frames, an image of another size than the camera's first, a missing or
malformed ``--roi`` file, a camera of it without a video): one message on stderr naming the
file, exit status 2, nothing left behind.

**Overlay mode** (``--overlay DIR``; no detection, mediapipe is not imported: numpy and
OpenCV only). ``DIR/overlays.json`` (written by ``panoman capture``) lists per camera the frames
to composite::

    {"scale": 0.25, "fps": 60.0, "cameras": [{"name": "cam01", "frames": [
        {"index": 0, "frame": 4, "silhouette": "cam01/silhouette_0000.png",
         "detections": [[x, y], ...], "model": [[x, y], ...]}, ...]}, ...]}

``frame`` is the camera's own video frame (0-based; decoded in order, never seeked) or the
image's index in its folder; ``silhouette`` (relative to ``DIR``) an 8-bit grey PNG, 255
inside the projected mesh, on a grid of ``scale`` × the full image (resized to the output
with linear interpolation, thresholded at 128; a size that does not match ``scale`` × the
video's is warned about); ``detections`` (the detected 2D keypoints) and ``model`` (the fitted
mesh's keypoints projected) are full-resolution pixels (a point with a ``null`` or
non-finite coordinate is skipped). ``--videos DIR`` holds the cameras' videos (``*.mp4``,
``*.avi``, ``*.mov``, ``*.mkv``) or image folders as for detection; ``--cameras`` restricts
the cameras. Each listed frame is resized by ``--video-scale`` (default 0.5, area
interpolation), the silhouette blended in blue at 45 % opacity with a 1-pixel dark-blue
outline along its edge, detections drawn as green and model keypoints as red filled dots
(radius 3 px at scale 0.5, ``max(2, round(6 × scale))``). Written, each file atomically
(a temporary name, then renamed; earlier files of the same name are replaced):

* ``DIR/<cam>/video_<index:04d>.png``: the composite of each listed frame;
* ``DIR/<cam>.mp4``: the listed frames in their listed order, ``mp4v`` (MPEG-4 part 2) at the
  json's ``fps`` (the width and height rounded down to even numbers); a camera without
  listed frames gets neither.

Errors (no ``overlays.json`` or a malformed one, a camera without a video, a listed frame past
the end of the video, a missing or undecodable silhouette, a video writer that cannot be
opened): one message on stderr naming the file, exit status 2 (files already written stay).

**Body: MediaPipe Pose (33 landmarks) → OpenPose BODY_25** (:data:`BODY25_FROM_MEDIAPIPE`).
Image-normalised ``x, y`` are multiplied by the width and height; the confidence is the
landmark's ``visibility`` clipped to [0, 1]. Left and right are the person's, in both.

=====  ==========  ==========================================================
BODY_25             MediaPipe Pose
=====  ==========  ==========================================================
0      Nose        0 nose
1      Neck        midpoint of 11 and 12 (shoulders); confidence the lower one
2–4    RShoulder…  12, 14, 16 (right shoulder, elbow, wrist)
5–7    LShoulder…  11, 13, 15 (left shoulder, elbow, wrist)
8      MidHip      midpoint of 23 and 24 (hips); confidence the lower one
9–11   RHip…       24, 26, 28 (right hip, knee, ankle)
12–14  LHip…       23, 25, 27 (left hip, knee, ankle)
15–18  REye…       5 right eye, 2 left eye, 8 right ear, 7 left ear
19     LBigToe     31 left foot index (the foot's tip, near the second toe)
20     LSmallToe   absent (``0 0 0``): MediaPipe has no little-toe point
21     LHeel       29 left heel
22–24  RBigToe…    32 right foot index, absent, 30 right heel
=====  ==========  ==========================================================

Joint centres and surface points: MediaPipe's shoulders, elbows, wrists, knees and ankles
are, as OpenPose's, approximately the joints' centres as seen in the image. Its hips are not
the hip joint centres: they lie towards the lateral surface of the pelvis
(``docs/formats-interchange.md``). Two points are formed here, not detected: the Neck is the
midpoint of the shoulders and MidHip the midpoint of the hips (a pelvis centre between the
two hip points), each with the lower of the two confidences. Nose, eyes and ears are surface
points; so are the foot points: the heel is the back of the heel, the foot index the tip of
the foot near the second toe (a little lateral of OpenPose's big toe).

**Hands** (21 points, the same order as OpenPose's: 0 wrist, thumb 1–4, index 5–8, middle
9–12, ring 13–16, little 17–20): Holistic's ``left_hand_landmarks`` (the person's left hand,
found from the pose's left wrist) → ``hand_left_keypoints_2d``, right → right. Hand landmarks
have no visibility: confidence 1 when the hand is found, 0 for a point outside the image.

**Face** (70 points: the 68 iBUG 300-W landmarks, 68 right pupil, 69 left pupil):
:data:`FACE70_FROM_MEDIAPIPE` picks one of FaceMesh's 478 points (468 mesh + 10 iris points
of ``refine_face_landmarks``) for each. Confidence 1 when the face is found (0 outside the
image). See the table's comments for how each group was chosen and which points are rough.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import tempfile
import time

__all__ = [
    "DETECTOR",
    "BODY25_FROM_MEDIAPIPE",
    "FACE70_FROM_MEDIAPIPE",
    "body25",
    "hand21",
    "face70",
    "person",
    "ROI_MARGIN",
    "roi_crop",
    "roi_canvas",
    "roi_offset",
    "roi_point",
    "roi_landmarks",
    "roi_results",
    "DetectError",
    "detect",
    "overlay",
    "parser",
    "main",
]

DETECTOR = "mediapipe 0.10.14 holistic model_complexity=1"

VIDEO_EXTENSIONS = (".mp4", ".avi", ".mov")
OVERLAY_VIDEO_EXTENSIONS = VIDEO_EXTENSIONS + (".mkv",)
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg")

# BODY_25 index → MediaPipe Pose landmark: an index, a pair (midpoint, lower confidence) or
# None (absent). See the module docstring.
BODY25_FROM_MEDIAPIPE = (
    0,  # 0 Nose ← nose
    (11, 12),  # 1 Neck ← midpoint of the shoulders
    12,  # 2 RShoulder ← right shoulder
    14,  # 3 RElbow ← right elbow
    16,  # 4 RWrist ← right wrist
    11,  # 5 LShoulder ← left shoulder
    13,  # 6 LElbow ← left elbow
    15,  # 7 LWrist ← left wrist
    (23, 24),  # 8 MidHip ← midpoint of the hips
    24,  # 9 RHip ← right hip
    26,  # 10 RKnee ← right knee
    28,  # 11 RAnkle ← right ankle
    23,  # 12 LHip ← left hip
    25,  # 13 LKnee ← left knee
    27,  # 14 LAnkle ← left ankle
    5,  # 15 REye ← right eye
    2,  # 16 LEye ← left eye
    8,  # 17 REar ← right ear
    7,  # 18 LEar ← left ear
    31,  # 19 LBigToe ← left foot index
    None,  # 20 LSmallToe: no MediaPipe point
    29,  # 21 LHeel ← left heel
    32,  # 22 RBigToe ← right foot index
    None,  # 23 RSmallToe: no MediaPipe point
    30,  # 24 RHeel ← right heel
)

# OpenPose face index (iBUG 300-W 68 + 2 pupils) → MediaPipe FaceMesh index.
#
# "Right"/"left" are the person's. FaceMesh's right side (mediapipe's FACEMESH_RIGHT_EYE:
# 33…133, FACEMESH_RIGHT_IRIS: 469–472 around the centre 468) is the person's right: negative
# x in mediapipe's canonical face model (+x is the person's left there), and on a frontal
# photograph 468 lies on the eye Pose calls the right one (Pose landmark 5, within 3 px).
# The table is mirror-symmetric (each right index ↔ its mirrored left index). It follows the
# commonly used MediaPipe → dlib-68 correspondences, with each 300-W point set to the FaceMesh
# vertex of the same contour (mediapipe's FACEMESH_FACE_OVAL / _EYEBROW / _EYE / _LIPS paths)
# nearest to where 300-W spaces it, measured on the canonical face model; checked by drawing
# the 70 points on a frontal photograph. Points known to be rough:
# * jaw 0–16: FaceMesh points are fixed on the head, 300-W's jaw points follow the visible
#   outline; on a turned head the far side's points (and 0–2 / 14–16, which are near the
#   ears) are behind the outline. 3–7 / 9–13 are at about equal arc length (±half a step:
#   the oval has 11 vertices from 127 to the chin, 300-W 8).
# * brows 17–26: FaceMesh's upper brow contour (as 300-W annotates the brows' upper edge).
# * nose 27–30: 27 is 168 (between the eyes, just above the eye corners), 30 the nose tip 4
#   (the most protruding vertex; 1, a little lower, is sometimes used instead); 28 / 29 are
#   the midline vertices nearest to equal spacing (197, 195). 31 / 35 are the nostrils'
#   lateral lower edges (98 / 327), 32 / 34 between them and the subnasale 2.
# * eyes 36–47: the eye corners and the lid vertices at one and two thirds of each lid.
# * lips 48–67: the corners 61 / 291 (outer) and 78 / 308 (inner), the centre line 0, 17, 13,
#   14; 50 / 52 are the cupid's bow peaks 37 / 267; 49 / 53 (40 / 270; 39 / 269 in other
#   tables), 55 / 56 / 58 / 59 at a third of the outer lips' arc length, the inner 61 / 63 /
#   65 / 67 at half the inner lips' (81 / 311 / 402 / 178; 82 / 312 / 317 / 87 elsewhere).
FACE68_FROM_MEDIAPIPE = (
    # jaw 0–16, from the person's right (near the right ear) over the chin (8) to the left
    127, 234, 93, 132, 58, 136, 149, 176, 152, 400, 378, 365, 288, 361, 323, 454, 356,
    # right brow 17–21 (outer → inner), left brow 22–26 (inner → outer)
    70, 63, 105, 66, 107, 336, 296, 334, 293, 300,
    # nose bridge 27–30 (top → tip), nostrils' lower edge 31–35 (right → left, 33 subnasale)
    168, 197, 195, 4, 98, 97, 2, 326, 327,
    # right eye 36–41: outer corner, upper lid outer / inner, inner corner, lower inner / outer
    33, 160, 158, 133, 153, 144,
    # left eye 42–47: inner corner, upper lid inner / outer, outer corner, lower outer / inner
    362, 385, 387, 263, 373, 380,
    # outer lips 48–59: right corner, upper (49–53, 51 centre), left corner, lower (55–59)
    61, 40, 37, 0, 267, 270, 291, 321, 314, 17, 84, 91,
    # inner lips 60–67: right corner, upper (61–63), left corner, lower (65–67)
    78, 81, 13, 311, 308, 402, 14, 178,
)
# 68 right pupil ← 468 (centre of the right iris), 69 left pupil ← 473 (left iris centre);
# both exist only with refine_face_landmarks=True (478 points).
FACE70_FROM_MEDIAPIPE = FACE68_FROM_MEDIAPIPE + (468, 473)


def _landmarks(landmarks):
    """The sequence of a ``NormalizedLandmarkList`` (``.landmark``), or ``landmarks`` itself."""
    return getattr(landmarks, "landmark", landmarks)


def _triple(x, y, c, width, height):
    """``[x·w, y·h, c]`` of an image-normalised point; ``[0, 0, 0]`` when ``c`` is 0 or the
    point is outside the image."""
    px, py = x * width, y * height
    if not (c > 0.0 and 0.0 <= px <= width and 0.0 <= py <= height):
        return [0.0, 0.0, 0.0]
    return [round(px, 3), round(py, 3), round(c, 4)]


def _visibility(landmark):
    v = float(getattr(landmark, "visibility", 1.0))
    return min(max(v, 0.0), 1.0) if math.isfinite(v) else 0.0


def body25(landmarks, width, height):
    """OpenPose BODY_25 ``pose_keypoints_2d`` (75 floats) of MediaPipe Pose's 33 landmarks
    (objects with ``x``, ``y``, ``visibility``, or a ``NormalizedLandmarkList``); ``[]`` when
    ``landmarks`` is ``None``."""
    if landmarks is None:
        return []
    lms = _landmarks(landmarks)
    if len(lms) != 33:
        raise ValueError(f"MediaPipe Pose has 33 landmarks, got {len(lms)}")
    out = []
    for src in BODY25_FROM_MEDIAPIPE:
        if src is None:
            out += [0.0, 0.0, 0.0]
        elif isinstance(src, tuple):
            a, b = lms[src[0]], lms[src[1]]
            c = min(_visibility(a), _visibility(b))
            out += _triple((a.x + b.x) / 2, (a.y + b.y) / 2, c, width, height)
        else:
            lm = lms[src]
            out += _triple(lm.x, lm.y, _visibility(lm), width, height)
    return out


def hand21(landmarks, width, height):
    """OpenPose ``hand_*_keypoints_2d`` (63 floats) of a MediaPipe hand's 21 landmarks (the same
    order), confidence 1; ``[]`` when ``landmarks`` is ``None``."""
    if landmarks is None:
        return []
    lms = _landmarks(landmarks)
    if len(lms) != 21:
        raise ValueError(f"a MediaPipe hand has 21 landmarks, got {len(lms)}")
    out = []
    for lm in lms:
        out += _triple(lm.x, lm.y, 1.0, width, height)
    return out


def face70(landmarks, width, height):
    """OpenPose ``face_keypoints_2d`` (210 floats) of MediaPipe FaceMesh's 478 landmarks
    (:data:`FACE70_FROM_MEDIAPIPE`), confidence 1; with 468 (no iris refinement) the pupils
    are ``0 0 0``; ``[]`` when ``landmarks`` is ``None``."""
    if landmarks is None:
        return []
    lms = _landmarks(landmarks)
    if len(lms) not in (468, 478):
        raise ValueError(f"MediaPipe FaceMesh has 468 or 478 landmarks, got {len(lms)}")
    out = []
    for src in FACE70_FROM_MEDIAPIPE:
        if src < len(lms):
            out += _triple(lms[src].x, lms[src].y, 1.0, width, height)
        else:
            out += [0.0, 0.0, 0.0]
    return out


def person(results, width, height):
    """The OpenPose ``people`` list (one person or none) of a Holistic result (an object with
    ``pose_landmarks``, ``face_landmarks``, ``left_hand_landmarks``, ``right_hand_landmarks``,
    each ``None`` when not found)."""
    groups = {
        "pose_keypoints_2d": body25(getattr(results, "pose_landmarks", None), width, height),
        "face_keypoints_2d": face70(getattr(results, "face_landmarks", None), width, height),
        "hand_left_keypoints_2d": hand21(
            getattr(results, "left_hand_landmarks", None), width, height
        ),
        "hand_right_keypoints_2d": hand21(
            getattr(results, "right_hand_landmarks", None), width, height
        ),
    }
    if not any(groups.values()):
        return []
    return [{"person_id": [-1], **groups}]


# ---------------------------------------------------------------------------------------
# Regions of interest (--roi): Holistic on a crop around a box, mapped back to the image

ROI_MARGIN = 0.25  # the box is enlarged by this fraction of its width / height on each side


def roi_crop(box, width, height, margin=ROI_MARGIN):
    """The crop ``(x0, y0, x1, y1)`` (whole pixels, ``x0 ≤ x < x1``) of a box ``[x0, y0, x1,
    y1]`` (full-image pixels) in a ``width`` × ``height`` image: the box enlarged by ``margin``
    × its width / height on each side, rounded outwards and clamped to the image; ``None``
    when nothing of it is inside the image."""
    bx0, by0, bx1, by1 = (float(v) for v in box)
    mx, my = margin * (bx1 - bx0), margin * (by1 - by0)
    x0 = max(0, math.floor(bx0 - mx))
    y0 = max(0, math.floor(by0 - my))
    x1 = min(int(width), math.ceil(bx1 + mx))
    y1 = min(int(height), math.ceil(by1 + my))
    if x1 <= x0 or y1 <= y0:
        return None
    return (x0, y0, x1, y1)


def roi_canvas(crops):
    """The fixed size ``(width, height)`` of Holistic's input for a camera's crops: the largest
    crop width and the largest crop height (``None`` without crops)."""
    crops = [c for c in crops if c is not None]
    if not crops:
        return None
    return (max(c[2] - c[0] for c in crops), max(c[3] - c[1] for c in crops))


def roi_offset(crop, canvas):
    """Where the crop's top-left pixel lies on the canvas: centred, whole pixels."""
    return ((canvas[0] - (crop[2] - crop[0])) // 2, (canvas[1] - (crop[3] - crop[1])) // 2)


def roi_point(x, y, crop, canvas):
    """Full-image pixels ``(x, y)`` of a point at canvas-normalised ``x, y`` (mediapipe's
    landmark coordinates on the canvas); ``None`` when it is outside the crop (in the padding)
    or not finite."""
    ox, oy = roi_offset(crop, canvas)
    cx, cy = x * canvas[0] - ox, y * canvas[1] - oy
    if not (0.0 <= cx <= crop[2] - crop[0] and 0.0 <= cy <= crop[3] - crop[1]):
        return None
    return (crop[0] + cx, crop[1] + cy)


class _Point:
    __slots__ = ("x", "y", "visibility")

    def __init__(self, x, y, visibility):
        self.x, self.y, self.visibility = x, y, visibility


def roi_landmarks(landmarks, crop, canvas, width, height):
    """Canvas landmarks (objects with ``x``, ``y`` and optionally ``visibility``, or a
    ``NormalizedLandmarkList``) as landmarks normalised to the full ``width`` × ``height``
    image, for :func:`body25`, :func:`hand21` and :func:`face70`; a point outside the crop
    becomes ``x = y = -1``, visibility 0 (not found). ``None`` stays ``None``."""
    if landmarks is None:
        return None
    out = []
    for lm in _landmarks(landmarks):
        p = roi_point(float(lm.x), float(lm.y), crop, canvas)
        if p is None:
            out.append(_Point(-1.0, -1.0, 0.0))
        else:
            out.append(_Point(p[0] / width, p[1] / height, getattr(lm, "visibility", 1.0)))
    return out


_GROUPS = ("pose_landmarks", "face_landmarks", "left_hand_landmarks", "right_hand_landmarks")


def roi_results(results, crop, canvas, width, height):
    """A Holistic result on the canvas with its four landmark groups mapped to the full image
    (:func:`roi_landmarks`), for :func:`person`."""
    from types import SimpleNamespace

    return SimpleNamespace(**{
        key: roi_landmarks(getattr(results, key, None), crop, canvas, width, height)
        for key in _GROUPS
    })


def _roi_segmentation(segmentation, crop, canvas, width, height):
    """The full-image segmentation (float, ``height`` × ``width``): the canvas's inside the
    crop, 0 elsewhere."""
    import cv2
    import numpy as np

    full = np.zeros((height, width), np.float32)
    if segmentation is None:
        return full
    seg = np.asarray(segmentation, np.float32)
    if seg.shape[:2] != (canvas[1], canvas[0]):
        seg = cv2.resize(seg, canvas, interpolation=cv2.INTER_LINEAR)
    x0, y0, x1, y1 = crop
    ox, oy = roi_offset(crop, canvas)
    full[y0:y1, x0:x1] = seg[oy:oy + y1 - y0, ox:ox + x1 - x0]
    return full


def _roi_canvas_image(image, crop, canvas):
    """The RGB canvas: the crop of the BGR ``image`` centred on black."""
    import cv2
    import numpy as np

    x0, y0, x1, y1 = crop
    ox, oy = roi_offset(crop, canvas)
    rgb = np.zeros((canvas[1], canvas[0], 3), np.uint8)
    rgb[oy:oy + y1 - y0, ox:ox + x1 - x0] = cv2.cvtColor(image[y0:y1, x0:x1], cv2.COLOR_BGR2RGB)
    return rgb


# ---------------------------------------------------------------------------------------
# Command line


class DetectError(Exception):
    """A user-facing error: one message (naming the file), exit status 2."""


class _Camera:
    def __init__(self, name, source, kind, images=None):
        self.name = name
        self.source = source  # absolute path of the video or the image folder
        self.kind = kind  # "video" | "images"
        self.images = images or []
        self.fps = None
        self.count = None  # frames in the source (a video's header: an estimate)


def _find_cameras(videos_dir, only, extensions=VIDEO_EXTENSIONS):
    if not os.path.isdir(videos_dir):
        raise DetectError(f"{videos_dir}: no such directory")
    cams = {}
    for entry in sorted(os.listdir(videos_dir)):
        path = os.path.abspath(os.path.join(videos_dir, entry))
        stem, ext = os.path.splitext(entry)
        cam = None
        if os.path.isfile(path) and ext.lower() in extensions:
            cam = _Camera(stem, path, "video")
        elif os.path.isdir(path):
            images = sorted(
                os.path.join(path, f)
                for f in os.listdir(path)
                if os.path.splitext(f)[1].lower() in IMAGE_EXTENSIONS
                and os.path.isfile(os.path.join(path, f))
            )
            if images:
                cam = _Camera(entry, path, "images", images)
        if cam is None:
            continue
        if cam.name in cams:
            raise DetectError(
                f"{path}: camera {cam.name!r} has two sources (also {cams[cam.name].source})"
            )
        cams[cam.name] = cam
    if not cams:
        kinds = " / ".join("*" + e for e in extensions)
        raise DetectError(
            f"{videos_dir}: no cameras (no {kinds} video, no folder of *.png / *.jpg images)"
        )
    if only:
        missing = [n for n in only if n not in cams]
        if missing:
            raise DetectError(
                f"{videos_dir}: no camera {', '.join(missing)} (found {', '.join(cams)})"
            )
        return [cams[n] for n in only]
    return list(cams.values())


def _read_json(path):
    """A JSON file's document; one :class:`DetectError` naming the file otherwise."""
    if not os.path.isfile(path):
        raise DetectError(f"{path}: no such file")
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except (OSError, ValueError) as e:
        raise DetectError(f"{path}: cannot read ({e})") from e


def _load_roi(path):
    """The boxes of a ``--roi`` file, checked: ``{camera: {frame: (x0, y0, x1, y1)}}``."""
    doc = _read_json(path)

    def bad(what):
        return DetectError(f"{path}: {what}")

    if not isinstance(doc, dict) or not isinstance(doc.get("cameras"), dict):
        raise bad("expected {\"cameras\": {\"<camera>\": {\"boxes\": {\"<frame>\": "
                  "[x0, y0, x1, y1], ...}}, ...}}")
    if not doc["cameras"]:
        raise bad("no cameras")
    roi = {}
    for name, cam in doc["cameras"].items():
        if name in ("", ".", "..") or "/" in name or os.sep in name:
            raise bad(f"{name!r} is not a camera name")
        boxes = cam.get("boxes") if isinstance(cam, dict) else None
        if not isinstance(boxes, dict):
            raise bad(f"camera {name}: 'boxes' must be an object (frame → [x0, y0, x1, y1])")
        frames = {}
        for key, box in boxes.items():
            if not (key.isascii() and key.isdigit()):
                raise bad(f"camera {name}: {key!r} is not a frame number (0, 1, …)")
            n = int(key)
            if n in frames:
                raise bad(f"camera {name}: frame {n} is listed twice")
            if not (
                isinstance(box, list) and len(box) == 4
                and all(_number(v) and math.isfinite(v) for v in box)
                and box[0] <= box[2] and box[1] <= box[3]
            ):
                raise bad(f"camera {name} frame {key}: the box must be [x0, y0, x1, y1], "
                          f"x0 ≤ x1, y0 ≤ y1 (got {box!r})")
            frames[n] = tuple(float(v) for v in box)
        roi[name] = frames
    return roi


def _open_video(cam):
    import cv2

    cap = cv2.VideoCapture(cam.source)
    if not cap.isOpened():
        raise DetectError(f"{cam.source}: cannot open the video")
    return cap


def _probe(cam):
    """Checks that the camera's first frame decodes; sets ``fps`` and ``count``."""
    import cv2

    if cam.kind == "video":
        cap = _open_video(cam)
        try:
            fps = cap.get(cv2.CAP_PROP_FPS)
            count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            ok, frame = cap.read()
        finally:
            cap.release()
        if not ok or frame is None:
            raise DetectError(f"{cam.source}: cannot decode the video (no frame)")
        cam.fps = float(fps) if fps and math.isfinite(fps) and fps > 0 else None
        cam.count = count if count > 0 else None
    else:
        if cv2.imread(cam.images[0], cv2.IMREAD_COLOR) is None:
            raise DetectError(f"{cam.images[0]}: cannot decode the image")
        cam.count = len(cam.images)


def _frames(cam, start, every, limit):
    """Yields ``(frame number, BGR image)`` of the selected frames of a camera."""
    import cv2

    if cam.kind == "images":
        for n in range(start, len(cam.images), every)[:limit]:
            image = cv2.imread(cam.images[n], cv2.IMREAD_COLOR)
            if image is None:
                raise DetectError(f"{cam.images[n]}: cannot decode the image")
            yield n, image
        return
    cap = _open_video(cam)
    try:
        n, done = 0, 0
        while limit is None or done < limit:
            if n >= start and (n - start) % every == 0:
                ok, image = cap.read()
                if not ok or image is None:
                    return  # the end of the stream
                yield n, image
                done += 1
            elif not cap.grab():
                return
            n += 1
    finally:
        cap.release()


def _expected(cam, start, every, limit):
    if cam.count is None:
        return limit
    n = max(0, -(-(cam.count - start) // every))
    return n if limit is None else min(n, limit)


class _Progress:
    """tqdm when importable, else a line on stderr every 10 frames."""

    def __init__(self, name, total, stream):
        self.name, self.total, self.n, self.stream = name, total, 0, stream
        try:
            from tqdm import tqdm
        except ImportError:
            self.bar = None
        else:
            self.bar = tqdm(total=total, desc=name, unit="frame", file=stream)

    def update(self):
        self.n += 1
        if self.bar is not None:
            self.bar.update(1)
        elif self.n % 10 == 0 or self.n == self.total:
            total = f"/{self.total}" if self.total else ""
            print(f"detect: {self.name}: {self.n}{total} frames", file=self.stream, flush=True)

    def close(self):
        if self.bar is not None:
            self.bar.close()


class _QuietStderr:
    """Sends file descriptor 2 to a temporary file while the detector runs (mediapipe's C++
    logs: the TFLite delegate, absl warnings, from its own threads too); ``stream`` writes to
    the real stderr (the progress bar). On an exception the captured text is shown after all."""

    def __enter__(self):
        sys.stderr.flush()
        self.saved = os.dup(2)
        self.stream = open(os.dup(self.saved), "w", buffering=1, errors="replace")
        self.file = tempfile.TemporaryFile()
        os.dup2(self.file.fileno(), 2)
        return self

    def __exit__(self, kind, value, tb):
        sys.stderr.flush()
        self.stream.close()
        os.dup2(self.saved, 2)
        os.close(self.saved)
        if kind is not None and not issubclass(kind, DetectError):
            self.file.seek(0)
            sys.stderr.write(self.file.read().decode(errors="replace"))
        self.file.close()
        return False


def _holistic(masks):
    import warnings

    import mediapipe as mp

    # protobuf 4.25 warns on every mediapipe result; harmless.
    warnings.filterwarnings("ignore", message="SymbolDatabase.GetPrototype", category=UserWarning)
    return mp.solutions.holistic.Holistic(
        static_image_mode=False,
        model_complexity=1,
        smooth_landmarks=True,
        enable_segmentation=masks,
        smooth_segmentation=True,
        refine_face_landmarks=True,
    )


def _mask(segmentation, width, height, scale):
    import cv2
    import numpy as np

    w, h = max(1, round(width * scale)), max(1, round(height * scale))
    if segmentation is None:
        return np.zeros((h, w), np.uint8)
    prob = np.asarray(segmentation, np.float32)
    if (w, h) != (prob.shape[1], prob.shape[0]):
        prob = cv2.resize(prob, (w, h), interpolation=cv2.INTER_AREA)
    return np.where(prob > 0.5, 255, 0).astype(np.uint8)


def _detect_camera(cam, out_dir, args, stream, boxes=None):
    """Detects one camera into ``out_dir``; with ``boxes`` (frame → box, ``--roi``) only
    inside the boxes."""
    import cv2

    os.makedirs(out_dir)
    entry = {
        "name": cam.name,
        "source": cam.source,
        "frames": 0,
        "fps": cam.fps,
        "width": None,
        "height": None,
        "found_body": 0,
        "found_left_hand": 0,
        "found_right_hand": 0,
        "found_face": 0,
    }
    if boxes is not None:
        entry.update(roi=os.path.abspath(args.roi), roi_frames=0, roi_canvas=None)
    crops = canvas = None  # with --roi: frame → crop, and the canvas size (at the first frame)
    progress = _Progress(cam.name, _expected(cam, args.start, args.every, args.frames), stream)
    holistic = _holistic(args.masks)
    try:
        for n, image in _frames(cam, args.start, args.every, args.frames):
            height, width = image.shape[:2]
            if entry["width"] is None:
                entry["width"], entry["height"] = width, height
            elif (width, height) != (entry["width"], entry["height"]):
                where = cam.images[n] if cam.kind == "images" else f"{cam.source} frame {n}"
                raise DetectError(
                    f"{where}: {width}×{height}, the camera's first frame is "
                    f"{entry['width']}×{entry['height']}"
                )
            if boxes is None:
                rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
                crop = None
            else:
                if crops is None:
                    crops = {k: roi_crop(b, width, height) for k, b in boxes.items()}
                    canvas = roi_canvas(crops.values())
                    entry["roi_canvas"] = list(canvas) if canvas else None
                crop = crops.get(n)
                rgb = None if crop is None else _roi_canvas_image(image, crop, canvas)
            if rgb is None:  # --roi, no box: nothing detected, Holistic not run
                res = segmentation = None
            else:
                rgb.flags.writeable = False
                try:
                    res = holistic.process(rgb)
                except Exception as e:  # mediapipe's RuntimeError / ValueError
                    raise DetectError(f"{cam.source} frame {n}: mediapipe failed: {e}") from e
                segmentation = res.segmentation_mask if args.masks else None
                if crop is not None:
                    entry["roi_frames"] += 1
                    res = roi_results(res, crop, canvas, width, height)
                    if args.masks:
                        segmentation = _roi_segmentation(segmentation, crop, canvas, width,
                                                         height)
            stem = os.path.join(out_dir, f"{cam.name}_{n:012d}")
            doc = {"version": 1.3, "people": [] if res is None else person(res, width, height)}
            with open(stem + "_keypoints.json", "w") as f:
                json.dump(doc, f, separators=(",", ":"))
            if args.masks:
                mask = _mask(segmentation, width, height, args.mask_scale)
                if not cv2.imwrite(stem + "_mask.png", mask):
                    raise DetectError(f"{stem}_mask.png: cannot write")
            entry["frames"] += 1
            if res is not None:
                entry["found_body"] += res.pose_landmarks is not None
                entry["found_left_hand"] += res.left_hand_landmarks is not None
                entry["found_right_hand"] += res.right_hand_landmarks is not None
                entry["found_face"] += res.face_landmarks is not None
            progress.update()
    finally:
        holistic.close()
        progress.close()
    if entry["frames"] == 0:
        raise DetectError(
            f"{cam.source}: zero frames (--start {args.start} is past the end?)"
        )
    return entry


def _is_replaceable(out):
    """An existing ``--out``: replaced only when empty or an earlier output."""
    return os.path.isdir(out) and (
        not os.listdir(out) or os.path.isfile(os.path.join(out, "detections.json"))
    )


def detect(args):
    """Runs the detector (``args`` as :func:`main` parses them); returns the summary dict."""
    out = os.path.abspath(args.out)
    if os.path.lexists(out) and not _is_replaceable(out):
        raise DetectError(
            f"{out}: exists and is not an earlier detector output (no detections.json); "
            "not replacing it"
        )
    roi = None
    if args.roi is not None:
        roi_path = os.path.abspath(args.roi)
        roi = _load_roi(roi_path)
        if args.cameras:
            missing = [n for n in args.cameras if n not in roi]
            if missing:
                raise DetectError(
                    f"{roi_path}: no camera {', '.join(missing)} (listed: {', '.join(roi)})"
                )
        cams = _find_cameras(args.videos, args.cameras or sorted(roi))
    else:
        cams = _find_cameras(args.videos, args.cameras)
    for cam in cams:
        _probe(cam)
        if _expected(cam, args.start, args.every, args.frames) == 0:
            raise DetectError(
                f"{cam.source}: zero frames (it has {cam.count}, --start {args.start})"
            )

    parent = os.path.dirname(out)
    created = []  # parent folders made here, removed again on failure
    p = parent
    while not os.path.isdir(p):
        created.append(p)
        p = os.path.dirname(p)
    for p in reversed(created):
        os.mkdir(p)
    tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(out)}.tmp-", dir=parent)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # mkdtemp's 0700 → as os.mkdir would make it
        t0 = time.perf_counter()
        with _QuietStderr() as quiet:
            entries = [
                _detect_camera(cam, os.path.join(tmp, cam.name), args, quiet.stream,
                               None if roi is None else roi[cam.name])
                for cam in cams
            ]
        seconds = time.perf_counter() - t0
        total = sum(e["frames"] for e in entries)
        summary = {
            "detector": DETECTOR,
            "cameras": entries,
            "seconds_per_frame": round(seconds / total, 4),
            "mask_scale": args.mask_scale if args.masks else None,
        }
        with open(os.path.join(tmp, "detections.json"), "w") as f:
            json.dump(summary, f, indent=2)
            f.write("\n")
        if os.path.lexists(out):
            old = tempfile.mkdtemp(prefix=f".{os.path.basename(out)}.old-", dir=parent)
            os.rename(out, os.path.join(old, "out"))
            os.rename(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        for p in created:
            try:
                os.rmdir(p)
            except OSError:
                pass
        raise
    return summary


# ---------------------------------------------------------------------------------------
# Overlay mode: a fitted mesh's silhouette and keypoints composited over the videos

OVERLAY_OPACITY = 0.45  # of the silhouette's blue
OVERLAY_BLUE = (255, 90, 0)  # BGR
OVERLAY_OUTLINE = (120, 30, 0)  # BGR: darker blue, the silhouette's edge
OVERLAY_DETECTION = (0, 210, 0)  # BGR: green
OVERLAY_MODEL = (0, 0, 255)  # BGR: red


def _number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _load_overlays(overlay_dir, only):
    """The cameras of ``overlay_dir/overlays.json`` (checked), restricted to ``only``."""
    path = os.path.join(overlay_dir, "overlays.json")
    doc = _read_json(path)

    def bad(what):
        return DetectError(f"{path}: {what}")

    if not isinstance(doc, dict):
        raise bad("not a JSON object")
    for key in ("scale", "fps"):
        v = doc.get(key)
        if not (_number(v) and math.isfinite(v) and v > 0):
            raise bad(f"{key!r} must be a positive number (got {v!r})")
    cams = doc.get("cameras")
    if not isinstance(cams, list):
        raise bad("'cameras' must be a list")
    names = {}
    for c, cam in enumerate(cams):
        name = cam.get("name") if isinstance(cam, dict) else None
        if (not isinstance(name, str) or name in ("", ".", "..") or "/" in name
                or os.sep in name):
            raise bad(f"cameras[{c}]: 'name' must be a camera name (got {name!r})")
        if name in names:
            raise bad(f"camera {name!r} is listed twice")
        names[name] = cam
        frames = cam.get("frames")
        if not isinstance(frames, list):
            raise bad(f"camera {name}: 'frames' must be a list")
        indices = set()
        for i, fr in enumerate(frames):
            where = f"camera {name} frames[{i}]"
            if not isinstance(fr, dict):
                raise bad(f"{where}: not an object")
            for key in ("index", "frame"):
                v = fr.get(key)
                if not (isinstance(v, int) and not isinstance(v, bool) and v >= 0):
                    raise bad(f"{where}: {key!r} must be an integer ≥ 0 (got {v!r})")
            if fr["index"] in indices:
                raise bad(f"{where}: index {fr['index']} is listed twice")
            indices.add(fr["index"])
            if not isinstance(fr.get("silhouette"), str) or not fr["silhouette"]:
                raise bad(f"{where}: 'silhouette' must be a file name")
            for key in ("detections", "model"):
                points = fr.get(key)
                if points is None:
                    continue
                if not isinstance(points, list) or not all(
                    isinstance(p, list) and len(p) >= 2 and all(
                        v is None or _number(v) for v in p
                    )
                    for p in points
                ):
                    raise bad(f"{where}: {key!r} must be a list of [x, y] points")
    if only:
        missing = [n for n in only if n not in names]
        if missing:
            raise bad(f"no camera {', '.join(missing)} (listed: {', '.join(names) or 'none'})")
        return doc, [names[n] for n in only]
    return doc, list(names.values())


def _write_atomic(path, data):
    """Writes ``data`` (bytes) to ``path`` through a temporary name in the same folder."""
    tmp = os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except OSError as e:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise DetectError(f"{path}: cannot write ({e.strerror or e})") from e


def _write_png(path, image):
    import cv2

    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise DetectError(f"{path}: cannot encode the PNG")
    _write_atomic(path, buf.tobytes())


def _frames_at(cam, wanted):
    """Yields ``(frame number, BGR image)`` of the frames ``wanted`` (sorted, distinct) of a
    camera; a video is decoded in order from its start (no seeking)."""
    import cv2

    if cam.kind == "images":
        for n in wanted:
            if n >= len(cam.images):
                raise DetectError(
                    f"{cam.source}: no image {n} (the folder has {len(cam.images)} images)"
                )
            image = cv2.imread(cam.images[n], cv2.IMREAD_COLOR)
            if image is None:
                raise DetectError(f"{cam.images[n]}: cannot decode the image")
            yield n, image
        return
    cap = _open_video(cam)
    try:
        pos = 0  # the next frame the stream gives
        for n in wanted:
            while pos < n:
                if not cap.grab():
                    break
                pos += 1
            ok, image = cap.read() if pos == n else (False, None)
            if not ok or image is None:
                raise DetectError(
                    f"{cam.source}: no frame {n} (the video ends after {pos} frames)"
                )
            pos += 1
            yield n, image
    finally:
        cap.release()


def _dot_radius(video_scale):
    return max(2, round(6 * video_scale))


def _composite(frame, silhouette, detections, model, video_scale):
    """The overlay picture: ``frame`` (BGR, already resized) with ``silhouette`` (grey, any
    size: resized to the frame's) blended in blue and outlined, ``detections`` (green) and
    ``model`` (red) full-resolution points as dots."""
    import cv2
    import numpy as np

    h, w = frame.shape[:2]
    if silhouette.shape[:2] != (h, w):
        silhouette = cv2.resize(silhouette, (w, h), interpolation=cv2.INTER_LINEAR)
    inside = silhouette >= 128
    out = frame.copy()
    if inside.any():
        blue = np.empty_like(frame)
        blue[:] = OVERLAY_BLUE
        blended = cv2.addWeighted(frame, 1.0 - OVERLAY_OPACITY, blue, OVERLAY_OPACITY, 0.0)
        out[inside] = blended[inside]
        m = inside.astype(np.uint8)
        edge = m > cv2.erode(m, np.ones((3, 3), np.uint8))  # 1 px inside the edge
        out[edge] = OVERLAY_OUTLINE
    radius = _dot_radius(video_scale)
    shift = 4  # fixed-point sub-pixel centres
    for points, color in ((detections or [], OVERLAY_DETECTION), (model or [], OVERLAY_MODEL)):
        for p in points:
            x, y = p[0], p[1]
            if x is None or y is None or not (math.isfinite(x) and math.isfinite(y)):
                continue
            x, y = x * video_scale, y * video_scale
            if not (-radius <= x <= w + radius and -radius <= y <= h + radius):
                continue
            centre = (int(round(x * (1 << shift))), int(round(y * (1 << shift))))
            cv2.circle(out, centre, radius << shift, color, -1, cv2.LINE_AA, shift)
    return out


def _write_video(path, pictures, fps):
    """``path`` (mp4v) of the PNG files ``pictures`` in order, through a temporary name."""
    import cv2

    first = cv2.imread(pictures[0], cv2.IMREAD_COLOR)
    if first is None:
        raise DetectError(f"{pictures[0]}: cannot read back")
    h, w = first.shape[:2]
    w, h = max(2, w - w % 2), max(2, h - h % 2)  # MPEG-4 wants even sizes
    stem, ext = os.path.splitext(os.path.basename(path))
    tmp = os.path.join(os.path.dirname(path), f".{stem}.tmp-{os.getpid()}{ext}")
    writer = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (w, h))
    try:
        if not writer.isOpened():
            raise DetectError(
                f"{path}: cannot open an OpenCV video writer (fourcc mp4v, {w}×{h}, {fps} fps; "
                f"OpenCV {cv2.__version__} without an MPEG-4 encoder?)"
            )
        for i, p in enumerate(pictures):
            image = first if i == 0 else cv2.imread(p, cv2.IMREAD_COLOR)
            if image is None:
                raise DetectError(f"{p}: cannot read back")
            image = image[:h, :w]
            if image.shape[:2] != (h, w):
                raise DetectError(f"{p}: {image.shape[1]}×{image.shape[0]}, expected {w}×{h}")
            writer.write(image)
        writer.release()
        if not os.path.isfile(tmp) or os.path.getsize(tmp) == 0:
            raise DetectError(f"{path}: the video writer wrote nothing")
        os.replace(tmp, path)
    except BaseException:
        writer.release()
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise
    return w, h


def _overlay_camera(entry, cam, overlay_dir, scale, fps, video_scale, stream):
    import cv2

    name = entry["name"]
    frames = entry["frames"]
    if not frames:
        print(f"detect: overlay {name}: no frames listed, nothing written", file=stream,
              flush=True)
        return {"name": name, "frames": 0, "video": None}
    cam_dir = os.path.join(overlay_dir, name)
    os.makedirs(cam_dir, exist_ok=True)
    need = {}  # frame number → positions in the list
    for pos, fr in enumerate(frames):
        need.setdefault(fr["frame"], []).append(pos)
    pictures = [None] * len(frames)
    full = None  # (width, height) of the source
    warned = False
    for n, image in _frames_at(cam, sorted(need)):
        height, width = image.shape[:2]
        if full is None:
            full = (width, height)
        elif (width, height) != full:
            where = cam.images[n] if cam.kind == "images" else f"{cam.source} frame {n}"
            raise DetectError(
                f"{where}: {width}×{height}, the camera's first frame is {full[0]}×{full[1]}"
            )
        size = (max(1, round(width * video_scale)), max(1, round(height * video_scale)))
        small = image if size == full else cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        for pos in need[n]:
            fr = frames[pos]
            sil_path = os.path.join(overlay_dir, fr["silhouette"])
            sil = cv2.imread(sil_path, cv2.IMREAD_GRAYSCALE)
            if sil is None:
                raise DetectError(f"{sil_path}: cannot decode the silhouette")
            want = (round(width * scale), round(height * scale))
            if not warned and (abs(sil.shape[1] - want[0]) > 1 or abs(sil.shape[0] - want[1]) > 1):
                warned = True
                print(
                    f"detect: warning: {sil_path}: {sil.shape[1]}×{sil.shape[0]}, expected "
                    f"{want[0]}×{want[1]} (scale {scale} × the video's {width}×{height}); "
                    "stretched over the frame",
                    file=stream, flush=True,
                )
            picture = _composite(small, sil, fr.get("detections"), fr.get("model"), video_scale)
            out = os.path.join(cam_dir, f"video_{fr['index']:04d}.png")
            _write_png(out, picture)
            pictures[pos] = out
    video = os.path.join(overlay_dir, f"{name}.mp4")
    w, h = _write_video(video, pictures, fps)
    print(f"detect: overlay {name}: {len(frames)} frames, {w}×{h} → {video}", file=stream,
          flush=True)
    return {"name": name, "frames": len(frames), "video": video, "width": w, "height": h}


def overlay(args):
    """The overlay mode (``args`` as :func:`main` parses them, ``args.overlay`` set): composites
    the silhouettes and keypoints of ``overlays.json`` over the videos; returns a summary
    (``{"cameras": [{"name", "frames", "video", "width", "height"}]}``)."""
    overlay_dir = os.path.abspath(args.overlay)
    if not os.path.isdir(overlay_dir):
        raise DetectError(f"{overlay_dir}: no such directory")
    video_scale = 0.5 if args.video_scale is None else args.video_scale
    doc, entries = _load_overlays(overlay_dir, args.cameras)
    names = [e["name"] for e in entries]
    sources = {
        c.name: c for c in _find_cameras(args.videos, names, OVERLAY_VIDEO_EXTENSIONS)
    } if names else {}
    # Everything that can be checked before decoding: silhouettes exist, image indices.
    for e in entries:
        cam = sources[e["name"]]
        for fr in e["frames"]:
            sil = os.path.join(overlay_dir, fr["silhouette"])
            if not os.path.isfile(sil):
                raise DetectError(f"{sil}: no such silhouette (camera {e['name']}, "
                                  f"index {fr['index']})")
            if cam.kind == "images" and fr["frame"] >= len(cam.images):
                raise DetectError(
                    f"{cam.source}: no image {fr['frame']} (the folder has "
                    f"{len(cam.images)} images; camera {e['name']}, index {fr['index']})"
                )
    done = []
    with _QuietStderr() as quiet:
        for e in entries:
            done.append(_overlay_camera(e, sources[e["name"]], overlay_dir, doc["scale"],
                                        doc["fps"], video_scale, quiet.stream))
    return {"cameras": done}


def _positive_int(text):
    n = int(text)
    if n < 1:
        raise argparse.ArgumentTypeError(f"{text}: must be at least 1")
    return n


def _non_negative_int(text):
    n = int(text)
    if n < 0:
        raise argparse.ArgumentTypeError(f"{text}: must be at least 0")
    return n


def _scale(text):
    s = float(text)
    if not (0.0 < s <= 1.0):
        raise argparse.ArgumentTypeError(f"{text}: must be in (0, 1]")
    return s


def parser():
    p = argparse.ArgumentParser(
        prog="detect.py",
        description="2D keypoints (OpenPose BODY_25 + face 70 + hands 21 JSON) of videos or "
        f"image folders, one per camera, with {DETECTOR} (offline): --videos DIR --out DIR. "
        "Overlay mode, --overlay DIR --videos DIR [--video-scale 0.5]: composites the "
        "mesh silhouettes (blue) and keypoints (detections green, model red) listed in "
        "DIR/overlays.json over the videos' frames into DIR/<cam>/video_<index>.png and "
        "DIR/<cam>.mp4 (mp4v); no detection. --roi FILE: detect only inside per-frame "
        "boxes (a bystander in view).",
    )
    p.add_argument("--videos", required=True, metavar="DIR",
                   help="one video per camera (*.mp4, *.avi, *.mov; also *.mkv with --overlay; "
                   "camera = file stem) or one image folder per camera (*.png, *.jpg)")
    p.add_argument("--out", metavar="DIR",
                   help="output folder (replaced atomically); required without --overlay")
    p.add_argument("--frames", type=_positive_int, metavar="N",
                   help="at most N frames per camera (default: all)")
    p.add_argument("--start", type=_non_negative_int, default=0, metavar="K",
                   help="first frame (0-based, default 0)")
    p.add_argument("--every", type=_positive_int, default=1, metavar="S",
                   help="every S-th frame (default 1)")
    p.add_argument("--masks", action="store_true",
                   help="also write person segmentation masks (<cam>_<frame>_mask.png)")
    p.add_argument("--mask-scale", type=_scale, default=0.25, metavar="F",
                   help="mask size relative to the image (default 0.25)")
    p.add_argument("--cameras", metavar="LIST",
                   type=lambda s: [c for c in (x.strip() for x in s.split(",")) if c],
                   help="comma-separated camera names (default: all)")
    p.add_argument("--roi", metavar="FILE",
                   help="detect only inside per-frame boxes: FILE (JSON) {\"cameras\": "
                   "{\"cam03\": {\"boxes\": {\"<frame>\": [x0, y0, x1, y1], ...}}}} in "
                   "full-image pixels; only its cameras are detected, each box enlarged by "
                   "25 %% per side; frames without a box: nobody found")
    p.add_argument("--overlay", metavar="DIR",
                   help="overlay mode: composite DIR/overlays.json's silhouettes and keypoints "
                   "over the videos (DIR/<cam>/video_NNNN.png, DIR/<cam>.mp4) instead of "
                   "detecting")
    p.add_argument("--video-scale", type=_scale, metavar="F",
                   help="with --overlay: output size relative to the video (default 0.5)")
    return p


def main(argv=None):
    """The command line; returns the exit status (0, or 2 on an error)."""
    p = parser()
    args = p.parse_args(argv)
    if args.overlay is not None:
        given = [
            opt for opt, on in (
                ("--out", args.out is not None), ("--frames", args.frames is not None),
                ("--start", args.start != 0), ("--every", args.every != 1),
                ("--masks", args.masks), ("--mask-scale", args.mask_scale != 0.25),
                ("--roi", args.roi is not None),
            ) if on
        ]
        if given:
            p.error(f"{', '.join(given)}: not with --overlay")
        try:
            summary = overlay(args)
        except DetectError as e:
            print(f"detect: error: {e}", file=sys.stderr)
            return 2
        frames = sum(c["frames"] for c in summary["cameras"])
        print(f"detect: overlay: {len(summary['cameras'])} cameras, {frames} frames → "
              f"{os.path.abspath(args.overlay)}", file=sys.stderr)
        return 0
    if args.out is None:
        p.error("the following arguments are required: --out")
    if args.video_scale is not None:
        p.error("--video-scale: only with --overlay")
    try:
        summary = detect(args)
    except DetectError as e:
        print(f"detect: error: {e}", file=sys.stderr)
        return 2
    frames = sum(c["frames"] for c in summary["cameras"])
    print(
        f"detect: {len(summary['cameras'])} cameras, {frames} frames, "
        f"{summary['seconds_per_frame']:.3f} s/frame → {os.path.abspath(args.out)}",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
