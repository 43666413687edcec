#!/usr/bin/env bash
# The Python tests (pytest, crates/panoman-py/tests): sets up or refreshes the venv and the
# wheel (scripts/python-setup.sh; skipped with PANOMAN_PY_SETUP_DONE=1, which scripts/test.sh
# sets after its own set-up), then runs every test. Extra arguments go to pytest.
# The tests use the small example model (panoman::training::small_model; cached in
# $PANOMAN_EXAMPLES or <tmp>/panoman-examples, the cache of the Rust doc tests) and a local
# Ray cluster of 2 CPUs.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${PANOMAN_PY_SETUP_DONE:-}" != 1 ]; then
    bash scripts/python-setup.sh
fi
venv="${PANOMAN_VENV:-target/python}"
RAY_USAGE_STATS_ENABLED=0 "$venv/bin/python" -m pytest -q -p no:cacheprovider \
    crates/panoman-py/tests "$@"
