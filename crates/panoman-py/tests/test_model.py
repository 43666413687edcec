"""Model, Params and the array conversions."""

import pickle

import numpy as np
import pytest

import panoman


def test_load_and_properties(model, model_path):
    assert model.topology == "small"
    assert model.n_vertices == 1229
    assert model.has_rig
    assert model.n_shape > 0
    assert list(model.blocks) == ["body_l", "face_l", "hands_l", "body_a", "face_a", "hands_a"]
    assert all(k >= 1 for k in model.blocks.values())
    faces = model.faces
    assert faces.dtype == np.int64 and faces.shape[1] == 3
    assert faces.min() == 0 and faces.max() == model.n_vertices - 1
    names = model.keypoint_names
    assert len(names) == 133 and names == panoman.keypoint_names()
    parts = model.edge_parts
    assert parts.dtype == np.uint8 and set(np.unique(parts)) <= {0, 1, 2, 3}
    vparts = model.vertex_parts
    assert vparts.dtype == np.uint8 and vparts.shape == (model.n_vertices,)
    regions = model.regions
    assert list(regions) == ["body", "face", "left_hand", "right_hand"]
    ids = np.concatenate(list(regions.values()))
    assert ids.dtype == np.int64 and np.array_equal(np.sort(ids), np.arange(model.n_vertices))
    for code, name in enumerate(regions):
        assert len(regions[name]) > 0 and (vparts[regions[name]] == code).all()
    assert len(regions["body"]) > max(len(regions[n]) for n in ("face", "left_hand", "right_hand"))
    assert "small" in repr(model)
    assert panoman.Model.load(str(model_path)).n_vertices == model.n_vertices


def test_pose_mean(model):
    mesh = model.pose()
    assert mesh.shape == (model.n_vertices, 3) and mesh.dtype == np.float64
    assert mesh.flags["C_CONTIGUOUS"] and np.isfinite(mesh).all()
    height = mesh[:, 2].max() - mesh[:, 2].min()
    assert 1.0 < height < 2.3  # metres


def test_pose_inputs_any_array_like(model):
    rng = np.random.default_rng(0)
    alpha = rng.normal(0, 0.5, model.n_shape)
    beta = rng.normal(0, 0.2, model.blocks["body_a"])
    ref = model.pose(alpha, {"body_a": beta})
    as_f32 = model.pose(alpha.astype(np.float32), {"body_a": beta.astype(np.float32)})
    assert np.allclose(as_f32, ref, atol=1e-5) and not np.array_equal(as_f32, model.pose())
    assert np.array_equal(model.pose(list(alpha), {"body_a": tuple(beta)}), ref)
    strided = np.zeros((model.n_shape, 2))
    strided[:, 0] = alpha
    assert np.array_equal(model.pose(strided[:, 0], {"body_a": beta}), ref)

    class Tensor:
        """What a CPU torch tensor offers numpy: the array protocol (float32 here)."""

        def __init__(self, a):
            self.a = np.asarray(a, dtype=np.float32)

        def __array__(self, dtype=None, copy=None):
            return self.a if dtype is None else self.a.astype(dtype)

    assert np.allclose(model.pose(Tensor(alpha), {"body_a": Tensor(beta)}), ref, atol=1e-5)


def test_pose_torch(model):
    torch = pytest.importorskip("torch")
    alpha = np.linspace(-1, 1, model.n_shape)
    ref = model.pose(alpha)
    assert np.allclose(model.pose(torch.tensor(alpha, dtype=torch.float32)), ref, atol=1e-5)


def test_pose_params_and_rigid(model):
    alpha = np.full(model.n_shape, 0.3)
    beta = {"body_l": np.linspace(0.0, 0.1, model.blocks["body_l"])}
    p = panoman.Params(alpha=alpha, beta=beta, translation=[1.0, 0.0, 0.0])
    a = model.pose(p)
    b = model.pose(alpha, beta, translation=[1.0, 0.0, 0.0])
    assert np.array_equal(a, b)
    c = model.pose(alpha, beta)
    assert np.allclose(a - c, [1.0, 0.0, 0.0])
    r = model.pose(alpha, beta, rotation=[0.0, 0.0, np.pi / 2])
    assert not np.allclose(r, c)
    assert np.allclose(np.linalg.norm(r[:, :2], axis=1), np.linalg.norm(c[:, :2], axis=1))


def test_pose_without_correction(model):
    beta = {"body_a": np.full(model.blocks["body_a"], 0.3)}
    mesh = model.pose(np.full(model.n_shape, 0.2), beta, correction=False)
    assert mesh.shape == (model.n_vertices, 3) and np.isfinite(mesh).all()


