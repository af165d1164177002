"""The plant step's speed before and after a change, as a ratio of alternating runs (session 37, s37_rlimit).

Session 37 gave the quasi-static step (R = 0) the amplifier's current limit; the step with R in must not slow
down. This script extracts an earlier revision's ``workbench`` (``git archive``, default ``f975e1a``, the change's
base) beside this checkout and times both in child processes, alternately (old, new, old, new, ...), so the
machine's load falls on both alike:

* ``open_rin``: ``PZTSimulator.run`` on the SN637 creep plant, R in, 10 kHz, ``workbench bench``'s drive;
* ``closed_rin``: the closed-loop hold of ``workbench bench`` (``ClosedLoop.run``: ``pzt_advance`` inlined in
  ``verify.closed_loop._loop``), R in;
* ``open_rout``: the same open-loop run with the resistor out (the changed branch: expected slower, it now reads
  Q from G's plays and moves G's plays too).

Each child warms up (compiles, or loads its numba cache) and keeps the best thread CPU time of three calls. The
ratio new / old per pair and its median over the pairs are printed (JSON with ``--json``). ``--aa`` runs the old
revision on both sides: the ratio's noise on this machine. ``--in-process REPS``: the open-loop runs only, both
kernels modules loaded side by side in one child and interleaved call by call (steadier under load: at load 3-4,
f975e1a against this change 1.05-1.07 median with R in, its own copy against itself 0.99).

    PYTHONPATH=. python benchmarks/rlimit_speed.py [--old f975e1a] [--pairs 8] [--steps 2000000] [--aa]
    PYTHONPATH=. python benchmarks/rlimit_speed.py --in-process 30 [--aa]
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time, dataclasses
import numpy as np
from workbench.plant import load_plant, PZTSimulator
from workbench.bench import _drive, _hold
steps = int(sys.argv[1])
root = sys.argv[2]
plant = root + "/plants/p888_51_sn637_creep.toml"
ctrl = root + "/controllers/sn637_loopshape.json"
pl = load_plant(plant)
v = _drive(steps)
out = {}
for name, pz in (("open_rin", pl.pzt), ("open_rout", pl.pzt.with_resistance(0.0))):
    sim = PZTSimulator(pz, 1e-4)
    sim.run(v[:1000])
    best = float("inf")
    for _ in range(3):
        sim.reset()
        c0 = time.thread_time()
        sim.run(v, decimate=1000)
        best = min(best, time.thread_time() - c0)
    out[name] = best
cl, ref = _hold(plant, ctrl)
cl.run(ref, periods=1000)
best = float("inf")
for _ in range(3):
    cl, ref = _hold(plant, ctrl)
    c0 = time.thread_time()
    cl.run(ref, decimate=1000, periods=steps)
    best = min(best, time.thread_time() - c0)
out["closed_rin"] = best
print(json.dumps(out))
"""


INPROC = r"""
import importlib.util, json, sys, time
import numpy as np
from workbench.plant import load_plant, PZTSimulator
from workbench.bench import _drive
old_path, new_path, root, n, reps = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5])
mods = []
for name, path in (("kernels_old", old_path), ("kernels_new", new_path)):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mods.append(mod)
old, new = mods
pl = load_plant(root + "/plants/p888_51_sn637_creep.toml")
v = _drive(n)
f = np.zeros(n)
out = {}
for name, pz in (("open_rin", pl.pzt), ("open_rout", pl.pzt.with_resistance(0.0))):
    sim = PZTSimulator(pz, 1e-4)
    st0 = sim.st.copy()
    rec = np.empty((n // 1000, 6))
    for mod in (old, new):
        mod.pzt_run(sim.m, st0.copy(), v[:1000], f[:1000], 1, 1000, rec)
    t = {"old": [], "new": []}
    recs = {}
    for k in range(reps):
        for key, mod in ((("old", old), ("new", new)) if k % 2 == 0 else (("new", new), ("old", old))):
            st = st0.copy()
            c0 = time.thread_time()
            mod.pzt_run(sim.m, st, v, f, 1, 1000, rec)
            t[key].append(time.thread_time() - c0)
            recs[key] = rec.copy()
    r = np.array(t["new"]) / np.array(t["old"])
    out[name] = {"median": float(np.median(r)), "q25": float(np.percentile(r, 25)), "q75": float(np.percentile(r, 75)),
                 "old_best_s": min(t["old"]), "new_best_s": min(t["new"]),
                 "records_identical": bool(np.array_equal(recs["old"], recs["new"]))}
print(json.dumps(out))
"""


