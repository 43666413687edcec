"""Python-side measurements (issues 12 and 45): the cost of a `Model.pose` call from Python
against the same call in Rust; `pose` at B = 1, `pose_precise` and `pose_vjp` (the torch
layer's forward and backward) and batched `pose_flat` on fitted parameters (the `Fitter`'s
outputs for generated people: what users pose); `pose_batch` on random β (N(0, 0.3) in every
block: far from any training pose, g's frame solve runs to its cap); and `fit_many` on Ray
against a serial loop (identical results required).

    target/python/bin/python crates/panoman-py/bench/bench.py --model M.safetensors \
        [--runs 50] [--bin target/release/panoman] [--frames 64] [--skip-ray] \
        [--anny-python VENV/bin/python]

The Rust figure comes from `panoman bench --model M --only pose --pose-params P --json` with
the same parameters written to P (the same library call, `Model::pose` of the full template at
B = 1; `g`'s iterations depend on the parameters, so both must pose the same ones). Python and
Rust runs alternate, `--rounds` times, and the medians of all runs are compared. Fits use the small example model
(`panoman.training.small_model()`), as the issue asks ("small-preset frames"). With
`--anny-python` (a Python with `anny==0.6.2` and torch installed) anny's forward
(`anny.Anny()` defaults, float32 and float64, all CPU threads) is timed at B = 1 and at the
batch size, without and with a backward pass (`vertices.sum().backward()` w.r.t. the pose and
phenotype inputs), in a subprocess. Prints one JSON object per measurement.
"""

import argparse
import json
import os
import statistics
import subprocess
import tempfile
import time

import numpy as np

import panoman


def median_ms(f, runs, warmup=2):
    for _ in range(warmup):
        f()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        f()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times), min(times), max(times)


def emit(**kw):
    print(json.dumps(kw), flush=True)


