#!/usr/bin/env python3
"""Fault injection for panoman's writers (issue 17): SIGKILL at random moments, a full disk,
two writers of one output directory, a read-only output directory, and `track --resume`.

    python3 scripts/fault-inject.py --bin target/release/panoman [--trials 20] [--quick]

For each of `synth` (small preset), `train` (small preset), `track` (a 24-frame clip, small
model) and `mocap solve` (the committed CSM excerpt, small model) the command runs once to
completion (the reference; a second run with other inputs gives the "previous" version), then
`--trials` times SIGKILLed at a moment drawn uniformly within the reference's run time, half
of the trials into an empty location, half over the previous complete version. Every file
left must be the reference's bytes, the previous version's bytes, or (files that hold
timings: reports, summary.json, the track checkpoint) pass its validator; a dataset's two
files must come from one run or be refused by panoman. Anything else is corrupt. The
validators load outputs with panoman itself (a model with `panoman pose`, a dataset with
`panoman train --evaluate-only`) or parse them (OBJ counts, JSON, PNG chunks, CSV columns,
the checkpoint's checksum); each validator is shown to reject a truncated reference first.

Exits 1 when anything is corrupt or a fault scenario misbehaves; prints one table.
Needs root for the tmpfs scenarios (skipped with a message where mount is refused).
Python 3 standard library only.
"""

import argparse
import hashlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CSM = ROOT / "crates/panoman-mocap/tests/data/ThomasFechten_head.csm"
N_FRAMES = 24

BIN = None
WORK = None
FAILURES = []  # scenario failures (not kill-trial corruption)


def sh(args, timeout=600, check=True, **kw):
    p = subprocess.run([str(BIN)] + [str(a) for a in args], capture_output=True, text=True,
                       timeout=timeout, **kw)
    if check and p.returncode != 0:
        sys.exit(f"fault-inject: {' '.join(map(str, args))} failed:\n{p.stderr}")
    return p


