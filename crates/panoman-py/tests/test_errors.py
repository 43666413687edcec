"""Bad inputs raise the documented panoman.Error subclasses with one-line messages."""

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

import panoman

V = 1229


def test_hierarchy():
    assert issubclass(panoman.InvalidError, ValueError)
    assert issubclass(panoman.FormatError, ValueError)
    assert issubclass(panoman.FileError, OSError)
    for e in (panoman.InvalidError, panoman.FormatError, panoman.FileError,
              panoman.NumericalError, panoman.InternalError):
        assert issubclass(e, panoman.Error)


def test_missing_model_file(tmp_path):
    path = tmp_path / "missing.safetensors"
    with pytest.raises(panoman.FileError) as e:
        panoman.Model.load(path)
    assert isinstance(e.value, OSError)
    assert str(e.value).startswith(str(path) + ": ") and "\n" not in str(e.value)


def test_corrupt_model_file(tmp_path, model_path):
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a model at all")
    with pytest.raises(panoman.FormatError) as e:
        panoman.Model.load(bad)
    assert str(e.value).startswith(str(bad))
    truncated = tmp_path / "truncated.safetensors"
    truncated.write_bytes(Path(model_path).read_bytes()[:4096])
    with pytest.raises(panoman.FormatError):
        panoman.Model.load(truncated)


@pytest.mark.parametrize(
    "alpha, match",
    [
        (np.zeros(1000), "alpha has 1000 values"),
        ([np.nan] * 6, r"alpha\[0\] is not finite"),
        (np.zeros((2, 2)), r"shape \(N,\)"),
        (np.zeros(2, dtype=np.complex128), "not a real number type"),
        (np.array(["a", "b"]), "not a real number type"),
        ([[1.0], [1.0, 2.0]], "not an array"),
    ],
)
def test_pose_bad_alpha(model, alpha, match):
    with pytest.raises(panoman.InvalidError, match=match):
        model.pose(alpha)


def test_pose_bad_beta(model):
    with pytest.raises(panoman.InvalidError, match="unknown block 'body'"):
        model.pose(None, {"body": [0.0]})
    with pytest.raises(panoman.InvalidError, match="beta.body_l has 10000 values"):
        model.pose(None, {"body_l": np.zeros(10_000)})
    with pytest.raises(panoman.InvalidError, match="expected a dict"):
        model.pose(None, [0.0])
    with pytest.raises(panoman.InvalidError, match="shape"):
        model.pose(translation=[1.0, 2.0])
    with pytest.raises(panoman.InvalidError, match="rows"):
        model.pose_batch(np.zeros((2, 1)), {"body_l": np.zeros((3, 1))})
    with pytest.raises(panoman.InvalidError):
        model.pose_batch()


def test_bad_vertices(model):
    with pytest.raises(panoman.InvalidError, match=r"\(1229, 3\)"):
        model.keypoints(np.zeros((10, 3)))
    with pytest.raises(panoman.InvalidError, match=r"\(1229, 3\)"):
        model.encode(np.zeros((V, 2)))
    bad = model.pose()
    bad[5, 1] = np.nan
    with pytest.raises(panoman.InvalidError, match="vertex 5 is not finite"):
        model.encode(bad)
    with pytest.raises(panoman.InvalidError, match="vertex 5 is not finite"):
        model.keypoints(bad)


def test_bad_fit_targets(fitter, target):
    _, kp = target
    with pytest.raises(panoman.InvalidError, match="unknown keypoint 'l_wristt'"):
        fitter.fit(keypoints={"l_wristt": (0.0, 0.0, 1.0)})
    with pytest.raises(panoman.InvalidError, match="unknown keypoint 'nope'"):
        fitter.fit(keypoints=kp, weights={"nope": 1.0})
    with pytest.raises(panoman.InvalidError, match=r"\(133, …\) \(TC-133\) or \(127, …\) \(TC-127\), got 100 rows"):
        fitter.fit(keypoints=kp[:100])
    nan = kp.copy()
    nan[3, 0] = np.nan
    with pytest.raises(panoman.InvalidError, match="not finite"):
        fitter.fit(keypoints=nan)
    with pytest.raises(panoman.InvalidError, match="≥ 0"):
        fitter.fit(keypoints=kp, weights=-np.ones(133))
    with pytest.raises(panoman.InvalidError, match="unknown method 'smpl'"):
        fitter.fit(keypoints=kp, method="smpl")
    with pytest.raises(panoman.InvalidError, match="millimetres"):
        fitter.fit(keypoints=kp, points=kp * 1000.0)
    with pytest.raises(panoman.InvalidError, match="handle"):
        fitter.fit(keypoints=kp, handles="not handles")
    with pytest.raises(panoman.InvalidError):
        fitter.fit()  # nothing to fit
    with pytest.raises(panoman.InvalidError, match="normals given without points"):
        fitter.fit(keypoints=kp, normals=kp)