def rust_pose_ms(binary, model, runs, params_path):
    out = subprocess.run(
        [binary, "bench", "--model", model, "--only", "pose", "--runs", str(runs), "--json",
         "--pose-params", params_path],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    for line in out.splitlines():
        row = json.loads(line)
        if row.get("name") == "pose":
            return row["median_ms"]
    raise SystemExit(f"{binary} bench printed no `pose` row")


ANNY_FORWARD = r"""
import json, statistics, sys, time, torch, anny
runs = int(sys.argv[2])
for batch in (1, int(sys.argv[1])):
    for dtype in (torch.float32, torch.float64):
        model = anny.Anny().to(dtype=dtype)
        inputs = {
            "pose_parameters": torch.eye(4, dtype=dtype)[None, None]
            .expand(batch, model.bone_count, 4, 4).clone(),
            "phenotype_kwargs": torch.full((batch, len(model.phenotype_labels)), 0.5,
                                           dtype=dtype),
        }
        for grad in (False, True):
            times = []
            for i in range(runs + 1):
                x = {k: v.clone().requires_grad_(grad) for k, v in inputs.items()}
                t = time.perf_counter()
                with torch.set_grad_enabled(grad):
                    out = model(**x)
                    if grad:
                        out["vertices"].sum().backward()
                if i:
                    times.append((time.perf_counter() - t) * 1e3)
            med = statistics.median(times)
            print(json.dumps({"name": "anny_forward" + ("_backward" if grad else ""),
                              "dtype": str(dtype), "batch": batch,
                              "vertices": len(model.template_vertices),
                              "threads": torch.get_num_threads(), "median_ms": med,
                              "min_ms": min(times), "max_ms": max(times), "runs": runs,
                              "meshes_per_s": batch / (med / 1e3)}), flush=True)
"""


def random_params(model, rng, batch=None):
    shape = (model.n_shape,) if batch is None else (batch, model.n_shape)
    alpha = rng.normal(0.0, 0.5, shape)
    betas = {}
    for name, k in model.blocks.items():
        s = (k,) if batch is None else (batch, k)
        betas[name] = rng.normal(0.0, 0.3, s)
    return alpha, betas


def fitted_params(model, n, seed):
    """`n` parameter sets as users pose them: `Fitter.fit` outputs for the keypoints of people
    from the MakeHuman generator (random phenotype, limbs posed), not random β."""
    rng = np.random.default_rng(seed)
    gen = panoman.Generator.from_model(model)
    fitter = panoman.Fitter(model)
    out = []
    for _ in range(n):
        spec = {
            "phenotype": {k: float(rng.uniform(0.2, 0.8)) for k in ("gender", "age", "weight")},
            "pose_euler_xyz_deg": {
                "upperarm01.L": [0.0, 0.0, float(rng.uniform(-20, 60))],
                "upperarm01.R": [0.0, 0.0, float(rng.uniform(-60, 20))],
                "lowerarm01.L": [float(rng.uniform(0, 90)), 0.0, 0.0],
                "upperleg01.R": [float(rng.uniform(-40, 10)), 0.0, 0.0],
                "lowerleg01.R": [float(rng.uniform(0, 60)), 0.0, 0.0],
            },
        }
        mesh = gen.generate(spec, model.topology)
        out.append(fitter.fit(keypoints=model.keypoints(mesh)).params)
    return out


def flat(model, params):
    """`pose_flat` arrays of a list of `Params`."""
    a = np.stack([p.alpha for p in params])
    b = np.stack([np.concatenate([p.beta[n] for n in model.blocks]) for p in params])
    r = np.stack([p.rotation for p in params])
    t = np.stack([p.translation for p in params])
    return a, b, r, t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--model", required=True, help="a full-template model (default preset)")
    ap.add_argument("--bin", default="target/release/panoman")
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--only-pose", action="store_true")
    ap.add_argument("--frames", type=int, default=64)
    ap.add_argument("--skip-ray", action="store_true")
    ap.add_argument("--anny-python", help="a Python with anny==0.6.2 + torch, for the peer figure")
    a = ap.parse_args()
    emit(load=os.getloadavg()[0], cpus=os.cpu_count())

    model = panoman.Model.load(a.model)
    rng = np.random.default_rng(0)
    alpha, betas = random_params(model, rng)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "p.json")
        p = panoman.Params(alpha=alpha, beta=betas)
        p.write(path)
        py, rust = [], []
        for _ in range(a.rounds):
            py.append(median_ms(lambda: model.pose(p), a.runs)[0])
            rust.append(rust_pose_ms(a.bin, a.model, a.runs, path))
    py_med, rust_med = statistics.median(py), statistics.median(rust)
    emit(name="pose_python", median_ms=py_med, rust_median_ms=rust_med, runs=a.runs,
         rounds=a.rounds, python_rounds_ms=py, rust_rounds_ms=rust, overhead=py_med / rust_med - 1.0)

    # Fitted parameters (what users pose): B = 1, the differentiable pair, and a batch.
    fitted = fitted_params(model, 8, 1)
    fa, fb, fr, ft = flat(model, fitted)
    k = [0]

    def one_at(i):
        return [x[i % len(fitted):i % len(fitted) + 1] for x in (fa, fb, fr, ft)]

    def cycle(f):
        k[0] += 1
        return f(*one_at(k[0]))

    for name, f in (
        ("pose_fitted", lambda a_, b_, r_, t_: model.pose_flat(a_, b_, r_, t_, precise=False)),
        ("pose_precise_fitted", lambda a_, b_, r_, t_: model.pose_flat(a_, b_, r_, t_)),
        ("pose_vjp_fitted", lambda a_, b_, r_, t_: model.pose_vjp(
            a_, b_, r_, t_, np.ones((1, model.n_vertices, 3)))),
    ):
        med, lo, hi = median_ms(lambda: cycle(f), a.runs)
        emit(name=name, batch=1, median_ms=med, min_ms=lo, max_ms=hi, runs=a.runs)
    reps = -(-a.batch // len(fitted))
    batch = [np.concatenate([x] * reps)[:a.batch] for x in (fa, fb, fr, ft)]
    runs = max(3, a.runs // 10)
    med, lo, hi = median_ms(lambda: model.pose_flat(*batch, precise=False), runs, warmup=1)
    emit(name="pose_batch_fitted", batch=a.batch, median_ms=med, min_ms=lo, max_ms=hi,
         runs=runs, meshes_per_s=a.batch / (med / 1e3))
    if a.only_pose:
        return
    alphas, bb = random_params(model, rng, a.batch)
    med, lo, hi = median_ms(lambda: model.pose_batch(alphas, bb), runs, warmup=1)
    emit(name="pose_batch", batch=a.batch, median_ms=med, min_ms=lo, max_ms=hi, runs=runs,
         meshes_per_s=a.batch / (med / 1e3))

    if a.anny_python:
        out = subprocess.run([a.anny_python, "-c", ANNY_FORWARD, str(a.batch), str(runs)],
                             check=True, capture_output=True, text=True).stdout
        print(out, end="", flush=True)

    if a.skip_ray:
        return
    import ray
    from panoman.distributed import fit_many

    small = panoman.training.small_model()
    sm = panoman.Model.load(small)
    people = [sm.pose(rng.normal(0.0, 0.5, sm.n_shape)) for _ in range(a.frames)]
    frames = [sm.keypoints(p) for p in people]
    fitter = panoman.Fitter(sm)
    t = time.perf_counter()
    serial = [fitter.fit(keypoints=k) for k in frames]
    t_serial = time.perf_counter() - t
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        fit_many(small, frames[:2], progress=False)  # actors start, model loaded once each
        t = time.perf_counter()
        out = fit_many(small, frames, progress=False)
        t_ray = time.perf_counter() - t
    finally:
        ray.shutdown()
    assert all(r.ok for r in out), [str(r.error) for r in out if not r.ok]
    diff = max(float(np.abs(r.result.vertices - s.vertices).max()) for r, s in zip(out, serial))
    emit(name="fit_many", frames=a.frames, serial_frames_per_s=a.frames / t_serial,
         ray_frames_per_s=a.frames / t_ray, max_vertex_diff_m=diff)


if __name__ == "__main__":
    main()