def sha(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def files_of(d):
    """Relative paths of the plain files under d (or d itself when it is a file set root)."""
    d = Path(d)
    return sorted(str(p.relative_to(d)) for p in d.rglob("*") if p.is_file())


def is_temp(name):
    return ".tmp-" in Path(name).name and Path(name).name.startswith(".")


# ---------------------------------------------------------------------------------------------
# Validators: return None when valid, else what is wrong.

def v_obj(path, ref):
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as e:
        return f"unreadable: {e}"
    if not text.endswith("\n"):
        return "no final newline (truncated)"
    nv = nf = 0
    for line in text.splitlines():
        if line.startswith("v "):
            parts = line.split()
            if len(parts) != 4:
                return f"bad vertex line {line!r}"
            try:
                [float(x) for x in parts[1:]]
            except ValueError:
                return f"bad vertex line {line!r}"
            nv += 1
        elif line.startswith("f "):
            nf += 1
    want = obj_counts(ref)
    return None if (nv, nf) == want else f"{nv} vertices / {nf} faces, expected {want}"


_OBJ_COUNTS = {}


def obj_counts(ref):
    if ref not in _OBJ_COUNTS:
        lines = Path(ref).read_text().splitlines()
        _OBJ_COUNTS[ref] = (sum(l.startswith("v ") for l in lines),
                            sum(l.startswith("f ") for l in lines))
    return _OBJ_COUNTS[ref]


def v_json(path, ref):
    try:
        v = json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        return f"not JSON: {e}"
    r = json.loads(Path(ref).read_text())
    if isinstance(r, dict):
        if not isinstance(v, dict) or set(v) != set(r):
            return "keys differ from the reference's"
        for k in ("frames", "n_frames"):
            if k not in r:
                continue
            if isinstance(r[k], list):
                # A list of per-frame rows (mocap solve's report): the same frames, the same
                # fields; their timings differ from run to run.
                got = v.get(k)
                if not isinstance(got, list) or len(got) != len(r[k]):
                    return f"{k} has {len(got) if isinstance(got, list) else got!r} rows, expected {len(r[k])}"
                if any(isinstance(a, dict) and set(a) != set(b) for a, b in zip(got, r[k])):
                    return f"{k}: a row's fields differ from the reference's"
            elif v.get(k) != r[k]:
                return f"{k} = {v.get(k)}, expected {r[k]}"
        if "per_frame" in r and len(v["per_frame"]) != len(r["per_frame"]):
            return "per_frame has the wrong length"
    return None


def v_png(path, ref):
    b = Path(path).read_bytes()
    if not b.startswith(b"\x89PNG\r\n\x1a\n"):
        return "no PNG signature"
    i = 8
    while i + 8 <= len(b):
        n = int.from_bytes(b[i:i + 4], "big")
        kind = b[i + 4:i + 8]
        i += 12 + n
        if kind == b"IEND":
            return None if i == len(b) else "bytes after IEND"
    return "no IEND chunk (truncated)"


def v_csv(path, ref):
    rows = [l.split(",") for l in Path(path).read_text().splitlines()]
    want = [l.split(",") for l in Path(ref).read_text().splitlines()]
    if len(rows) != len(want) or any(len(a) != len(b) for a, b in zip(rows, want)):
        return "rows or columns differ from the reference's"
    return None


def fnv1a(b):
    h = 0xcbf29ce484222325
    for x in b:
        h = ((h ^ x) * 0x100000001b3) & 0xFFFFFFFFFFFFFFFF
    return h


def v_state(path, ref):
    b = Path(path).read_bytes()
    if not b.startswith(b"PMTRKRS1") or len(b) < 16:
        return "no checkpoint magic"
    hl = int.from_bytes(b[8:16], "little")
    if 16 + hl > len(b):
        return "header longer than the file"
    try:
        h = json.loads(b[16:16 + hl])
    except ValueError:
        return "header is not JSON"
    if not 0 < h.get("frames_done", -1) <= N_FRAMES:
        return "bad frames_done"
    t = b[16 + hl:]
    if len(t) < 16 or not t.startswith(b"PMTRKCK1"):
        return "no tracker checkpoint"
    if fnv1a(t[:-8]) != int.from_bytes(t[-8:], "little"):
        return "tracker checksum mismatch"
    return None


def v_rows(path, ref):
    lines = Path(path).read_text().split("\n")
    # A journal: every line complete except possibly a torn last one (dropped by --resume).
    for l in lines[:-2]:
        try:
            json.loads(l)
        except ValueError:
            return "a complete line is not JSON"
    return None


_MODEL_OK = {}


def v_model(path, ref):
    h = sha(path)
    if h not in _MODEL_OK:
        out = WORK / "validate-pose.obj"
        p = sh(["pose", "--model", path, "--params", WORK / "zero-params.json", "--out", out],
               check=False)
        _MODEL_OK[h] = None if p.returncode == 0 else (p.stderr.strip().splitlines() or ["?"])[-1]
    return _MODEL_OK[h]


_DATA_OK = {}


def v_dataset(d):
    """panoman's dataset reader on directory d (via train --evaluate-only on a model copy)."""
    d = Path(d)
    key = tuple(sha(d / f) if (d / f).exists() else None
                for f in ("dataset.json", "dataset.safetensors"))
    if key not in _DATA_OK:
        m = WORK / "eval-model" / "M.safetensors"
        m.parent.mkdir(exist_ok=True)
        shutil.copy(WORK / "ref-train" / "M.safetensors", m)
        p = sh(["train", "--data", d, "--preset", "small", "--evaluate-only", "--skip-curves",
                "--out", m], check=False)
        _DATA_OK[key] = None if p.returncode == 0 else (p.stderr.strip().splitlines() or ["?"])[-1]
    return _DATA_OK[key]


def v_dataset_file(path, ref):
    return v_dataset(Path(path).parent)


def validator(name):
    n = Path(name).name
    if n in ("dataset.json", "dataset.safetensors"):
        return v_dataset_file
    if n == "state.bin":
        return v_state
    if n == "rows.jsonl":
        return v_rows
    if n.endswith(".obj"):
        return v_obj
    if n.endswith(".json"):
        return v_json
    if n.endswith(".png"):
        return v_png
    if n.endswith(".csv"):
        return v_csv
    if n.endswith(".safetensors"):
        return v_model
    return None


# Files whose bytes change from run to run (timings): validated, not compared.
def nondeterministic(name):
    n = Path(name).name
    return n in ("summary.json", "report.json", "M.report.json", "state.bin", "rows.jsonl", "lock")


# ---------------------------------------------------------------------------------------------
# The commands.

class Cmd:
    def __init__(self, name, args, out, prev_args, is_dir):
        self.name, self.args, self.out, self.prev_args, self.is_dir = name, args, out, prev_args, is_dir

    def argv(self, base, prev=False):
        a = self.prev_args if prev else self.args
        return [x.replace("{OUT}", str(base / self.out)) if isinstance(x, str) else x for x in a]

    def outputs(self, base):
        """Output files (relative to base) this command writes."""
        if self.is_dir:
            d = base / self.out
            return [str(Path(self.out) / f) for f in files_of(d)] if d.exists() else []
        stem = self.out[: -len(".safetensors")]
        names = [stem + x for x in (".safetensors", ".report.json", ".fig7.csv", ".fig7.png")]
        temps = [f for f in files_of(base) if is_temp(f) and any(f"/.{n}.tmp-" in f"/{f}" for n in names)]
        return [f for f in names if (base / f).exists()] + temps


def setup():
    zero = WORK / "zero-params.json"
    zero.write_text("{}\n")
    sh(["synth", "--preset", "small", "--out", WORK / "ref-synth" / "D"])
    sh(["synth", "--preset", "small", "--seed", "1", "--out", WORK / "prev-synth" / "D"])
    (WORK / "ref-train").mkdir()
    (WORK / "prev-train").mkdir()
    sh(["train", "--data", WORK / "ref-synth" / "D", "--preset", "small",
        "--out", WORK / "ref-train" / "M.safetensors"])
    sh(["train", "--data", WORK / "prev-synth" / "D", "--preset", "small",
        "--out", WORK / "prev-train" / "M.safetensors"])
    model = WORK / "ref-train" / "M.safetensors"
    # A clip: 6 key poses (generate + keypoints), linearly interpolated to N_FRAMES frames.
    keys = []
    for i in range(6):
        p = WORK / f"pose{i}.json"
        p.write_text(json.dumps({"pose_euler_xyz_deg": {"upperarm01.R": [0, 0, 10 * i],
                                                        "lowerarm01.R": [7 * i, 0, 0]},
                                 "root_rotation_z_deg": 4 * i}))
        m = WORK / f"pose{i}.obj"
        k = WORK / f"pose{i}.kp.json"
        sh(["generate", "--params", p, "--topology", "small", "--out", m])
        sh(["keypoints", "--mesh", m, "--topology", "small", "--out", k])
        keys.append(json.loads(k.read_text())["keypoints"])
    frames = WORK / "frames"
    frames.mkdir()
    for f in range(N_FRAMES):
        u = f / (N_FRAMES - 1) * 5
        i = min(int(u), 4)
        t = u - i
        kp = {n: [(1 - t) * a + t * b for a, b in zip(keys[i][n], keys[i + 1][n])] for n in keys[i]}
        (frames / f"frame_{f:03d}.json").write_text(json.dumps({"units": "m", "keypoints": kp}))
    track = ["track", "--model", model, "--frames", frames, "--out", "{OUT}"]
    mocap = ["mocap", "solve", "--markers", CSM, "--model", model, "--frames", "0:8", "--folds", "2",
             "--held-out-step", "4", "--calibration-frames", "4", "--out", "{OUT}"]
    synth = ["synth", "--preset", "small", "--out", "{OUT}"]
    train = ["train", "--data", WORK / "ref-synth" / "D", "--preset", "small", "--out", "{OUT}"]
    return [
        Cmd("synth", synth, "D", synth[:-2] + ["--seed", "1", "--out", "{OUT}"], True),
        Cmd("train", train, "M.safetensors",
            ["train", "--data", WORK / "prev-synth" / "D", "--preset", "small", "--out", "{OUT}"], False),
        Cmd("track", track, "T", track + ["--baseline", "lbs"], True),
        Cmd("mocap solve", mocap, "S", mocap + ["--method", "lbs"], True),
    ]


def run_ref(c, base, prev=False):
    base.mkdir(parents=True, exist_ok=True)
    t = time.monotonic()
    sh(c.argv(base, prev))
    return time.monotonic() - t


def check_tree(c, base, ref, prev):
    """Classifies what a run left under base: (state, problems, temp files)."""
    problems, temps = [], []
    left = c.outputs(base)
    refs = {f: sha(ref / f) for f in c.outputs(ref)}
    prevs = {f: sha(prev / f) for f in c.outputs(prev)} if prev else {}
    kinds = set()
    for f in left:
        p = base / f
        if is_temp(f):
            temps.append(f)
            continue
        if Path(f).name == "lock":
            continue
        h = sha(p)
        if h == refs.get(f):
            kinds.add("new")
        elif h == prevs.get(f):
            kinds.add("prev")
        elif nondeterministic(f) and f in refs:
            v = validator(f)
            why = v(p, ref / f) if v else None
            if why:
                problems.append(f"{f}: {why}")
            else:
                kinds.add("new")
        else:
            v = validator(f)
            why = v(p, ref / f) if (v and f in refs) else "unexpected file"
            problems.append(f"{f}: neither the reference nor the previous bytes"
                            + (f" and it does not load ({why})" if why else " but it LOADS AS VALID"))
    if c.name == "synth":
        d = base / c.out
        j, s = d / "dataset.json", d / "dataset.safetensors"
        if j.exists() and s.exists():
            pair = (sha(j), sha(s))
            ok_pairs = {(sha(ref / c.out / "dataset.json"), sha(ref / c.out / "dataset.safetensors"))}
            if prev:
                ok_pairs.add((sha(prev / c.out / "dataset.json"), sha(prev / c.out / "dataset.safetensors")))
            if pair not in ok_pairs:
                why = v_dataset(d)
                if why is None:
                    problems.append("dataset: files of two runs that panoman LOADS AS VALID")
                else:
                    kinds.add("refused-mixed")
    n_ref = len([f for f in refs if Path(f).name != "lock"])
    n_left = len([f for f in left if not is_temp(f) and Path(f).name != "lock"])
    if problems:
        state = "corrupt"
    elif n_left == 0:
        state = "none"
    elif kinds == {"prev"} and n_left == len([f for f in prevs if Path(f).name != "lock"]):
        state = "previous"
    elif kinds <= {"new"} and n_left == n_ref:
        state = "complete"
    else:
        state = "mixed"
    return state, problems, temps


def kill_trials(c, n, rng, t_ref, ref, prev):
    tally = {"none": 0, "previous": 0, "mixed": 0, "complete": 0, "corrupt": 0, "temp": 0}
    for i in range(n):
        base = WORK / f"trial-{c.name.replace(' ', '-')}-{i}"
        base.mkdir()
        with_prev = i % 2 == 1
        if with_prev:
            for f in c.outputs(prev):
                (base / f).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(prev / f, base / f)
        delay = rng.uniform(0, t_ref)
        p = subprocess.Popen([str(BIN)] + [str(a) for a in c.argv(base)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(delay)
        if p.poll() is None:
            os.kill(p.pid, signal.SIGKILL)
        p.wait()
        state, problems, temps = check_tree(c, base, ref, prev if with_prev else None)
        tally[state] += 1
        tally["temp"] += bool(temps)
        for q in problems:
            print(f"  CORRUPT {c.name} trial {i} (killed at {delay:.2f} s): {q}")
        shutil.rmtree(base)
    return tally


# ---------------------------------------------------------------------------------------------
# Fault scenarios.

def one_line_error(p, needle):
    """A non-zero exit whose stderr ends with exactly one `error: ` line naming `needle`
    (progress lines of the stages before it, e.g. train's timings, are allowed)."""
    lines = [l for l in p.stderr.splitlines() if l.strip()]
    errors = [l for l in lines if l.startswith("error: ")]
    return (p.returncode != 0 and len(errors) == 1 and lines[-1] == errors[0]
            and needle in errors[0] and "panicked" not in p.stderr), (lines[-1] if lines else "")


def mount_tmpfs(d, size):
    d.mkdir(parents=True, exist_ok=True)
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(d)],
                       capture_output=True, text=True)
    return p.returncode == 0


def umount(d):
    subprocess.run(["umount", str(d)], capture_output=True)


def full_disk(cmds, refs):
    res = {}
    for c in cmds:
        ref = refs[c.name]
        total = sum((ref / f).stat().st_size for f in c.outputs(ref))
        size = max(64, total // 2 // 1024)
        d = WORK / f"full-{c.name.replace(' ', '-')}"
        if not mount_tmpfs(d, f"{size}k"):
            return None
        try:
            p = sh(c.argv(d), check=False)
            good, line = one_line_error(p, str(d))
            state, problems, temps = check_tree(c, d, ref, None)
            ok = good and not problems and not temps and "space" in line.lower()
            res[c.name] = (ok, f"{size} KiB: {line}" + (f"; {problems}" if problems else "")
                           + (f"; temp files left {temps}" if temps else ""))
        finally:
            umount(d)
    return res


def read_only(cmds):
    res = {}
    for c in cmds:
        d = WORK / f"ro-{c.name.replace(' ', '-')}"
        if not mount_tmpfs(d, "1m"):
            return None
        try:
            if c.is_dir:
                (d / c.out).mkdir()
            subprocess.run(["mount", "-o", "remount,ro", str(d)], check=True)
            p = sh(c.argv(d), check=False)
            good, line = one_line_error(p, str(d))
            res[c.name] = (good, line)
        finally:
            umount(d)
    return res


def concurrent(c, ref, n, rng):
    """Two processes with the same arguments into one directory, n times."""
    outcomes = []
    for i in range(n):
        base = WORK / f"conc-{c.name}-{i}"
        base.mkdir()
        a = subprocess.Popen([str(BIN)] + [str(x) for x in c.argv(base)], stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
        time.sleep(rng.uniform(0, 0.5))
        b = subprocess.Popen([str(BIN)] + [str(x) for x in c.argv(base)], stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
        ea, eb = a.communicate()[1], b.communicate()[1]
        codes = (a.returncode, b.returncode)
        clean = all(rc == 0 or (len([l for l in e.splitlines() if l.strip()]) == 1
                                and e.startswith("error: "))
                    for rc, e in zip(codes, (ea, eb)))
        state, problems, temps = check_tree(c, base, ref, None)
        ok = clean and 0 in codes and state == "complete" and not temps
        outcomes.append((ok, "both succeeded" if codes == (0, 0) else
                         "one failed cleanly: " + (eb if b.returncode else ea).strip()))
        if not ok:
            print(f"  CONCURRENT {c.name} {i}: exit {codes}, {state}, {problems}, {temps}\n{ea}{eb}")
        shutil.rmtree(base)
    return outcomes


def resume_trials(c, ref, n, rng, t_ref):
    results = []
    for i in range(n):
        base = WORK / f"resume-{i}"
        base.mkdir()
        # Killed once a random number of frames (1 … N−2) are recorded.
        target = rng.randint(1, N_FRAMES - 2)
        rows = base / c.out / "track-resume" / "rows.jsonl"
        t = time.monotonic()
        p = subprocess.Popen([str(BIN)] + [str(a) for a in c.argv(base)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        while p.poll() is None and time.monotonic() - t < 10 * t_ref:
            if rows.exists() and rows.read_text().count("\n") >= target:
                break
            time.sleep(0.002)
        if p.poll() is None:
            os.kill(p.pid, signal.SIGKILL)
        p.wait()
        delay = time.monotonic() - t
        done = len(list((base / c.out).glob("*.obj")))
        r = sh(c.argv(base) + ["--resume"], check=False)
        same = all(sha(base / f) == sha(ref / f) for f in c.outputs(ref)
                   if not nondeterministic(f))
        s = json.loads((base / c.out / "summary.json").read_text()) if r.returncode == 0 else {}
        ok = r.returncode == 0 and same and s.get("frames") == N_FRAMES
        msg = [l for l in r.stderr.splitlines() if "resuming" in l]
        results.append((ok, f"killed at {delay:.2f} s with {done} frames written; "
                            + (msg[0] if msg else r.stderr.strip()[-200:])))
        shutil.rmtree(base)
    return results


def self_test(cmds, refs):
    """Each validator rejects a truncated copy of a reference output."""
    bad = []
    for c in cmds:
        ref = refs[c.name]
        seen = set()
        for f in c.outputs(ref):
            v = validator(f)
            if v in (None, v_dataset_file, v_rows) or v in seen:
                continue
            seen.add(v)
            if v(ref / f, ref / f) is not None:
                bad.append(f"{c.name}: validator rejects the reference {f}")
            t = WORK / "truncated" / f
            t.parent.mkdir(parents=True, exist_ok=True)
            b = (ref / f).read_bytes()
            t.write_bytes(b[: len(b) * 2 // 3])
            if v(t, ref / f) is None:
                bad.append(f"{c.name}: validator accepts a truncated {f}")
        if c.name == "synth":
            if v_dataset(ref / c.out) is not None:
                bad.append("the reference dataset does not load")
            cut = WORK / "truncated-dataset" / "D"
            cut.mkdir(parents=True)
            shutil.copy(ref / "D" / "dataset.json", cut)
            b = (ref / "D" / "dataset.safetensors").read_bytes()
            (cut / "dataset.safetensors").write_bytes(b[: len(b) * 2 // 3])
            if v_dataset(cut) is None:
                bad.append("a dataset with truncated tensors loads")
            mixed = WORK / "mixed" / "D"
            mixed.mkdir(parents=True)
            shutil.copy(ref / "D" / "dataset.safetensors", mixed)
            shutil.copy(WORK / "prev-synth" / "D" / "dataset.json", mixed)
            if v_dataset(mixed) is None:
                bad.append("a dataset mixed from two runs loads")
    return bad


def main():
    global BIN, WORK
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", default=str(ROOT / "target/release/panoman"))
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--quick", action="store_true", help="5 kill trials per command, fewer scenarios")
    ap.add_argument("--seed", type=int, default=17)
    ap.add_argument("--keep", action="store_true", help="keep the work directory")
    a = ap.parse_args()
    BIN = Path(a.bin).resolve()
    if not BIN.is_file():
        sys.exit(f"fault-inject: {BIN}: no such binary (cargo build --release -p panoman-cli)")
    trials = 5 if a.quick else a.trials
    rng = random.Random(a.seed)
    WORK = Path(tempfile.mkdtemp(prefix="panoman-fault-"))
    t0 = time.monotonic()
    try:
        print(f"fault-inject: {BIN}, work {WORK}, {trials} kill trials per command, seed {a.seed}")
        cmds = setup()
        refs, prevs, times = {}, {}, {}
        for c in cmds:
            slug = c.name.replace(" ", "-")
            refs[c.name] = WORK / f"ref-{slug}"
            prevs[c.name] = WORK / f"prev-{slug}"
            if c.name in ("synth", "train"):
                times[c.name] = run_ref(c, WORK / f"time-{slug}")  # timed on a fresh location
                shutil.rmtree(WORK / f"time-{slug}")
            else:
                times[c.name] = run_ref(c, refs[c.name])
                run_ref(c, prevs[c.name], prev=True)
        bad = self_test(cmds, refs)
        for b in bad:
            print(f"  VALIDATOR {b}")
            FAILURES.append(b)
        rows = []
        for c in cmds:
            tally = kill_trials(c, trials, rng, times[c.name], refs[c.name], prevs[c.name])
            rows.append((c.name, trials, times[c.name], tally))
        print()
        print(f"{'command':<12} {'trials':>6} {'run s':>6} {'none':>5} {'prev kept':>9} "
              f"{'partial*':>8} {'complete':>8} {'temp left':>9} {'corrupt':>7}")
        for name, n, t, k in rows:
            print(f"{name:<12} {n:>6} {t:>6.1f} {k['none']:>5} {k['previous']:>9} {k['mixed']:>8} "
                  f"{k['complete']:>8} {k['temp']:>9} {k['corrupt']:>7}")
        print("  none: killed before any output; prev kept: only the previous version's files;"
              "\n  partial*: some files new, others absent or previous (each one complete);"
              "\n  temp left: a dead process's hidden .<name>.tmp-<pid> file (removed by the next"
              " writer);\n  corrupt: a file that is neither the reference, the previous version"
              " nor valid.")
        corrupt = sum(k["corrupt"] for _, _, _, k in rows)

        print()
        scen = []
        fd = full_disk(cmds, refs)
        if fd is None:
            print("full disk: SKIPPED (mount -t tmpfs not permitted here)")
        else:
            for name, (ok, why) in fd.items():
                scen.append(("full disk", name, ok, why))
        ro = read_only(cmds)
        if ro is None:
            print("read-only: SKIPPED (mount -t tmpfs not permitted here)")
        else:
            for name, (ok, why) in ro.items():
                scen.append(("read-only", name, ok, why))
        n_conc = 2 if a.quick else 5
        for c in cmds:
            if c.name in ("synth", "track"):
                for ok, why in concurrent(c, refs[c.name], n_conc, rng):
                    scen.append(("concurrent", c.name, ok, why))
        track = next(c for c in cmds if c.name == "track")
        for ok, why in resume_trials(track, refs["track"], 2 if a.quick else 5, rng, times["track"]):
            scen.append(("kill + resume", "track", ok, why))
        for kind, name, ok, why in scen:
            print(f"{'ok  ' if ok else 'FAIL'} {kind:<13} {name:<12} {why}")
            if not ok:
                FAILURES.append(f"{kind} {name}")
        print()
        print(f"corrupt outputs: {corrupt}; scenario failures: {len(FAILURES)}; "
              f"{time.monotonic() - t0:.0f} s")
        return 1 if corrupt or FAILURES else 0
    finally:
        if a.keep:
            print(f"kept {WORK}")
        else:
            shutil.rmtree(WORK, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
