"""Batch fitting on Ray: independent frames in chunks, one sequence kept on one actor.

    python examples/python/batch_ray.py [MODEL.safetensors] [--address ADDRESS]

Without --address it starts a local Ray (all CPUs); with one (e.g. `auto` after `ray start
--head`) it uses that cluster. Needs `pip install ray tqdm` (scripts/python-setup.sh does).
"""

import argparse

import numpy as np

import panoman
from panoman.distributed import Sequence, fit_many


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("model", nargs="?")
    ap.add_argument("--address")
    ap.add_argument("--frames", type=int, default=8)
    a = ap.parse_args()
    path = a.model or panoman.training.small_model()
    model = panoman.Model.load(path)

    rng = np.random.default_rng(0)
    people = [model.pose(rng.normal(0, 0.5, model.n_shape)) for _ in range(a.frames)]
    frames = [model.keypoints(p) for p in people]
    walk = Sequence(frames[0] + [0.0, -0.02 * t, 0.0] for t in range(4))  # one person moving
    broken = frames[0].copy()
    broken[0] = np.nan  # reported as that frame's error, the others go on

    out = fit_many(path, frames + [broken, walk], address=a.address, chunk_size=2)
    for i, r in enumerate(out[:-1]):
        if r.ok:
            body = r.result.report["keypoint_residuals"]["body"]["mean_mm"]
            err = np.abs(r.result.vertices - people[i]).mean() * 1000 if i < len(people) else 0
            print(f"frame {i}: body keypoints {body:.2f} mm, mean vertex error {err:.1f} mm")
        else:
            print(f"frame {i}: {type(r.error).__name__}: {r.error}")
    for t, r in enumerate(out[-1]):
        print(f"sequence frame {t}: {r.result.report['total_seconds']:.2f} s")


if __name__ == "__main__":
    main()
