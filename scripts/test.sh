#!/usr/bin/env bash
# The test suite (what CI runs, via .ci/run): formatting, every crate's tests and doc tests,
# then the numbered library examples on the small example model, then the Python tests
# (scripts/python-test.sh, which sets up its venv in target/python on first use).
# The interchange tests use node + npm (pinned tools in tools/node) and Debian's chromium; they
# are skipped with a note unless PANOMAN_NODE_TESTS=1 (which .ci/run sets).
set -euo pipefail
cd "$(dirname "$0")/.."
# Wall time per step, printed as each ends.
step_t0=$SECONDS
timed() {
    printf '[time] %-24s %5d s\n' "$1" $((SECONDS - step_t0))
    step_t0=$SECONDS
}
cargo fmt --all --check
timed "cargo fmt"
if command -v npm >/dev/null 2>&1; then
    npm ci --prefix tools/node --no-audit --no-fund --silent
fi
timed "npm ci"
# One Python venv (target/python, scripts/python-setup.sh): the `panoman` wheel and its test
# tools, and the PyPI `bvh` package, the second BVH reader of the `mocap export` test
# (PANOMAN_PY_TESTS=1, set by .ci/run, makes its absence an error there). Its PyPI packages
# download while cargo compiles the tests; the wheel then reuses cargo's build.
mkdir -p target
bash scripts/python-setup.sh --deps-only >target/python-deps.log 2>&1 &
deps_pid=$!
cargo test --release --workspace --no-run
timed "cargo test build"
if ! wait "$deps_pid"; then
    cat target/python-deps.log >&2
    echo "test.sh: the Python venv's packages failed to install (target/python-deps.log)" >&2
    exit 1
fi
bash scripts/python-setup.sh
timed "python venv + wheel"
cargo test --release --workspace
timed "cargo test run"
for example in 01_pose 02_fit_keypoints 03_track 04_fit_scan; do
    echo "example $example:"
    cargo run --release --quiet --example "$example"
done
timed "examples"
# Python bindings (crates/panoman-py): the venv and wheel were set up above; pytest.
PANOMAN_PY_SETUP_DONE=1 bash scripts/python-test.sh
timed "pytest"
