#!/usr/bin/env bash
# Fuzz smoke run: builds the libFuzzer targets in fuzz/ and runs each for N seconds
# (FUZZ_SECONDS, default 20) from its seed corpus (fuzz/seeds/<target>, which also holds the
# inputs of every crash found so far). Fails on the first crash, OOM, timeout or over-cap
# allocation; libFuzzer's reproducer lands in fuzz/artifacts/<target>/.
#
#   scripts/fuzz-smoke.sh                 # every target, 20 s each
#   FUZZ_SECONDS=60 scripts/fuzz-smoke.sh bvh c3d
#   FUZZ_RUNS=1000000 scripts/fuzz-smoke.sh ply   # a fixed number of executions instead
#
# The targets are built by plain cargo with libFuzzer's coverage instrumentation (the flags
# cargo-fuzz passes for `-s none`, plus debug assertions and overflow checks) on the stable
# toolchain, so cargo-fuzz need not be installed; RUSTC_BOOTSTRAP=1 is set as the cargo-fuzz
# path set it on stable. `cargo fuzz` works on the same folder for longer runs (fuzz/README.md).
set -euo pipefail
cd "$(dirname "$0")/../fuzz"

seconds="${FUZZ_SECONDS:-20}"
runs="${FUZZ_RUNS:-}"
# No sanitizer: the workspace has no `unsafe`; the allocation cap is the targets' global
# allocator (fuzz/src/lib.rs).
host="$(rustc -vV | sed -n 's/^host: //p')"
export RUSTC_BOOTSTRAP=1
RUSTFLAGS="--cfg fuzzing -Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares -Cdebug-assertions -Coverflow-checks" \
    cargo build --release --bins --target "$host"
bin_dir="target/$host/release"

if [ "$#" -gt 0 ]; then targets=("$@"); else mapfile -t targets < <(basename -s .rs fuzz_targets/*.rs); fi
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
status=0
printf '%-14s %10s %8s %8s %6s\n' target execs cov ft secs
for t in "${targets[@]}"; do
    mkdir -p "$work/$t" "artifacts/$t"
    limit=(-max_total_time="$seconds")
    if [ -n "$runs" ]; then limit=(-runs="$runs"); fi
    start=$(date +%s)
    set +e
    "$bin_dir/$t" "$work/$t" "seeds/$t" "${limit[@]}" -rss_limit_mb=2048 -malloc_limit_mb=64 \
        -timeout=10 -print_final_stats=1 -artifact_prefix="artifacts/$t/" >"$work/$t.log" 2>&1
    rc=$?
    set -e
    secs=$(( $(date +%s) - start ))
    execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$work/$t.log" | tail -1)
    last=$(grep -E '^#[0-9]+' "$work/$t.log" | tail -1)
    cov=$(sed -n 's/.* cov: \([0-9]*\).*/\1/p' <<<"$last")
    ft=$(sed -n 's/.* ft: \([0-9]*\).*/\1/p' <<<"$last")
    printf '%-14s %10s %8s %8s %6s\n' "$t" "${execs:-?}" "${cov:-?}" "${ft:-?}" "$secs"
    if [ "$rc" != 0 ]; then
        echo "fuzz-smoke: target $t failed (exit $rc); last lines of its log:" >&2
        tail -40 "$work/$t.log" >&2
        status=1
    fi
done
exit "$status"
