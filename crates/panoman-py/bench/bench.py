"""Python-side measurements of issue 12 (README "Python"): the cost of a `Model.pose` call from
Python against the same call in Rust, `pose_batch` throughput, and `fit_many` on Ray against a
serial loop (identical results required).

    target/python/bin/python crates/panoman-py/bench/bench.py --model M.safetensors \
        [--runs 50] [--bin target/release/panoman] [--frames 64] [--skip-ray] \
        [--anny-python VENV/bin/python]

The Rust figure comes from `panoman bench --model M --only pose --pose-params P --json` with
the same parameters written to P (the same library call, `Model::pose` of the full template at
B = 1; `g`'s iterations depend on the parameters, so both must pose the same ones). Python and
Rust runs alternate, `--rounds` times, and the medians of all runs are compared. Fits use the small example model
(`panoman.training.small_model()`), as the issue asks ("small-preset frames"). With
`--anny-python` (a Python with `anny==0.6.2` and torch installed) anny's batched forward
(`anny.Anny()` defaults, float32 and float64, no grad, all CPU threads) is timed at the same
batch size in a subprocess. Prints one JSON object per measurement.
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
batch, runs = int(sys.argv[1]), int(sys.argv[2])
for dtype in (torch.float32, torch.float64):
    model = anny.Anny().to(dtype=dtype)
    inputs = {
        "pose_parameters": torch.eye(4, dtype=dtype)[None, None]
        .expand(batch, model.bone_count, 4, 4).clone(),
        "phenotype_kwargs": torch.full((batch, len(model.phenotype_labels)), 0.5, dtype=dtype),
    }
    times = []
    with torch.no_grad():
        model(**inputs)
        for _ in range(runs):
            t = time.perf_counter()
            model(**inputs)
            times.append((time.perf_counter() - t) * 1e3)
    med = statistics.median(times)
    print(json.dumps({"name": "anny_forward", "dtype": str(dtype), "batch": batch,
                      "vertices": len(model.template_vertices), "threads": torch.get_num_threads(),
                      "median_ms": med, "min_ms": min(times), "max_ms": max(times),
                      "runs": runs, "meshes_per_s": batch / (med / 1e3)}), flush=True)
"""


def random_params(model, rng, batch=None):
    shape = (model.n_shape,) if batch is None else (batch, model.n_shape)
    alpha = rng.normal(0.0, 0.5, shape)
    betas = {}
    for name, k in model.blocks.items():
        s = (k,) if batch is None else (batch, k)
        betas[name] = rng.normal(0.0, 0.3, s)
    return alpha, betas


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

    if a.only_pose:
        return
    alphas, bb = random_params(model, rng, a.batch)
    runs = max(3, a.runs // 10)
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
