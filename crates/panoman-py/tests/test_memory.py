"""1,000 pose calls leave the resident memory flat.

A leak of the output array alone would be 1229 × 3 × 8 B ≈ 29 KB per call, 29 MB over
1,000 calls; a leak of the parameter vectors ~1 KB per call, 1 MB. The bound (4 MB) is far
below the first and catches anything larger than 4 KB per call, and well above the noise of
the allocators once warmed up (measured: under 1 MB).
"""

import gc
import sys

import numpy as np
import pytest

BOUND_MB = 4.0


def rss_mb():
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
def test_pose_rss_flat(model):
    alpha = np.linspace(-1, 1, model.n_shape)
    beta = {"body_a": np.full(model.blocks["body_a"], 0.05)}
    for _ in range(100):  # warm up the evaluator pool and the allocators
        model.pose(alpha, beta)
    gc.collect()
    before = rss_mb()
    total = 0.0
    for i in range(1000):
        total += model.pose(alpha * (i % 7) / 7.0, beta)[0, 2]
    gc.collect()
    after = rss_mb()
    growth = after - before
    print(f"RSS before {before:.1f} MB, after 1000 poses {after:.1f} MB, growth {growth:.2f} MB")
    assert np.isfinite(total)
    assert growth < BOUND_MB