def test_params_files(tmp_path, model):
    with pytest.raises(panoman.FileError):
        panoman.Params.read(tmp_path / "none.json", model)
    bad = tmp_path / "bad.json"
    bad.write_text('{"alpha": [1.0], "beta": {"elbow": [1.0]}}')
    with pytest.raises(panoman.FormatError, match="bad.json"):
        panoman.Params.read(bad, model)
    with pytest.raises(panoman.InvalidError):
        panoman.Params.from_json("{")


def test_mesh_files(tmp_path):
    with pytest.raises(panoman.FileError):
        panoman.io.read_mesh(tmp_path / "none.obj")
    corrupt = tmp_path / "corrupt.ply"
    corrupt.write_bytes(b"ply\nformat nonsense\n")
    with pytest.raises(panoman.FormatError):
        panoman.io.read_mesh(corrupt)
    with pytest.raises(panoman.Error):
        panoman.io.read_mesh(tmp_path / "mesh.stl")
    with pytest.raises(panoman.FileError):
        panoman.io.write_mesh(tmp_path / "no" / "dir" / "m.obj", np.zeros((3, 3)), [[0, 1, 2]])
    with pytest.raises(panoman.InvalidError, match="indices"):
        panoman.io.write_mesh(tmp_path / "m.obj", np.zeros((3, 3)), [[0, 1, 3]])


def test_panic_becomes_exception():
    with pytest.raises(panoman.InternalError, match="test panic"):
        panoman._panoman._panic()
    assert panoman.keypoint_names()[0]  # the interpreter goes on


def _cli():
    root = Path(__file__).resolve().parents[3]
    exe = root / "target" / "release" / "panoman"
    return exe if exe.exists() else None


@pytest.mark.skipif(_cli() is None, reason="the panoman CLI is not built (cargo build -p panoman-cli)")
def test_messages_match_cli(tmp_path, model_path):
    """The exception's text is what `panoman` prints after `error: ` for the same failure."""
    missing = tmp_path / "missing.safetensors"
    params = tmp_path / "p.json"
    params.write_text("{}")
    run = subprocess.run(
        [str(_cli()), "pose", "--model", str(missing), "--params", str(params),
         "--out", str(tmp_path / "o.obj")],
        capture_output=True, text=True, env=dict(os.environ),
    )
    assert run.returncode != 0
    with pytest.raises(panoman.FileError) as e:
        panoman.Model.load(missing)
    assert run.stderr.strip().splitlines()[-1] == f"error: {e.value}"
    bad = tmp_path / "bad.json"
    bad.write_text('{"alpha": [1.0], "beta": {"elbow": [1.0]}}')
    run = subprocess.run(
        [str(_cli()), "pose", "--model", str(model_path), "--params", str(bad),
         "--out", str(tmp_path / "o.obj")],
        capture_output=True, text=True,
    )
    with pytest.raises(panoman.FormatError) as e:
        panoman.Params.read(bad, panoman.Model.load(model_path))
    assert run.stderr.strip().splitlines()[-1] == f"error: {e.value}"


def test_bad_handles(fitter, target):
    _, kp = target
    with pytest.raises(panoman.InvalidError, match="99999"):
        fitter.fit(keypoints=kp, handles={99999: (0.0, 0.0, 1.0)})
    with pytest.raises(panoman.InvalidError, match="index ≥ 0"):
        fitter.fit(keypoints=kp, handles=[(-1, (0.0, 0.0, 1.0))])
    with pytest.raises(panoman.InvalidError, match="handle 0"):
        fitter.fit(keypoints=kp, handles=[(3, (0.0, np.inf, 1.0))])
