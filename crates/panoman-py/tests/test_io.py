"""panoman.io: mesh files."""

import numpy as np
import pytest

import panoman


@pytest.mark.parametrize("ext", ["obj", "ply"])
def test_mesh_round_trip(tmp_path, model, ext):
    mesh = model.pose(np.full(model.n_shape, 0.5))
    path = tmp_path / f"m.{ext}"
    panoman.io.write_mesh(path, mesh, model.faces)
    v, f = panoman.io.read_mesh(path)
    assert v.shape == mesh.shape and np.allclose(v, mesh, atol=1e-6)
    assert f.dtype == np.int64 and np.array_equal(f, model.faces)
    panoman.io.write_mesh(str(path), mesh.astype(np.float32), model.faces.astype(np.uint32))
    assert np.allclose(panoman.io.read_mesh(path)[0], mesh, atol=1e-5)
