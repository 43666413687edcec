#!/usr/bin/env bash
# Python set-up (README "Python"): a virtual environment in target/python (or $PANOMAN_VENV)
# with maturin, numpy, pytest, ray and tqdm from PyPI (crates/panoman-py/requirements-dev.txt),
# then the `panoman` wheel built from crates/panoman-py (abi3, CPython >= 3.9) and installed.
# Idempotent: a second run only rebuilds what changed. `--deps-only`: the venv and its PyPI
# packages, no wheel (scripts/test.sh downloads them while cargo compiles).
set -euo pipefail
cd "$(dirname "$0")/.."
venv="${PANOMAN_VENV:-target/python}"
req=crates/panoman-py/requirements-dev.txt
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
# Reinstall the requirements only when the list changed.
if ! cmp -s "$req" "$venv/.requirements"; then
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$req"
    cp "$req" "$venv/.requirements"
fi
# The optional torch layer's tests (crates/panoman-py/tests/test_torch.py) need torch.
torch_req=crates/panoman-py/requirements-torch.txt
if [ "${PANOMAN_TORCH_TESTS:-}" = 1 ] && ! cmp -s "$torch_req" "$venv/.requirements-torch"; then
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$torch_req"
    cp "$torch_req" "$venv/.requirements-torch"
fi
if [ "${1:-}" = --deps-only ]; then
    exit 0
fi
# Build the wheel with the workspace's target/ (shared with cargo) and install it.
wheels=target/wheels/panoman-py
rm -rf "$wheels"
"$venv/bin/maturin" build --release --quiet -m crates/panoman-py/Cargo.toml \
    --interpreter "$venv/bin/python" --compatibility linux --out "$wheels"
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps \
    --force-reinstall "$wheels"/panoman-*.whl