def _inproc(old_tree, new_tree, steps, reps):
    """``pzt_run`` of the two trees' kernels modules, loaded side by side in one child and interleaved call by call
    (the same m, state and drive: the layout is the same); a fresh numba cache (modules loaded from a path are not
    reloadable from one)."""
    with tempfile.TemporaryDirectory(prefix="rlimit_nbc_") as cache:
        env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1", NUMBA_CACHE_DIR=cache)
        r = subprocess.run([sys.executable, "-c", INPROC, str(Path(old_tree) / "workbench/plant/kernels.py"),
                            str(Path(new_tree) / "workbench/plant/kernels.py"), str(ROOT), str(steps), str(reps)],
                           env=env, capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def _extract(rev, dest):
    """``git archive rev workbench`` unpacked into ``dest``; the path."""
    arc = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "workbench"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=arc, check=True)
    return Path(dest)


def _child(tree, steps):
    env = dict(os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1")
    r = subprocess.run([sys.executable, "-c", CHILD, str(steps), str(ROOT)], env=env, capture_output=True, text=True,
                       check=True, cwd=str(tree))
    return json.loads(r.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", default="f975e1a", help="the revision before the change (default f975e1a)")
    ap.add_argument("--pairs", type=int, default=8)
    ap.add_argument("--steps", type=int, default=2_000_000)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--aa", action="store_true", help="an A/A control: the old revision on both sides (the noise "
                                                      "of the ratio on this machine)")
    ap.add_argument("--in-process", type=int, metavar="REPS", default=0,
                    help="instead: pzt_run of both kernels modules in one process, REPS calls each interleaved (the "
                         "steadier figure under load)")
    args = ap.parse_args(argv)
    import numpy as np
    with tempfile.TemporaryDirectory(prefix="rlimit_old_") as tmp:
        old = _extract(args.old, tmp)
        new = ROOT
        if args.aa:
            Path(tmp, "b").mkdir()
            new = _extract(args.old, Path(tmp, "b"))
        if args.in_process:
            res = _inproc(old, new, args.steps, args.in_process)
            for key, r in res.items():
                print(f"{key}: new / old median {r['median']:.3f} (quartiles {r['q25']:.3f}-{r['q75']:.3f}); best CPU "
                      f"{r['old_best_s']:.4f} s -> {r['new_best_s']:.4f} s; records identical: {r['records_identical']}")
            if args.json:
                args.json.write_text(json.dumps({"old": args.old, "aa": args.aa, "in_process": res}, indent=1))
            return
        _child(old, 1000)                      # compile both once (their numba caches), untimed
        _child(new, 1000)
        pairs = []
        for k in range(args.pairs):
            a, b = (_child(old, args.steps), _child(new, args.steps)) if k % 2 == 0 else \
                tuple(reversed((_child(new, args.steps), _child(old, args.steps))))
            pairs.append({"old": a, "new": b, "load": os.getloadavg()})
            print(f"pair {k + 1}: " + ", ".join(f"{key} {b[key] / a[key]:.3f}" for key in a), flush=True)
    keys = pairs[0]["old"].keys()
    ratios = {key: [p["new"][key] / p["old"][key] for p in pairs] for key in keys}
    summary = {key: {"median": float(np.median(r)), "min": float(min(r)), "max": float(max(r)),
                     "old_best_s": min(p["old"][key] for p in pairs), "new_best_s": min(p["new"][key] for p in pairs)}
               for key, r in ratios.items()}
    for key, s in summary.items():
        print(f"{key}: new / old median {s['median']:.3f} (pairs {s['min']:.3f}-{s['max']:.3f}); best CPU "
              f"{s['old_best_s']:.3f} s -> {s['new_best_s']:.3f} s over {args.steps} steps")
    if args.json:
        args.json.write_text(json.dumps({"old": args.old, "aa": args.aa, "steps": args.steps, "pairs": pairs,
                                         "summary": summary}, indent=1))


if __name__ == "__main__":
    main()
