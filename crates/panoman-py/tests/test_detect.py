"""panoman.detect: the offline 2D keypoint detector (MediaPipe Holistic → OpenPose JSON).

The mapping functions (and the ``--roi`` crop geometry) run on synthetic landmarks, without
mediapipe. The runs of the command line need mediapipe 0.10.14: in this interpreter, else the
detector's own environment (``scripts/detect-setup.sh``: ``$PANOMAN_DETECT_VENV`` or
``target/detect``); they are skipped without it. The runs on real videos also need
``$PANOMAN_DETECT_VIDEOS``: a folder of one video per camera with one person (e.g. Pose2Sim's
``Demo_SinglePerson/videos``).
"""

import importlib.util
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace

import pytest

from panoman import detect

ROOT = Path(__file__).resolve().parents[3]
SCRIPT = ROOT / "crates" / "panoman-py" / "python" / "panoman" / "detect.py"

W, H = 1000, 2000


def lm(x, y, visibility=1.0):
    return SimpleNamespace(x=x, y=y, z=0.0, visibility=visibility)


def pose_landmarks():
    """33 distinct landmarks inside the image: landmark i at ((i+1)/40, (i+1)/35)."""
    return [lm((i + 1) / 40, (i + 1) / 35, 0.5 + i / 100) for i in range(33)]


def triples(flat):
    assert len(flat) % 3 == 0
    return [flat[i : i + 3] for i in range(0, len(flat), 3)]


# BODY_25 name → MediaPipe Pose landmark name (restated independently of the module's table).
MEDIAPIPE_POSE = (
    "nose left_eye_inner left_eye left_eye_outer right_eye_inner right_eye right_eye_outer "
    "left_ear right_ear mouth_left mouth_right left_shoulder right_shoulder left_elbow "
    "right_elbow left_wrist right_wrist left_pinky right_pinky left_index right_index "
    "left_thumb right_thumb left_hip right_hip left_knee right_knee left_ankle right_ankle "
    "left_heel right_heel left_foot_index right_foot_index"
).split()
BODY25 = {
    "Nose": "nose", "RShoulder": "right_shoulder", "RElbow": "right_elbow",
    "RWrist": "right_wrist", "LShoulder": "left_shoulder", "LElbow": "left_elbow",
    "LWrist": "left_wrist", "RHip": "right_hip", "RKnee": "right_knee",
    "RAnkle": "right_ankle", "LHip": "left_hip", "LKnee": "left_knee", "LAnkle": "left_ankle",
    "REye": "right_eye", "LEye": "left_eye", "REar": "right_ear", "LEar": "left_ear",
    "LBigToe": "left_foot_index", "LHeel": "left_heel", "RBigToe": "right_foot_index",
    "RHeel": "right_heel",
}
BODY25_NAMES = (
    "Nose Neck RShoulder RElbow RWrist LShoulder LElbow LWrist MidHip RHip RKnee RAnkle LHip "
    "LKnee LAnkle REye LEye REar LEar LBigToe LSmallToe LHeel RBigToe RSmallToe RHeel"
).split()


def test_body25_mapping():
    lms = pose_landmarks()
    kp = triples(detect.body25(lms, W, H))
    assert len(kp) == 25
    for i, name in enumerate(BODY25_NAMES):
        if name in BODY25:
            src = lms[MEDIAPIPE_POSE.index(BODY25[name])]
            assert kp[i] == pytest.approx([src.x * W, src.y * H, src.visibility], abs=1e-3), name
    for name, (a, b) in {"Neck": ("left_shoulder", "right_shoulder"),
                         "MidHip": ("left_hip", "right_hip")}.items():
        la, lb = lms[MEDIAPIPE_POSE.index(a)], lms[MEDIAPIPE_POSE.index(b)]
        want = [(la.x + lb.x) / 2 * W, (la.y + lb.y) / 2 * H, min(la.visibility, lb.visibility)]
        assert kp[BODY25_NAMES.index(name)] == pytest.approx(want, abs=1e-3), name
    assert kp[BODY25_NAMES.index("LSmallToe")] == [0, 0, 0]
    assert kp[BODY25_NAMES.index("RSmallToe")] == [0, 0, 0]
    # A NormalizedLandmarkList-like object (.landmark) gives the same.
    assert detect.body25(SimpleNamespace(landmark=lms), W, H) == detect.body25(lms, W, H)


def test_body25_confidence_and_outside_points():
    lms = pose_landmarks()
    lms[0] = lm(0.5, 0.5, 1.7)  # visibility clipped to 1
    lms[7] = lm(0.5, 0.5, -0.2)  # left ear: 0 → not found
    lms[8] = lm(1.2, 0.5, 0.9)  # right ear outside the image → not found
    lms[11] = lm(0.4, 0.2, 0.3)  # left shoulder: the neck takes the lower confidence
    lms[12] = lm(0.6, 0.2, 0.8)
    kp = triples(detect.body25(lms, W, H))
    assert kp[0] == pytest.approx([500, 1000, 1.0])
    assert kp[BODY25_NAMES.index("LEar")] == [0, 0, 0]
    assert kp[BODY25_NAMES.index("REar")] == [0, 0, 0]
    assert kp[1] == pytest.approx([500, 400, 0.3])
    assert detect.body25(None, W, H) == []
    with pytest.raises(ValueError):
        detect.body25(lms[:21], W, H)


