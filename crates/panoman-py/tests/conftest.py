"""Shared fixtures: the small example model (built once from the CC0 assets by
``panoman.training.small_model``, cached in ``$PANOMAN_EXAMPLES`` or
``<tmp>/panoman-examples`` — the same cache as the Rust doc tests and examples)."""

import numpy as np
import pytest

import panoman


@pytest.fixture(scope="session")
def model_path():
    return panoman.training.small_model()


@pytest.fixture(scope="session")
def model(model_path):
    return panoman.Model.load(model_path)


@pytest.fixture(scope="session")
def fitter(model):
    return panoman.Fitter(model)


def person(model, seed):
    """A posed mesh of the model: random small α and body β (a plausible person)."""
    rng = np.random.default_rng(seed)
    alpha = rng.normal(0.0, 0.5, model.n_shape)
    beta = {"body_a": rng.normal(0.0, 0.2, model.blocks["body_a"])}
    beta["body_a"][0] = 0.0
    return model.pose(alpha, beta)


@pytest.fixture(scope="session")
def target(model):
    """A posed mesh and its 133 keypoints (metres)."""
    mesh = person(model, 1)
    return mesh, model.keypoints(mesh)
