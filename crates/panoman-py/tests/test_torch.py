"""``panoman.torch``: the differentiable layer (gradcheck, the correction's gradient, shapes and
keypoints, the fitting example). Skipped without torch unless ``PANOMAN_TORCH_TESTS=1``
(``.ci/run`` sets it and installs torch), where its absence is an error."""

import importlib.util
import os
import pathlib

import numpy as np
import pytest

import panoman

if os.environ.get("PANOMAN_TORCH_TESTS") == "1":
    import torch
else:
    torch = pytest.importorskip("torch")

import panoman.torch as pt  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[3]


def inputs(layer, seed, dtype=torch.float64):
    rng = np.random.default_rng(seed)
    beta = np.zeros((1, layer.n_beta))
    sl = layer.beta_slices["body_a"]
    beta[0, sl] = rng.normal(0.0, 0.2, sl.stop - sl.start)
    beta[0, sl.start] = 0.0
    t = lambda a: torch.tensor(a, dtype=dtype, requires_grad=True)  # noqa: E731
    return (t(rng.normal(0.0, 0.5, (1, layer.n_shape))), t(beta), t([[0.3, -0.2, 0.5]]),
            t([[0.1, 0.2, -0.3]]))


def test_gradcheck_float64(model):
    """Without the correction every step is float64 and the backward pass is the exact
    derivative of the forward (g's frames polished to the minimiser), so torch's gradcheck
    (central differences, eps 1e-6) holds at rtol 1e-4: the full Jacobian of a random 4-vector
    projection of the vertices, and fast mode on all vertices and keypoints."""
    layer = pt.PanoManLayer(model, correction=False, dtype=torch.float64)
    args = inputs(layer, 0)
    proj = torch.tensor(np.random.default_rng(1).normal(size=(model.n_vertices * 3, 4)))

    def projected(a, b, r, t):
        return pt.pose(model, a, b, r, t, correction=False).reshape(1, -1) @ proj

    assert torch.autograd.gradcheck(projected, args, eps=1e-6, atol=1e-6, rtol=1e-4)

    def both(a, b, r, t):
        out = layer(alpha=a, beta=b, rotation=r, translation=t)
        return out.vertices, out.keypoints

    assert torch.autograd.gradcheck(both, args, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)


def test_gradient_with_correction(model):
    """With the correction MLP (float32, piecewise linear) the directional derivative matches
    central differences to 0.1 %: at h = 1e-4 its f32 rounding over 2h is ~1e-4 relative
    (measured 1.5e-4); at h = 1e-3 a unit's ReLU already flips inside ±h along this random
    direction (2 % off), at 1e-5 the rounding dominates (1e-3)."""
    layer = pt.PanoManLayer(model, correction=True, dtype=torch.float64)
    a, b, r, t = inputs(layer, 2)
    w = torch.tensor(np.random.default_rng(3).normal(size=(1, model.n_vertices, 3)))
    (layer(alpha=a, beta=b, rotation=r, translation=t).vertices * w).sum().backward()
    rng = np.random.default_rng(4)
    dirs = [torch.tensor(rng.normal(size=x.shape)) for x in (a, b, r, t)]
    analytic = sum((x.grad * d).sum() for x, d in zip((a, b, r, t), dirs)).item()
    h = 1e-4
    with torch.no_grad():
        f = [(layer(*(x + s * d for x, d in zip((a, b, r, t), dirs))).vertices * w).sum().item()
             for s in (h, -h)]
    fd = (f[0] - f[1]) / (2 * h)
    assert abs(fd) > 1e-3
    assert abs(fd - analytic) <= 1e-3 * abs(fd), (fd, analytic)


def test_layer_shapes_dtypes_and_keypoints(model):
    layer = pt.PanoManLayer(model)
    out = layer()
    assert out.vertices.shape == (1, model.n_vertices, 3) and out.vertices.dtype == torch.float32
    alpha = torch.linspace(-1, 1, layer.n_shape)
    single = layer(alpha=alpha)
    assert single.vertices.shape == (model.n_vertices, 3)
    assert single.keypoints.shape == (len(model.keypoint_names), 3)
    ref = model.pose(alpha.numpy().astype(np.float64))
    assert np.allclose(single.vertices.numpy(), ref, atol=1e-5)
    assert np.allclose(single.keypoints.numpy(), model.keypoints(ref), atol=1e-5)
    batch = layer(alpha=torch.stack([alpha, -alpha]))
    assert batch.vertices.shape == (2, model.n_vertices, 3)
    assert np.allclose(batch.vertices[1].numpy(), model.pose(-alpha.numpy().astype(np.float64)),
                       atol=1e-5)
    # In float64 the keypoints are the model's to rounding (its weights are kept in float64).
    l64 = pt.PanoManLayer(model, dtype=torch.float64)
    v64 = torch.tensor(ref)[None]
    assert np.allclose(l64.keypoints(v64)[0].numpy(), model.keypoints(ref), rtol=0, atol=1e-12)
    # β from a dict equals the flat layout.
    k = model.blocks["body_a"]
    flat = layer.beta_from_dict({"body_a": torch.full((1, k), 0.1)})
    assert flat.shape == (1, layer.n_beta)
    assert torch.all(flat[0, layer.beta_slices["body_a"]] == 0.1)
    assert torch.count_nonzero(flat) == k
    with pytest.raises(ValueError, match="unknown β blocks"):
        layer.beta_from_dict({"tail_a": torch.zeros(1, 3)})


def test_bad_inputs_raise(model):
    layer = pt.PanoManLayer(model)
    with pytest.raises(ValueError, match="alpha"):
        layer(alpha=torch.zeros(1, layer.n_shape + 1))
    n = model.n_shape
    kb = sum(model.blocks.values())
    z = np.zeros((1, 3))
    with pytest.raises(panoman.InvalidError, match="betas"):
        model.pose_flat(np.zeros((1, n)), np.zeros((1, kb - 1)), z, z)
    grad = np.zeros((1, model.n_vertices, 3))
    grad[0, 7, 2] = np.nan
    with pytest.raises(panoman.InvalidError, match="vertex 7"):
        model.pose_vjp(np.zeros((1, n)), np.zeros((1, kb)), z, z, grad)
    with pytest.raises(panoman.InvalidError, match="grad"):
        model.pose_vjp(np.zeros((1, n)), np.zeros((1, kb)), z, z, grad[:, :5])


def test_fitting_example_converges(model):
    """``examples/python/torch_fit.py``: Adam through the layer brings a generated person (not
    a pose of the model) from the mean shape at the origin to a fraction of its start error."""
    spec = importlib.util.spec_from_file_location("torch_fit",
                                                  ROOT / "examples/python/torch_fit.py")
    ex = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ex)
    target, _ = ex.target_person(model)
    _, history = ex.fit(model, target, iterations=40, log=lambda _: None)
    assert history[-1] < 0.25 * history[0], history
