"""Fitter, FitResult, Tracker."""

import pickle

import numpy as np
import pytest

import panoman

BODY = 15


def body_mm(result):
    return result.report["keypoint_residuals"]["body"]["mean_mm"]


def test_fit_keypoints(model, fitter, target):
    mesh, kp = target
    fit = fitter.fit(keypoints=kp)
    assert fit.vertices.shape == (model.n_vertices, 3) and fit.vertices.dtype == np.float64
    assert isinstance(fit.params, panoman.Params)
    assert fit.report["method"] == "panoman"
    assert set(fit.report["keypoint_residuals"]) >= {"body", "face", "left_hand", "right_hand"}
    assert body_mm(fit) < 5.0
    assert np.abs(model.keypoints(fit.vertices) - kp).mean() < 0.01
    assert "bones" in str(fit.rig_params) or len(fit.rig_params) > 0
    assert fitter.setup_seconds > 0 and len(fitter.bone_names) > 100
    assert "panoman" in repr(fit)


def test_fit_named_keypoints_and_weights(model, fitter, target):
    _, kp = target
    names = model.keypoint_names
    named = {n: tuple(kp[i]) for i, n in enumerate(names) if i < BODY or i >= 91}
    fit = fitter.fit(keypoints=named, weights={names[0]: 0.5})
    assert set(fit.report["keypoint_residuals"]) >= {"body"}
    assert body_mm(fit) < 10.0
    w = np.ones(133, dtype=np.float32)
    w[BODY:91] = 0.0
    fit_w = fitter.fit(keypoints=kp, weights=w)
    assert body_mm(fit_w) < 10.0


def test_fit_lbs(model, fitter, target):
    _, kp = target
    lbs = fitter.fit(keypoints=kp, method="lbs")
    assert lbs.params is None
    assert lbs.report["method"] == "lbs" and lbs.vertices.shape == (model.n_vertices, 3)
    assert lbs.report["stages"] == []


def test_fit_handles_and_points(model, fitter, target):
    mesh, kp = target
    handles = {0: mesh[0] + [0.0, 0.0, 0.01], 100: mesh[100]}
    fit = fitter.fit(keypoints=kp, handles=handles)
    assert np.linalg.norm(fit.vertices[100] - mesh[100]) < 0.02
    fit2 = fitter.fit(keypoints=kp, handles=[(0, mesh[0], 2.0), (100, mesh[100])])
    assert fit2.vertices.shape == mesh.shape
    scan = fitter.fit(keypoints=kp, points=mesh[::3])
    assert np.abs(scan.vertices - mesh).mean() < 0.02


def test_foot_keypoints_place_the_feet_and_tc127_arrays_still_fit(model, fitter, target):
    mesh, kp = target
    names = model.keypoint_names
    feet = [names.index(n) for n in
            ("l_big_toe", "l_small_toe", "l_heel", "r_big_toe", "r_small_toe", "r_heel")]
    assert feet == list(range(15, 21)) and model.keypoint_names == panoman.keypoint_names()
    soles = model.sole_points()
    assert sorted(soles) == sorted(names[i] for i in feet) and len(set(soles.values())) == 6
    # The heel keypoints lifted 3 cm (toes down): the LBS fit follows them through the IK.
    lifted = kp.copy()
    for i in (17, 20):
        lifted[i, 2] += 0.03
    fit = fitter.fit(keypoints=lifted, method="lbs")
    plain = fitter.fit(keypoints=kp, method="lbs")
    got = model.keypoints(fit.vertices)
    was = model.keypoints(plain.vertices)
    for i in (17, 20):
        with_lift = np.linalg.norm(got[i] - lifted[i])
        without = np.linalg.norm(was[i] - lifted[i])
        assert without > 0.02 and with_lift < 0.5 * without, (names[i], without, with_lift)
    assert "feet" in fit.report["keypoint_residuals"]
    # A (127, 3) array of the TC-127 layout (no feet) still fits, as the same keypoints by name.
    old = np.delete(kp, feet, axis=0)
    assert old.shape == (127, 3)
    a = fitter.fit(keypoints=old, method="lbs")
    b = fitter.fit(keypoints={n: tuple(kp[i]) for i, n in enumerate(names) if i not in feet},
                   method="lbs")
    assert np.array_equal(a.vertices, b.vertices)
    assert "feet" not in a.report["keypoint_residuals"]