def test_pose_batch_matches_pose(model):
    rng = np.random.default_rng(2)
    alphas = rng.normal(0, 0.5, (4, model.n_shape))
    betas = {"body_a": rng.normal(0, 0.2, (4, model.blocks["body_a"]))}
    trans = rng.normal(0, 1, (4, 3))
    out = model.pose_batch(alphas, betas, translations=trans)
    assert out.shape == (4, model.n_vertices, 3) and out.dtype == np.float64
    for i in range(4):
        one = model.pose(alphas[i], {"body_a": betas["body_a"][i]}, translation=trans[i])
        assert np.allclose(out[i], one, atol=1e-12)
    only_beta = model.pose_batch(betas=betas)
    assert only_beta.shape == (4, model.n_vertices, 3)


def test_encode_round_trip(model):
    # A shape-only person (the small model encodes strong β poses only roughly).
    mesh = model.pose(np.random.default_rng(3).normal(0, 0.5, model.n_shape))
    params = model.encode(mesh)
    assert isinstance(params, panoman.Params)
    assert params.alpha.shape == (model.n_shape,)
    assert np.abs(model.pose(params) - mesh).max() < 0.05
    with_rest = model.encode(np.asfortranarray(mesh), rest=model.rest_shape(params.alpha))
    assert np.abs(model.pose(with_rest) - mesh).max() < 0.05
    moved = model.encode(mesh + [0.5, 0.0, 0.0])
    assert np.allclose(moved.translation - params.translation, [0.5, 0.0, 0.0], atol=0.01)


def test_keypoints(model, target):
    mesh, kp = target
    assert kp.shape == (133, 3) and kp.dtype == np.float64
    shifted = model.keypoints(mesh + [0.0, 0.0, 1.0])
    assert np.allclose(shifted - kp, [0.0, 0.0, 1.0])


def test_rest_shape(model):
    rest = model.rest_shape(np.zeros(model.n_shape))
    assert rest.shape == (model.n_vertices, 3)
    assert not np.allclose(model.rest_shape([1.0]), rest)


def test_params_api(tmp_path, model):
    k = model.blocks["face_a"]
    p = panoman.Params(alpha=np.arange(model.n_shape, dtype=np.float32),
                       beta={"face_a": np.ones(k)}, rotation=(0, 0, 0.1))
    assert p.alpha.tolist() == list(range(model.n_shape)) and p.alpha.dtype == np.float64
    assert p.beta["face_a"].tolist() == [1.0] * k
    assert p.rotation.tolist() == [0.0, 0.0, 0.1]
    p.translation = [0.0, 1.0, 2.0]
    assert p.translation.tolist() == [0.0, 1.0, 2.0]
    p.beta = {"face_a": np.full(k, 2.0)}
    assert p.beta["face_a"][0] == 2.0
    assert pickle.loads(pickle.dumps(p)) == p
    assert panoman.Params.from_json(p.to_json()) == p
    assert p != panoman.Params()
    path = tmp_path / "params.json"
    p.write(path)
    assert panoman.Params.read(path, model) == p
    assert f"face_a: {k}" in repr(p)


def test_generator_from_model(model):
    gen = panoman.Generator.from_model(model)
    assert len(gen.bone_names) > 100
    mesh = gen.generate({}, "small")
    assert mesh.shape == (model.n_vertices, 3)
    older = gen.generate({"phenotype": {"age": 0.9}}, "small")
    assert not np.allclose(older, mesh)
    assert np.array_equal(panoman.generate("{}", "small", model=model), mesh)
    assert gen.faces("small").shape == model.faces.shape
    with pytest.raises(panoman.InvalidError, match="unknown phenotype `height_cm`"):
        gen.generate({"phenotype": {"height_cm": 180}}, "small")
    with pytest.raises(panoman.InvalidError, match="unknown topology"):
        gen.generate({}, "tiny")


def test_assets_dir():
    d = panoman.assets.default_dir()
    assert isinstance(d, str) and d
    import os

    assert os.path.samefile(panoman.assets.fetch(d), d)  # complete already: returns at once


def test_version():
    assert panoman.__version__.count(".") == 2


def test_generate_from_assets(model):
    """panoman.generate without a model loads the generator from the asset tree; it is the
    generator the model file embeds."""
    mesh = panoman.generate({"phenotype": {"age": 0.3}}, "small")
    embedded = panoman.Generator.from_model(model).generate({"phenotype": {"age": 0.3}}, "small")
    assert np.allclose(mesh, embedded, atol=1e-9)
    assert panoman.Generator.load().generate({}, "anny").shape == (13718, 3)