def test_hands_and_face():
    hand = [lm(0.1 + i / 100, 0.2 + i / 200) for i in range(21)]
    hand[20] = lm(-0.01, 0.5)  # outside
    kp = triples(detect.hand21(hand, W, H))
    assert len(kp) == 21
    assert kp[0] == pytest.approx([100, 400, 1.0]) and kp[5] == pytest.approx([150, 450, 1.0])
    assert kp[20] == [0, 0, 0]
    assert detect.hand21(None, W, H) == []

    table = detect.FACE70_FROM_MEDIAPIPE
    assert len(table) == 70 and len(set(table)) == 70
    assert all(0 <= i < 468 for i in table[:68]) and table[68:] == (468, 473)
    face = [lm((i % 30 + 1) / 32, (i // 30 + 1) / 17) for i in range(478)]
    kp = triples(detect.face70(face, W, H))
    for k in (0, 8, 30, 36, 45, 48, 68, 69):
        src = face[table[k]]
        assert kp[k] == pytest.approx([src.x * W, src.y * H, 1.0], abs=1e-3)
    # Without the iris refinement (468 points) the pupils are absent.
    kp = triples(detect.face70(face[:468], W, H))
    assert kp[68] == kp[69] == [0, 0, 0] and kp[0][2] == 1.0
    assert detect.face70(None, W, H) == []


def test_person():
    nothing = SimpleNamespace(pose_landmarks=None, face_landmarks=None,
                              left_hand_landmarks=None, right_hand_landmarks=None)
    assert detect.person(nothing, W, H) == []
    hand = [lm(0.5, 0.5)] * 21
    res = SimpleNamespace(pose_landmarks=pose_landmarks(), face_landmarks=None,
                          left_hand_landmarks=None, right_hand_landmarks=hand)
    (p,) = detect.person(res, W, H)
    assert p["person_id"] == [-1]
    assert len(p["pose_keypoints_2d"]) == 75 and len(p["hand_right_keypoints_2d"]) == 63
    assert p["face_keypoints_2d"] == [] and p["hand_left_keypoints_2d"] == []
    json.dumps({"version": 1.3, "people": [p]})


def test_roi_crop_geometry():
    # The box enlarged by 25 % of its width / height per side, rounded outwards, clamped.
    assert detect.ROI_MARGIN == 0.25
    assert detect.roi_crop([200, 400, 600, 1200], W, H) == (100, 200, 700, 1400)
    assert detect.roi_crop([200.3, 400.6, 599.2, 1199.9], W, H) == (100, 200, 699, 1400)
    assert detect.roi_crop([-50, 1800, 900, 2300], W, H) == (0, 1675, 1000, 2000)
    assert detect.roi_crop([1100, 10, 1300, 50], W, H) is None  # entirely right of the image
    assert detect.roi_crop([500, 500, 500, 500], W, H) is None  # a point: no area
    assert detect.roi_crop([10, 10, 30, 30], W, H, margin=0.0) == (10, 10, 30, 30)
    crops = [(100, 200, 700, 1400), None, (0, 1675, 1000, 2000)]
    assert detect.roi_canvas(crops) == (1000, 1200)
    assert detect.roi_canvas([None]) is None
    # Centred on the canvas, whole pixels.
    assert detect.roi_offset((100, 200, 700, 1400), (1000, 1200)) == (200, 0)
    assert detect.roi_offset((0, 1675, 1000, 2000), (1000, 1200)) == (0, 437)
    assert detect.roi_offset((0, 0, 1000, 1200), (1000, 1200)) == (0, 0)


def to_canvas(px, py, crop, canvas):
    """The forward map (independent of the module's): full-image pixels → canvas-normalised."""
    ox = (canvas[0] - (crop[2] - crop[0])) // 2
    oy = (canvas[1] - (crop[3] - crop[1])) // 2
    return (px - crop[0] + ox) / canvas[0], (py - crop[1] + oy) / canvas[1]


def test_roi_point_mapping():
    crop, canvas = (137, 421, 637, 1221), (640, 1000)  # crop 500×800, offset (70, 100)
    for px, py in [(137, 421), (637, 1221), (300.25, 777.5), (500, 1000)]:
        x, y = to_canvas(px, py, crop, canvas)
        assert detect.roi_point(x, y, crop, canvas) == pytest.approx((px, py), abs=1e-9)
    # In the padding (outside the crop), or not finite: not found.
    for px, py in [(136, 500), (638, 500), (300, 420), (300, 1222)]:
        assert detect.roi_point(*to_canvas(px, py, crop, canvas), crop, canvas) is None
    assert detect.roi_point(0.0, 0.0, crop, canvas) is None
    assert detect.roi_point(float("nan"), 0.5, crop, canvas) is None
    # A crop as large as the canvas: canvas (0, 0) / (1, 1) are the crop's corners.
    assert detect.roi_point(0.0, 1.0, crop, (500, 800)) == (137, 1221)


def test_roi_results_to_openpose():
    """Landmarks found on the canvas come out at their full-image positions (body, hands,
    face); points in the padding are 0 0 0; groups not found stay empty."""
    crop = detect.roi_crop([300, 500, 700, 1500], W, H)  # (200, 250, 800, 1750)
    canvas = (800, 1600)  # crop 600×1500, centred at (100, 50)
    truth = [(200 + 600 * (i + 1) / 34, 250 + 1500 * ((i * 7) % 33 + 1) / 34) for i in range(33)]
    pose = [lm(*to_canvas(px, py, crop, canvas), 0.5 + i / 100) for i, (px, py) in
            enumerate(truth)]
    pose[7] = lm(50 / 800, 0.5, 0.9)  # left ear in the left padding
    hand = [lm(*to_canvas(210 + 10 * i, 300 + 5 * i, crop, canvas)) for i in range(21)]
    hand[20] = lm(0.999, 0.999)  # in the padding
    face = [lm(*to_canvas(400 + i % 30, 400 + i // 30, crop, canvas)) for i in range(478)]
    res = SimpleNamespace(pose_landmarks=SimpleNamespace(landmark=pose), face_landmarks=face,
                          left_hand_landmarks=None, right_hand_landmarks=hand,
                          segmentation_mask=None)
    mapped = detect.roi_results(res, crop, canvas, W, H)
    assert mapped.left_hand_landmarks is None
    (p,) = detect.person(mapped, W, H)
    body = triples(p["pose_keypoints_2d"])
    for i, name in enumerate(BODY25_NAMES):
        if name in BODY25 and name != "LEar":
            k = MEDIAPIPE_POSE.index(BODY25[name])
            assert body[i] == pytest.approx([*truth[k], 0.5 + k / 100], abs=2e-3), name
    a, b = truth[11], truth[12]
    assert body[1] == pytest.approx([(a[0] + b[0]) / 2, (a[1] + b[1]) / 2, 0.61], abs=2e-3)
    assert body[BODY25_NAMES.index("LEar")] == [0, 0, 0]
    hand_kp = triples(p["hand_right_keypoints_2d"])
    assert hand_kp[0] == pytest.approx([210, 300, 1]) and hand_kp[19] == pytest.approx(
        [400, 395, 1])
    assert hand_kp[20] == [0, 0, 0]
    assert p["hand_left_keypoints_2d"] == []
    face_kp = triples(p["face_keypoints_2d"])
    for k in (0, 30, 68, 69):
        src = detect.FACE70_FROM_MEDIAPIPE[k]
        assert face_kp[k] == pytest.approx([400 + src % 30, 400 + src // 30, 1], abs=2e-3)
    nothing = SimpleNamespace(pose_landmarks=None, face_landmarks=None,
                              left_hand_landmarks=None, right_hand_landmarks=None)
    assert detect.person(detect.roi_results(nothing, crop, canvas, W, H), W, H) == []


def write_roi(path, cameras):
    path.write_text(json.dumps({"cameras": {
        name: {"boxes": {str(n): box for n, box in boxes.items()}}
        for name, boxes in cameras.items()
    }}))
    return path


def run(python, *args, **kw):
    return subprocess.run([python, str(SCRIPT), *map(str, args)], capture_output=True,
                          text=True, timeout=120, **kw)


def test_plain_script_without_dependencies(tmp_path):
    # detect.py loaded by path with numpy, OpenCV, mediapipe, tqdm and panoman unimportable.
    code = textwrap.dedent(f"""
        import sys, importlib.util
        for m in ("numpy", "cv2", "mediapipe", "tqdm", "panoman"):
            sys.modules[m] = None
        spec = importlib.util.spec_from_file_location("detect", {str(SCRIPT)!r})
        d = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(d)
        from types import SimpleNamespace as N
        assert len(d.body25([N(x=0.5, y=0.5, visibility=1.0)] * 33, 10, 10)) == 75
        p = d._Progress("cam", 20, sys.stdout)
        for _ in range(20):
            p.update()
        sys.exit(d.main(["--videos", {str(tmp_path / "missing")!r}, "--out", "o"]))
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2, r.stderr
    assert r.stdout.splitlines() == ["detect: cam: 10/20 frames", "detect: cam: 20/20 frames"]
    assert "missing: no such directory" in r.stderr
    r = run(sys.executable, "--help")
    assert r.returncode == 0 and "--mask-scale" in r.stdout and "--overlay DIR" in r.stdout


def test_errors_before_detection(tmp_path):
    (tmp_path / "videos").mkdir()
    (tmp_path / "videos" / "cam01.mp4").write_bytes(b"not read here")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "keep.txt").write_text("x")
    cases = [
        (["--videos", tmp_path / "nope"], "nope: no such directory"),
        (["--videos", tmp_path / "other"], "no cameras"),
        (["--videos", tmp_path / "videos", "--cameras", "cam01,cam09"], "no camera cam09"),
        (["--videos", tmp_path / "videos", "--out", tmp_path / "other"], "not replacing"),
    ]
    for args, message in cases:
        if "--out" not in args:
            args = [*args, "--out", tmp_path / "out" / "deep"]
        r = run(sys.executable, *args)
        assert r.returncode == 2 and message in r.stderr, (args, r.stderr)
        assert r.stderr.count("\n") == 1, r.stderr
    assert not (tmp_path / "out").exists()
    assert (tmp_path / "other" / "keep.txt").exists()
    for bad in (["--every", "0"], ["--mask-scale", "0"], ["--start", "-1"]):
        r = run(sys.executable, "--videos", tmp_path, "--out", tmp_path / "o", *bad)
        assert r.returncode == 2


def test_roi_errors_before_detection(tmp_path):
    videos = tmp_path / "videos"
    videos.mkdir()
    (videos / "cam01.mp4").write_bytes(b"not read here")
    (videos / "cam02.mp4").write_bytes(b"not read here")
    good = {"cam01": {0: [1, 2, 30, 40]}}
    roi = tmp_path / "roi.json"
    cases = [
        (None, [], "roi.json: no such file"),
        ("{", [], "roi.json: cannot read"),
        ("[]", [], 'expected {"cameras"'),
        ('{"cameras": {}}', [], "roi.json: no cameras"),
        ({"cam01": {"x": [1, 2, 3, 4]}}, [], "'x' is not a frame number"),
        ({"cam01": {-1: [1, 2, 3, 4]}}, [], "'-1' is not a frame number"),
        ({"cam01": {3: [1, 2, 3]}}, [], "camera cam01 frame 3: the box must be"),
        ({"cam01": {3: [5, 2, 3, 4]}}, [], "x0 ≤ x1"),
        ({"cam01": {3: [1, 2, 3, None]}}, [], "the box must be"),
        ('{"cameras": {"cam01": {"boxes": {"1": [0, 0, 1, 1], "01": [0, 0, 1, 1]}}}}', [],
         "frame 1 is listed twice"),
        ('{"cameras": {"cam01": []}}', [], "'boxes' must be an object"),
        ({"cam09": {0: [1, 2, 3, 4]}}, [], "videos: no camera cam09"),
        (good, ["--cameras", "cam02"], "roi.json: no camera cam02 (listed: cam01)"),
    ]
    for content, extra, message in cases:
        if content is None:
            roi.unlink(missing_ok=True)
        elif isinstance(content, str):
            roi.write_text(content)
        else:
            write_roi(roi, content)
        r = run(sys.executable, "--videos", videos, "--out", tmp_path / "out", "--roi", roi,
                *extra)
        assert r.returncode == 2 and message in r.stderr, (content, r.stderr)
        assert r.stderr.count("\n") == 1, r.stderr
    assert not (tmp_path / "out").exists()
    write_roi(roi, good)
    r = run(sys.executable, "--videos", videos, "--overlay", tmp_path, "--roi", roi)
    assert r.returncode == 2 and "--roi: not with --overlay" in r.stderr, r.stderr


@pytest.fixture(scope="module")
def detector():
    """An interpreter with mediapipe and OpenCV: this one, else the detector's environment."""
    if importlib.util.find_spec("mediapipe") and importlib.util.find_spec("cv2"):
        return sys.executable
    venv = Path(os.environ.get("PANOMAN_DETECT_VENV", "target/detect"))
    python = (venv if venv.is_absolute() else ROOT / venv) / "bin" / "python"
    if not python.exists():
        pytest.importorskip("mediapipe", reason="no mediapipe (scripts/detect-setup.sh)")
    return str(python)


def test_face_table_follows_facemesh_contours(detector):
    code = textwrap.dedent(f"""
        import importlib.util, json
        from mediapipe.python.solutions import face_mesh_connections as c
        spec = importlib.util.spec_from_file_location("detect", {str(SCRIPT)!r})
        d = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(d)
        def ids(s):
            return {{i for e in s for i in e}}
        t = d.FACE68_FROM_MEDIAPIPE
        print(json.dumps([
            set(t[0:17]) <= ids(c.FACEMESH_FACE_OVAL),
            set(t[17:22]) <= ids(c.FACEMESH_RIGHT_EYEBROW),
            set(t[22:27]) <= ids(c.FACEMESH_LEFT_EYEBROW),
            set(t[36:42]) <= ids(c.FACEMESH_RIGHT_EYE),
            set(t[42:48]) <= ids(c.FACEMESH_LEFT_EYE),
            set(t[48:68]) <= ids(c.FACEMESH_LIPS),
            sorted(ids(c.FACEMESH_RIGHT_IRIS)) == [469, 470, 471, 472],
            sorted(ids(c.FACEMESH_LEFT_IRIS)) == [474, 475, 476, 477],
        ]))
    """)
    r = subprocess.run([detector, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout) == [True] * 8


MAKE_INPUTS = """
import sys, cv2, numpy as np
from pathlib import Path
d = Path(sys.argv[1]); (d / "camB").mkdir(parents=True)
w = cv2.VideoWriter(str(d / "camA.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30, (96, 64))
for i in range(6):
    w.write(np.full((64, 96, 3), 30 * i, np.uint8))
w.release()
for i in range(3):
    cv2.imwrite(str(d / "camB" / f"img{i:03d}.png"), np.full((40, 60, 3), 50 * i, np.uint8))
(d / "broken").mkdir(); (d / "broken" / "camC.avi").write_bytes(b"not a video")
"""


def test_run_on_synthetic_inputs(detector, tmp_path):
    """Frames without a person: the layout of the output, frame selection, masks, errors."""
    inputs = tmp_path / "in"
    r = subprocess.run([detector, "-c", MAKE_INPUTS, str(inputs)], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "res" / "det"
    r = run(detector, "--videos", inputs, "--out", out, "--every", "2", "--masks",
            "--mask-scale", "0.5")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "res").iterdir()) == ["det"]  # no temp left
    summary = json.loads((out / "detections.json").read_text())
    assert summary["detector"] == "mediapipe 0.10.14 holistic model_complexity=1"
    assert summary["mask_scale"] == 0.5 and summary["seconds_per_frame"] > 0
    cams = {c["name"]: c for c in summary["cameras"]}
    assert list(cams) == ["camA", "camB"]
    assert cams["camA"]["source"] == str(inputs / "camA.mp4")
    assert (cams["camA"]["frames"], cams["camA"]["fps"]) == (3, 30.0)
    assert (cams["camA"]["width"], cams["camA"]["height"]) == (96, 64)
    assert (cams["camB"]["frames"], cams["camB"]["fps"], cams["camB"]["width"]) == (2, None, 60)
    for c in cams.values():
        assert c["found_body"] == c["found_face"] == 0
        assert c["found_left_hand"] == c["found_right_hand"] == 0
    assert sorted(p.name for p in (out / "camA").iterdir()) == [
        f"camA_{n:012d}_{kind}" for n in (0, 2, 4) for kind in ("keypoints.json", "mask.png")
    ]
    assert sorted(p.name for p in (out / "camB").iterdir())[-1] == "camB_000000000002_mask.png"
    doc = json.loads((out / "camA" / "camA_000000000004_keypoints.json").read_text())
    assert doc == {"version": 1.3, "people": []}
    png = (out / "camB" / "camB_000000000000_mask.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert int.from_bytes(png[16:20], "big") == 30 and int.from_bytes(png[20:24], "big") == 20

    # A second run replaces the first; --start, --frames, --cameras, no masks.
    r = run(detector, "--videos", inputs, "--out", out, "--start", "1", "--frames", "2",
            "--cameras", "camA")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (out / "camA").iterdir()) == [
        "camA_000000000001_keypoints.json", "camA_000000000002_keypoints.json"
    ]
    assert json.loads((out / "detections.json").read_text())["mask_scale"] is None
    assert not (out / "camB").exists()

    # Errors leave the earlier output as it was.
    before = sorted(str(p) for p in out.rglob("*"))
    for args, message in [
        (["--videos", inputs / "broken"], "camC.avi: cannot"),
        (["--videos", inputs, "--start", "6"], "camA.mp4: zero frames"),
    ]:
        r = run(detector, *args, "--out", out)
        assert r.returncode == 2 and message in r.stderr, r.stderr
    assert sorted(str(p) for p in out.rglob("*")) == before
    assert sorted(p.name for p in (tmp_path / "res").iterdir()) == ["det"]


def test_roi_run_on_synthetic_inputs(detector, tmp_path):
    """--roi: only the file's cameras, every selected frame written (no box: nobody), the
    detections.json fields, masks, a new --out folder next to a detection folder."""
    inputs = tmp_path / "in"
    r = subprocess.run([detector, "-c", MAKE_INPUTS, str(inputs)], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    (inputs / "broken" / "camC.avi").unlink()
    # camA 96×64, frames 0–5: boxes on 0 (partly outside), 1, 3 (entirely outside), 9 (past
    # the selection); camB's image folder is not in the file.
    roi = write_roi(tmp_path / "roi.json", {"camA": {
        0: [-10, 20, 40, 60], 1: [30.5, 10, 70, 50], 3: [200, 10, 300, 50], 9: [0, 0, 96, 64],
    }})
    main = tmp_path / "det"
    r = run(detector, "--videos", inputs, "--out", main, "--cameras", "camA")
    assert r.returncode == 0, r.stderr
    out = tmp_path / "det-roi"
    r = run(detector, "--videos", inputs, "--out", out, "--roi", roi, "--masks",
            "--mask-scale", "0.5", "--frames", "5")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["det", "det-roi", "in", "roi.json"]
    summary = json.loads((out / "detections.json").read_text())
    (c,) = summary["cameras"]
    assert c["name"] == "camA" and c["frames"] == 5 and c["found_body"] == 0
    assert c["roi"] == str(roi) and c["roi_frames"] == 2
    # crops: frame 0 (0, 10, 53, 64), 1 (20, 0, 80, 60), 9 (0, 0, 96, 64) → canvas 96×64
    assert c["roi_canvas"] == [96, 64]
    assert sorted(p.name for p in out.iterdir()) == ["camA", "detections.json"]
    assert sorted(p.name for p in (out / "camA").iterdir()) == [
        f"camA_{n:012d}_{kind}" for n in range(5) for kind in ("keypoints.json", "mask.png")
    ]
    for n in range(5):
        doc = json.loads((out / "camA" / f"camA_{n:012d}_keypoints.json").read_text())
        assert doc == {"version": 1.3, "people": []}
    png = (out / "camA" / "camA_000000000003_mask.png").read_bytes()
    assert int.from_bytes(png[16:20], "big") == 48 and int.from_bytes(png[20:24], "big") == 32
    assert "roi" not in json.loads((main / "detections.json").read_text())["cameras"][0]
    # --cameras restricts the file's cameras; the earlier ROI output is replaced.
    write_roi(roi, {"camA": {0: [0, 0, 10, 10]}, "camB": {1: [0, 0, 60, 40]}})
    r = run(detector, "--videos", inputs, "--out", out, "--roi", roi, "--cameras", "camB")
    assert r.returncode == 0, r.stderr
    (c,) = json.loads((out / "detections.json").read_text())["cameras"]
    assert (c["name"], c["frames"], c["roi_frames"], c["roi_canvas"]) == ("camB", 3, 1, [60, 40])
    assert sorted(p.name for p in out.iterdir()) == ["camB", "detections.json"]


ROI_SEGMENTATION = """
import importlib.util, json, sys
import numpy as np
spec = importlib.util.spec_from_file_location("detect", sys.argv[1])
d = importlib.util.module_from_spec(spec)
spec.loader.exec_module(d)
crop, canvas = (30, 20, 70, 50), (50, 40)  # crop 40×30, centred at (5, 5)
seg = np.zeros((40, 50), np.float32)
seg[5:35, 5:45] = 0.25  # the crop's area
seg[10, 8] = 1.0  # crop pixel (3, 5) → image (33, 25)
seg[0, 0] = 1.0  # padding: dropped
full = d._roi_segmentation(seg, crop, canvas, 100, 80)
small = d._roi_segmentation(seg[::2, ::2], crop, canvas, 100, 80)  # another size: resized
rgb = d._roi_canvas_image(np.arange(80 * 100 * 3, dtype=np.uint32).reshape(80, 100, 3)
                          .astype(np.uint8), crop, canvas)
print(json.dumps({
    "shape": list(full.shape), "ones": np.argwhere(full == 1.0).tolist(),
    "quarter": [int((full == 0.25).sum()), np.argwhere(full == 0.25).min(0).tolist(),
                np.argwhere(full == 0.25).max(0).tolist()],
    "small": list(small.shape), "none": float(d._roi_segmentation(None, crop, canvas, 100,
                                                                    80).sum()),
    "rgb": [list(rgb.shape), rgb[:5].sum().item(), rgb[5, 5].tolist(),
            rgb[34, 44].tolist(), rgb[35:].sum().item()],
    "bgr": [(20 * 100 + 30) * 3 % 256, (49 * 100 + 69) * 3 % 256],
}))
"""


def test_roi_segmentation_paste(opencv):
    r = subprocess.run([opencv, "-c", ROI_SEGMENTATION, str(SCRIPT)], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    assert got["shape"] == [80, 100] and got["ones"] == [[25, 33]]
    assert got["quarter"] == [40 * 30 - 1, [20, 30], [49, 69]]
    assert got["small"] == [80, 100] and got["none"] == 0.0
    shape, top, first, last, bottom = got["rgb"]
    assert shape == [40, 50, 3] and top == 0 and bottom == 0
    # The crop's BGR pixel (x 30, y 20) as RGB at the canvas's (5, 5), (69, 49) at (44, 34).
    b0, b1 = got["bgr"]
    assert first == [(b0 + 2) % 256, (b0 + 1) % 256, b0]
    assert last == [(b1 + 2) % 256, (b1 + 1) % 256, b1]


@pytest.mark.skipif(not os.environ.get("PANOMAN_DETECT_VIDEOS"),
                    reason="set PANOMAN_DETECT_VIDEOS to a folder of videos of one person")
def test_run_on_videos(detector, tmp_path):
    videos = Path(os.environ["PANOMAN_DETECT_VIDEOS"])
    exts = (".mp4", ".avi", ".mov")
    cam = sorted(p.stem for p in videos.iterdir() if p.suffix.lower() in exts)[0]
    out = tmp_path / "det"
    r = run(detector, "--videos", videos, "--out", out, "--frames", "3", "--cameras", cam,
            "--masks")
    assert r.returncode == 0, r.stderr
    (c,) = json.loads((out / "detections.json").read_text())["cameras"]
    assert c["frames"] == 3 and c["found_body"] == 3
    for n in range(3):
        (p,) = json.loads((out / cam / f"{cam}_{n:012d}_keypoints.json").read_text())["people"]
        body = triples(p["pose_keypoints_2d"])
        for name in ("Neck", "RShoulder", "LShoulder", "MidHip", "RHip", "LHip"):
            assert body[BODY25_NAMES.index(name)][2] > 0.5, name
        # Each hand's wrist is nearer the pose's wrist of the same side.
        for key, same, other in (("hand_left_keypoints_2d", "LWrist", "RWrist"),
                                 ("hand_right_keypoints_2d", "RWrist", "LWrist")):
            if p[key] and p[key][2] > 0:
                s, o = body[BODY25_NAMES.index(same)], body[BODY25_NAMES.index(other)]
                d = [((p[key][0] - q[0]) ** 2 + (p[key][1] - q[1]) ** 2) ** 0.5 for q in (s, o)]
                assert d[0] < d[1], key
        assert (out / cam / f"{cam}_{n:012d}_mask.png").exists()


@pytest.mark.skipif(not os.environ.get("PANOMAN_DETECT_VIDEOS"),
                    reason="set PANOMAN_DETECT_VIDEOS to a folder of videos of one person")
def test_roi_run_on_videos(detector, tmp_path):
    """--roi around the person the full frame finds: the same body, within a few pixels."""
    videos = Path(os.environ["PANOMAN_DETECT_VIDEOS"])
    exts = (".mp4", ".avi", ".mov")
    cam = sorted(p.stem for p in videos.iterdir() if p.suffix.lower() in exts)[0]
    full = tmp_path / "full"
    r = run(detector, "--videos", videos, "--out", full, "--frames", "4", "--cameras", cam)
    assert r.returncode == 0, r.stderr
    bodies, boxes = {}, {}
    for n in range(4):
        (p,) = json.loads((full / cam / f"{cam}_{n:012d}_keypoints.json").read_text())["people"]
        bodies[n] = triples(p["pose_keypoints_2d"])
        pts = [(x, y) for x, y, c in bodies[n] if c > 0.5]
        xs, ys = [x for x, _ in pts], [y for _, y in pts]
        pad = 0.1 * (max(ys) - min(ys))  # the keypoints' box, a little larger (head, feet)
        boxes[n] = [min(xs) - pad, min(ys) - 2 * pad, max(xs) + pad, max(ys) + pad]
    roi = write_roi(tmp_path / "roi.json", {cam: {n: boxes[n] for n in (0, 1, 2)}})
    out = tmp_path / "roi"
    r = run(detector, "--videos", videos, "--out", out, "--frames", "4", "--roi", roi,
            "--masks")
    assert r.returncode == 0, r.stderr
    (c,) = json.loads((out / "detections.json").read_text())["cameras"]
    assert c["frames"] == 4 and c["roi_frames"] == 3 and c["found_body"] == 3
    for n in range(3):
        (p,) = json.loads((out / cam / f"{cam}_{n:012d}_keypoints.json").read_text())["people"]
        body = triples(p["pose_keypoints_2d"])
        height = boxes[n][3] - boxes[n][1]
        errors = sorted(
            ((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2) ** 0.5
            for a, b in zip(body, bodies[n]) if a[2] > 0.5 and b[2] > 0.5
        )
        assert len(errors) >= 15, errors
        assert errors[len(errors) // 2] < 0.03 * height, (n, errors)  # the median
    doc = json.loads((out / cam / f"{cam}_{3:012d}_keypoints.json").read_text())
    assert doc["people"] == []  # no box
    assert (out / cam / f"{cam}_{3:012d}_mask.png").exists()


# ---------------------------------------------------------------------------------------
# Overlay mode (--overlay): numpy and OpenCV only, no mediapipe.


@pytest.fixture(scope="module")
def opencv():
    """An interpreter with OpenCV and numpy: this one, else the detector's environment."""
    if importlib.util.find_spec("cv2") and importlib.util.find_spec("numpy"):
        return sys.executable
    venv = Path(os.environ.get("PANOMAN_DETECT_VENV", "target/detect"))
    python = (venv if venv.is_absolute() else ROOT / venv) / "bin" / "python"
    if not python.exists():
        pytest.importorskip("cv2", reason="no OpenCV (scripts/detect-setup.sh)")
    return str(python)


def overlay_case(root, cams):
    """``root/ov/overlays.json`` listing ``cams`` (name → [(index, frame), ...]), each frame's
    silhouette ``<cam>/silhouette_<index>.png`` (not written here) and one detection and
    two model points (one of them null)."""
    ov = root / "ov"
    ov.mkdir(parents=True, exist_ok=True)
    doc = {"scale": 0.25, "fps": 60.0, "cameras": [
        {"name": name, "frames": [
            {"index": i, "frame": f, "silhouette": f"{name}/silhouette_{i:04d}.png",
             "detections": [[20.0, 20.0]], "model": [[140.0, 100.0], [None, 3.0]]}
            for i, f in frames
        ]}
        for name, frames in cams.items()
    ]}
    (ov / "overlays.json").write_text(json.dumps(doc))
    return ov


def test_overlay_errors_before_decoding(tmp_path):
    """Errors found before OpenCV is needed (this interpreter: no cv2 required)."""
    videos = tmp_path / "videos"
    videos.mkdir()
    (videos / "camA.mp4").write_bytes(b"not read here")
    ov = overlay_case(tmp_path, {"camA": [(0, 0), (1, 3)], "camC": [(0, 0)]})
    (ov / "camA").mkdir()
    (ov / "camA" / "silhouette_0000.png").write_bytes(b"not read here")
    empty = tmp_path / "empty"
    empty.mkdir()
    cases = [
        (["--overlay", empty], "overlays.json: no such file"),
        (["--overlay", tmp_path / "nope"], "nope: no such directory"),
        (["--overlay", ov], "no camera camC"),
        (["--overlay", ov, "--cameras", "camA"], "silhouette_0001.png: no such silhouette"),
        (["--overlay", ov, "--cameras", "camX"], "overlays.json: no camera camX"),
    ]
    for args, message in cases:
        r = run(sys.executable, *args, "--videos", videos)
        assert r.returncode == 2 and message in r.stderr, (args, r.stderr)
        assert r.stderr.count("\n") == 1, r.stderr
    (ov / "overlays.json").write_text('{"scale": 0.25, "fps": 0, "cameras": []}')
    r = run(sys.executable, "--overlay", ov, "--videos", videos)
    assert r.returncode == 2 and "overlays.json: 'fps' must be a positive number" in r.stderr
    (ov / "overlays.json").write_text("{")
    r = run(sys.executable, "--overlay", ov, "--videos", videos)
    assert r.returncode == 2 and "overlays.json: cannot read" in r.stderr
    # Detection options do not go with --overlay; --video-scale only goes with it.
    for bad in (["--overlay", ov, "--out", tmp_path / "o"], ["--overlay", ov, "--masks"],
                ["--out", tmp_path / "o", "--video-scale", "0.5"],
                ["--overlay", ov, "--video-scale", "0"], []):
        r = run(sys.executable, "--videos", videos, *bad)
        assert r.returncode == 2, (bad, r.stderr)
    assert not (tmp_path / "o").exists()
    assert sorted(p.name for p in ov.rglob("*")) == ["camA", "overlays.json",
                                                     "silhouette_0000.png"]


MAKE_OVERLAY_INPUTS = """
import sys, cv2, numpy as np
from pathlib import Path
root = Path(sys.argv[1]); videos = root / "videos"; ov = root / "ov"
(videos / "camB").mkdir(parents=True)
# camA: 10 frames of 160×120, frame i uniformly grey 10 + 20 i.
w = cv2.VideoWriter(str(videos / "camA.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30, (160, 120))
for i in range(10):
    w.write(np.full((120, 160, 3), 10 + 20 * i, np.uint8))
w.release()
# camB: 4 images of 80×60.
for i in range(4):
    cv2.imwrite(str(videos / "camB" / f"img{i:02d}.png"), np.full((60, 80, 3), 40 * i, np.uint8))
# Silhouettes on the 0.25 grid: a rectangle over full-resolution x 60–120, y 40–80.
for cam, size in (("camA", (30, 40)), ("camB", (15, 20))):
    (ov / cam).mkdir(parents=True, exist_ok=True)
    for i in range(4):
        s = np.zeros(size, np.uint8)
        s[10:20, 15:30] = 255
        cv2.imwrite(str(ov / cam / f"silhouette_{i:04d}.png"), s)
"""

READ_OVERLAYS = """
import json, sys, cv2, numpy as np
out = {}
for p in sys.argv[1:]:
    if p.endswith(".png"):
        im = cv2.imread(p, cv2.IMREAD_COLOR)
        out[p] = {"size": [im.shape[1], im.shape[0]], "pixels": im.astype(int).tolist()}
    else:
        cap = cv2.VideoCapture(p)
        frames = []
        while True:
            ok, im = cap.read()
            if not ok:
                break
            frames.append(int(round(float(np.median(im[:8, :8])))))
        out[p] = {"opened": cap.isOpened() or bool(frames), "fps": cap.get(cv2.CAP_PROP_FPS),
                  "size": [cap.get(cv2.CAP_PROP_FRAME_WIDTH), cap.get(cv2.CAP_PROP_FRAME_HEIGHT)],
                  "corner_grey": frames}
print(json.dumps(out))
"""


def read_overlays(python, *paths):
    r = subprocess.run([python, "-c", READ_OVERLAYS, *map(str, paths)], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def test_overlay_on_synthetic_inputs(opencv, tmp_path):
    # Listed out of order (frames 7, 2, 9): decoded in order, written in the listed order.
    ov = overlay_case(tmp_path, {"camA": [(0, 7), (1, 2), (2, 9)], "camB": [(0, 3)]})
    r = subprocess.run([opencv, "-c", MAKE_OVERLAY_INPUTS, str(tmp_path)], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    videos = tmp_path / "videos"
    r = run(opencv, "--overlay", ov, "--videos", videos)
    assert r.returncode == 0, r.stderr
    assert "overlay camA: 3 frames, 80×60" in r.stderr and "overlay camB: 1 frames" in r.stderr
    assert sorted(p.name for p in (ov / "camA").iterdir() if p.name.startswith("video_")) == [
        "video_0000.png", "video_0001.png", "video_0002.png"
    ]
    assert not [p for p in ov.rglob(".*")]  # no temporary file left
    pngs = [ov / "camA" / f"video_{i:04d}.png" for i in range(3)]
    got = read_overlays(opencv, *pngs, ov / "camB" / "video_0000.png", ov / "camA.mp4",
                        ov / "camB.mp4")
    for i, (p, grey) in enumerate(zip(pngs, (150, 50, 190))):
        im = got[str(p)]
        assert im["size"] == [80, 60], p
        px = im["pixels"]  # rows of [b, g, r]
        assert all(abs(c - grey) <= 8 for c in px[5][75]), (p, px[5][75])  # plain frame
        b, g, r = px[30][45]  # inside the silhouette (full resolution 90, 60): blue
        assert b > g + 40 and b > r + 60, (p, px[30][45])
        assert b == pytest.approx(0.55 * grey + 0.45 * 255, abs=10)
        # A 1-px darker outline: on the silhouette's edge, not 2 px inside it.
        outline = [(y, x) for y in range(60) for x in range(80) if px[y][x] == [120, 30, 0]]
        assert len(outline) >= 80 and all(
            18 <= y <= 41 and 28 <= x <= 61 for y, x in outline
        ), outline
        assert px[30][35] != [120, 30, 0] and px[25][45] != [120, 30, 0]
        b, g, r = px[10][10]  # the detection (20, 20): green
        assert g > 150 and b < 80 and r < 80, px[10][10]
        b, g, r = px[50][70]  # the model point (140, 100): red
        assert r > 200 and b < 80 and g < 80, px[50][70]
        assert all(abs(c - grey) <= 8 for c in px[10][16])  # dots of radius 3 px
    assert got[str(ov / "camB" / "video_0000.png")]["size"] == [40, 30]
    video = got[str(ov / "camA.mp4")]
    assert video["opened"] and video["size"] == [80, 60] and video["fps"] == 60
    assert [abs(a - b) <= 8 for a, b in zip(video["corner_grey"], (150, 50, 190))] == [True] * 3
    assert len(got[str(ov / "camB.mp4")]["corner_grey"]) == 1

    # --cameras, --video-scale; a second run replaces the files.
    r = run(opencv, "--overlay", ov, "--videos", videos, "--cameras", "camA",
            "--video-scale", "0.25")
    assert r.returncode == 0, r.stderr
    got = read_overlays(opencv, pngs[2], ov / "camA.mp4")
    assert got[str(pngs[2])]["size"] == [40, 30]
    assert got[str(ov / "camA.mp4")]["size"] == [40, 30]
    assert len(got[str(ov / "camA.mp4")]["corner_grey"]) == 3

    # Errors: a frame past the end of the video / of the image folder, an undecodable
    # silhouette; one line on stderr naming the file.
    for cams, message in [
        ({"camA": [(0, 3), (1, 10)]}, "camA.mp4: no frame 10 (the video ends after 10 frames)"),
        ({"camB": [(0, 4)]}, "camB: no image 4 (the folder has 4 images"),
        ({"camA": [(5, 1)]}, "silhouette_0005.png: no such silhouette"),
    ]:
        overlay_case(tmp_path, cams)
        r = run(opencv, "--overlay", ov, "--videos", videos)
        assert r.returncode == 2 and message in r.stderr, r.stderr
        assert r.stderr.count("\n") == 1, r.stderr
    (ov / "camA" / "silhouette_0005.png").write_bytes(b"not a png")
    r = run(opencv, "--overlay", ov, "--videos", videos)
    assert r.returncode == 2 and "silhouette_0005.png: cannot decode" in r.stderr, r.stderr
    assert r.stderr.count("\n") == 1, r.stderr
    assert not [p for p in ov.rglob(".*")]
