#!/usr/bin/env python3
"""Compare two `panoman eval` summary.json files number by number.

Usage: tools/compare_summaries.py BEFORE.json AFTER.json [--rtol 1e-9]

Timing entries (a key on the path ending in `_s`, `seconds`, `_ms` or containing `time`) are listed apart:
they measure the machine, not the results. Exit status 1 if any other number differs by more
than `rtol` (relative, with an absolute floor of 1e-12) or the key sets differ.
"""
import json
import sys


def leaves(v, path=""):
    if isinstance(v, dict):
        for k, x in v.items():
            yield from leaves(x, f"{path}.{k}" if path else k)
    elif isinstance(v, list):
        for i, x in enumerate(v):
            yield from leaves(x, f"{path}[{i}]")
    elif isinstance(v, (int, float)) and not isinstance(v, bool):
        yield path, float(v)


def is_timing(path):
    parts = [p.split("[")[0].lower() for p in path.split(".")]
    return any(p.endswith(("_s", "seconds", "_ms")) or "time" in p for p in parts)


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    rtol = 1e-9
    if "--rtol" in sys.argv:
        rtol = float(sys.argv[sys.argv.index("--rtol") + 1])
        args = [a for a in args if a != str(sys.argv[sys.argv.index("--rtol") + 1])]
    a = dict(leaves(json.load(open(args[0]))))
    b = dict(leaves(json.load(open(args[1]))))
    bad = 0
    for k in sorted(set(a) ^ set(b)):
        print(f"only in {'before' if k in a else 'after'}: {k}")
        bad += 1
    same = timing = 0
    worst = (0.0, "")
    for k in sorted(set(a) & set(b)):
        x, y = a[k], b[k]
        if is_timing(k):
            timing += 1
            continue
        d = abs(x - y) / max(abs(x), abs(y), 1e-12)
        if x != x and y != y:
            d = 0.0
        if d > worst[0]:
            worst = (d, k)
        if d > rtol:
            print(f"differs: {k}: {x!r} vs {y!r} (rel {d:.3g})")
            bad += 1
        else:
            same += 1
    print(f"{same} numbers agree (rtol {rtol}), {bad} differ, {timing} timing entries skipped; "
          f"largest relative difference {worst[0]:.3g} at {worst[1] or '-'}")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
