"""panoman.distributed on a local Ray cluster (num_cpus=2): same results as serial fits."""

import numpy as np
import pytest

import panoman

ray = pytest.importorskip("ray")
from panoman.distributed import FrameResult, Sequence, fit_many  # noqa: E402

from conftest import person  # noqa: E402


@pytest.fixture(scope="module")
def cluster():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def test_fit_many_matches_serial(cluster, model, model_path):
    kps = [model.keypoints(person(model, s)) for s in (10, 11, 12)]
    bad = kps[0].copy()
    bad[0, 0] = np.nan
    seq = [kps[1] + [0.0, 0.005 * i, 0.0] for i in range(3)]
    frames = [kps[0], {"keypoints": kps[1]}, bad, Sequence(seq), kps[2]]
    out = fit_many(model_path, frames, chunk_size=2, progress=True)
    assert len(out) == len(frames)

    # The failing frame is reported with its error; the others are fitted.
    assert isinstance(out[2], FrameResult) and not out[2].ok
    assert isinstance(out[2].error, panoman.InvalidError) and "not finite" in str(out[2].error)

    serial = panoman.Fitter(model)
    for i, kp in ((0, kps[0]), (1, kps[1]), (4, kps[2])):
        assert out[i].ok and out[i].error is None
        ref = serial.fit(keypoints=kp)
        diff = np.abs(out[i].result.vertices - ref.vertices).max()
        assert diff < 1e-6, f"frame {i}: {diff}"
        assert np.allclose(out[i].result.params.alpha, ref.params.alpha, atol=1e-6)

    tracker = panoman.Tracker(model)
    assert isinstance(out[3], list) and len(out[3]) == 3
    for got, kp in zip(out[3], seq):
        ref = tracker.track(keypoints=kp)
        assert got.ok and np.abs(got.result.vertices - ref.vertices).max() < 1e-6


def test_fit_many_empty_and_lbs(cluster, model, model_path):
    assert fit_many(model_path, [], progress=False) == []
    kp = model.keypoints(person(model, 20))
    out = fit_many(model_path, [kp], method="lbs", progress=False)
    ref = panoman.Fitter(model).fit(keypoints=kp, method="lbs")
    assert out[0].result.params is None
    assert np.abs(out[0].result.vertices - ref.vertices).max() < 1e-6


def test_fit_many_bad_model_path(cluster, tmp_path, target):
    _, kp = target
    out = fit_many(tmp_path / "missing.safetensors", [kp], progress=False)
    assert not out[0].ok and "missing.safetensors" in str(out[0].error)
