"""Fit PanoMan (and the LBS baseline) to 127 TC-127 keypoints.

    python examples/python/fit_keypoints.py [MODEL.safetensors]

Without a model it builds the small example model (~8 s on first use). The keypoints come from
a posed mesh of the model itself, so the residuals show how well the fit recovers them.
"""

import os
import sys
import tempfile

import numpy as np

import panoman


def main():
    path = sys.argv[1] if len(sys.argv) > 1 else panoman.training.small_model()
    model = panoman.Model.load(path)

    # A person: some shape α and body-angle β, placed 2 m in front of the origin.
    rng = np.random.default_rng(7)
    truth = model.pose(rng.normal(0, 0.5, model.n_shape), translation=[0.0, -2.0, 0.0])
    keypoints = model.keypoints(truth)  # (127, 3) metres

    # Any subset by name works too: {"l_wrist": (x, y, z), ...}.
    named = {n: keypoints[i] for i, n in enumerate(model.keypoint_names)}
    assert len(named) == 127

    fitter = panoman.Fitter(model)  # the rig and solvers, built once
    fit = fitter.fit(keypoints=keypoints)
    lbs = fitter.fit(keypoints=keypoints, method="lbs")
    for name, r in (("panoman", fit), ("lbs", lbs)):
        res = r.report["keypoint_residuals"]
        groups = ", ".join(f"{g} {v['mean_mm']:.2f}" for g, v in res.items())
        err = np.abs(r.vertices - truth).mean() * 1000
        print(f"{name}: {r.report['total_seconds']:.2f} s; keypoint residual (mm): {groups}; "
              f"mean vertex error {err:.1f} mm")
    print(f"alpha: {np.round(fit.params.alpha[:4], 3)} ...")
    out = os.path.join(tempfile.gettempdir(), "panoman-fit.obj")
    panoman.io.write_mesh(out, fit.vertices, model.faces)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
