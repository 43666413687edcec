"""Fit PanoMan's α, β, rotation and translation to a mesh with a torch optimizer, through the
differentiable layer ``panoman.torch`` (the gradients come from the Rust vector–Jacobian
product, exact).

    python examples/python/torch_fit.py [MODEL.safetensors] [--iterations N]

Without a model it builds the small example model (~8 s on first use). The target is a person
from the MakeHuman generator (another shape, arm and leg angles, a turn of the whole body): not
a pose of the model itself. The loss is the mean squared vertex distance plus the keypoints';
it starts from the mean shape at the origin, with the rigid placement unknown. The least-squares
encoder (``Model.encode``, no optimizer) is printed beside it as a reference.
"""

import argparse
import time

import numpy as np
import torch

import panoman
import panoman.torch as pt


def target_person(model):
    """A generated person in the model's topology, turned and moved (metres)."""
    gen = panoman.Generator.from_model(model)
    spec = {
        "phenotype": {"gender": 0.8, "age": 0.6, "weight": 0.7},
        "pose_euler_xyz_deg": {
            "upperarm01.L": [0.0, 0.0, 40.0],
            "lowerarm01.L": [50.0, 0.0, 0.0],
            "upperleg01.R": [-30.0, 0.0, 0.0],
            "lowerleg01.R": [40.0, 0.0, 0.0],
        },
        "root_rotation_z_deg": 25.0,
        "root_translation_m": [0.2, -0.1, 0.05],
    }
    return gen.generate(spec, model.topology), gen.generate({"phenotype": spec["phenotype"]},
                                                            model.topology)


def fit(model, target, iterations=60, lr=0.05, log=print):
    """Adam on (α, β, rotation, translation); returns the layer output and the per-iteration
    mean vertex error (mm)."""
    layer = pt.PanoManLayer(model, dtype=torch.float64)
    x = torch.tensor(target)[None]
    kp = layer.keypoints(x)
    alpha = torch.zeros(1, layer.n_shape, dtype=torch.float64, requires_grad=True)
    beta = torch.zeros(1, layer.n_beta, dtype=torch.float64, requires_grad=True)
    rot = torch.zeros(1, 3, dtype=torch.float64, requires_grad=True)
    trans = (x.mean(dim=1) - torch.tensor(model.pose(np.zeros(model.n_shape))).mean(dim=0))
    trans = trans.clone().requires_grad_(True)
    opt = torch.optim.Adam([alpha, beta, rot, trans], lr=lr)
    history = []
    for it in range(iterations):
        opt.zero_grad()
        out = layer(alpha=alpha, beta=beta, rotation=rot, translation=trans)
        loss = ((out.vertices - x) ** 2).sum(-1).mean() + ((out.keypoints - kp) ** 2).sum(-1).mean()
        loss.backward()
        opt.step()
        err = 1000 * (out.vertices - x).norm(dim=-1).mean().item()
        history.append(err)
        if it % 10 == 0 or it == iterations - 1:
            log(f"iteration {it:3d}: loss {loss.item():.3e}, mean vertex error {err:.1f} mm")
    with torch.no_grad():
        out = layer(alpha=alpha, beta=beta, rotation=rot, translation=trans)
    history.append(1000 * (out.vertices - x).norm(dim=-1).mean().item())
    return out, history


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model", nargs="?", help="model file (default: the small example model)")
    ap.add_argument("--iterations", type=int, default=60)
    a = ap.parse_args()
    model = panoman.Model.load(a.model or panoman.training.small_model())
    target, rest = target_person(model)
    t0 = time.perf_counter()
    _, history = fit(model, target, a.iterations)
    dt = time.perf_counter() - t0
    print(f"Adam, {a.iterations} iterations: {history[0]:.1f} → {history[-1]:.1f} mm "
          f"({dt:.1f} s, {1000 * dt / a.iterations:.0f} ms per forward + backward)")
    enc = model.encode(target, rest=rest)
    err = 1000 * np.linalg.norm(model.pose(enc) - target, axis=1).mean()
    print(f"reference, Model.encode (given the rest shape): {err:.1f} mm")


if __name__ == "__main__":
    main()