def test_fit_result_pickles(fitter, target):
    _, kp = target
    fit = fitter.fit(keypoints=kp, method="lbs")
    back = pickle.loads(pickle.dumps(fit))
    assert np.array_equal(back.vertices, fit.vertices) and back.report == fit.report


def test_fit_fixed_params(model, fitter, target):
    _, kp = target
    fixed = panoman.Params(alpha=np.zeros(model.n_shape))
    fit = fitter.fit(keypoints=kp, fixed=fixed)
    assert np.allclose(fit.params.alpha, 0.0)


def test_tracker(model, target):
    mesh, kp = target
    tracker = panoman.Tracker(model)
    for i in range(3):
        frame = tracker.track(keypoints=kp + [0.0, 0.01 * i, 0.0])
        assert body_mm(frame) < 5.0
    assert tracker.frames == 3
    with pytest.raises(panoman.InvalidError):
        tracker.track(keypoints={"bogus": (0, 0, 0)})
    assert tracker.frames == 3
    lbs = panoman.Tracker(model, "lbs", cold=True)
    assert lbs.track(kp).params is None and lbs.frames == 1


def test_tracker_shape_calibration(model, target):
    mesh, kp = target
    tracker = panoman.Tracker(model, "lbs")
    frames = [kp, kp + [0.0, 0.02, 0.0]]
    cal = tracker.calibrate_shape(frames)
    assert len(cal["knobs"]) == 9 and "measure-lowerarm-length-incr" in cal["knobs"]
    assert all(-1.0 <= v <= 1.0 for v in cal["knobs"].values())
    assert np.isfinite(cal["before_mm"]) and np.isfinite(cal["after_mm"]) and cal["seconds"] > 0
    assert body_mm(tracker.track(kp)) < 10.0
    with pytest.raises(panoman.InvalidError, match="2 keypoint sets"):
        tracker.calibrate_shape(frames, handles=[{0: mesh[0]}])


def test_motion_data(tmp_path, fitter, target):
    _, kp = target
    lbs = fitter.fit(keypoints=kp, method="lbs")
    path = tmp_path / "lbs.params.json"
    import json

    path.write_text(json.dumps(lbs.rig_params))
    motion = fitter.read_motion(path)
    assert motion and set(motion) <= set(fitter.bone_names)
    assert all(v.shape == (3,) for v in motion.values())
    fit = fitter.fit(keypoints=kp, motion=motion, motion_weight=0.5)
    assert body_mm(fit) < 10.0
    with pytest.raises(panoman.InvalidError, match="LBS"):
        fitter.fit(keypoints=kp, motion=motion, method="lbs")


def test_tracker_contacts(model, target):
    mesh, kp = target
    tracker = panoman.Tracker(model, "lbs")
    frames = [kp, kp, kp]
    info = tracker.set_contacts(frames, fps=30.0)
    # A person standing still: both feet planted in every frame.
    assert info["frames_down"] == [3, 3]
    assert len(info["weights"]) == 3 and all(w == [1.0, 1.0] for w in info["weights"])
    for _ in range(3):
        assert body_mm(tracker.track(kp)) < 10.0
    # The prior covers three frames: a fourth is refused, the sequence unchanged.
    with pytest.raises(panoman.InvalidError, match="all fitted"):
        tracker.track(kp)
    assert tracker.frames == 3
    assert tracker.set_contacts(None) is None
    tracker.track(kp)
    assert tracker.frames == 4
    # Bad input: a zero up direction, a frame without its ankles, no frame rate.
    with pytest.raises(panoman.InvalidError, match="up direction"):
        tracker.set_contacts(frames, up=(0.0, 0.0, 0.0))
    names = panoman.keypoint_names()
    no_ankle = {n: kp[i] for i, n in enumerate(names) if n != "l_ankle"}
    with pytest.raises(panoman.InvalidError, match="frame 1 has no l_ankle"):
        tracker.set_contacts([kp, no_ankle])
    with pytest.raises(panoman.InvalidError, match="frame rate"):
        tracker.set_contacts(frames, fps=0.0)
