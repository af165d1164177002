"""s34_foreign: NEW draws of gen.py (new noise seeds AND new parameter values) for A1/A2, main vs a branch.

    cd WORKTREE && OPENBLAS_NUM_THREADS=1 /work/main/.venv/bin/python benchmarks/outsider2/fresh.py --draw-seed S \
        --n-clean N --n-creep M --trees /work/main /work/wt/s34_foreign [--out logs/fresh_S.jsonl]

Clean records: a sine or a triangle, 0.1-20 Hz (log-uniform), at 100 Hz-100 kHz (one of the four decades, at least
50 samples a cycle, at most 300,000 rows), 5-9 cycles after a 0.5 s rest; the Preisach density's width r0 0.05-0.2
of the span, its mean spread 0.2-0.8 and centre 0.35-0.55 (gen.py used 0.10 / 0.35 / 0.45), rest state on the
descending branch or demagnetised (1 in 3); the P-888 rig (gauge) or the small one (no gauge, generic plant).
Creep records: the P-888 rig, a steps drive of 5-8 random levels, 2-5 s holds, at 1 or 10 kHz, a Kelvin creep
10-60x the displacement's noise (batch.py's size). Each record's CLI answer is run with each tree's code (cwd and
PYTHONPATH the tree: ``python -m`` puts the cwd first; ``TREE::ARGS`` adds CLI arguments). One JSON line per
(record, tree).
"""
import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import batch  # noqa: E402
import gen  # noqa: E402

PY = "/work/main/.venv/bin/python"


def draw_clean(rng, k, cycles=None, rest_s="yes"):
    """A clean periodic record (the module notes); ``cycles`` (lo, hi): a float cycle count, log-uniform, and
    ``rest_s`` "yes" / "no" / "both": the 0.5 s rest before the drive (s37_short; None / "yes": the original draw)."""
    rig = "p888" if rng.random() < 0.7 else "small"
    shape = "sine" if rng.random() < 0.6 else "tri"
    lead = 0.5
    if cycles is not None and rest_s != "yes":
        lead = 0.0 if rest_s == "no" or rng.random() < 0.5 else 0.5
    for _ in range(100):
        f = float(np.exp(rng.uniform(np.log(0.1), np.log(20.0))))
        rate = float(rng.choice([100.0, 1e3, 1e4, 1e5]))
        n_cyc = (int(rng.integers(5, 10)) if cycles is None else
                 float(np.exp(rng.uniform(np.log(cycles[0]), np.log(cycles[1])))))
        dur = lead + n_cyc / f
        if rate / f >= 50 and dur * rate <= 3e5:
            break
    pre = {"r0_frac": float(rng.uniform(0.05, 0.2)), "m_sigma_frac": float(rng.uniform(0.2, 0.8)),
           "m_center_frac": float(rng.uniform(0.35, 0.55))}
    rest = "demag" if rng.random() < 1 / 3 else "descending"
    c = dict(name=f"fresh{k}_{rig}_{shape}{f:.3g}Hz_{rate:g}Hz", kind="clean", rig=rig, shape=shape, f=f,
             rate=rate, dur=dur, preisach=pre, rest=rest, seed=int(rng.integers(1000, 10**6)))
    if cycles is not None:
        c.update(cycles=n_cyc, lead_s=lead, name=f"fresh{k}_{rig}_{shape}{f:.3g}Hz_{n_cyc:.2f}cyc_{rate:g}Hz"
                 + ("_norest" if lead == 0 else ""))
    return c


def draw_periodic_effect(rng, k, kind, cycles, rest_s):
    """A short periodic record of :func:`draw_clean`'s draw with a structural mode or a sensor latency (s37_short)."""
    c = draw_clean(rng, k, cycles, rest_s)
    c["kind"] = kind
    if kind == "mode":
        hi = c["rate"] / 3.0 / c["f"]
        ratio = float(np.exp(rng.uniform(np.log(3.0), np.log(max(min(40.0, hi), 3.01)))))
        c["mode"] = [ratio * c["f"], float(rng.uniform(0.01, 0.05))]
        c["name"] = c["name"].replace("fresh", "fmode", 1) + f"_mode{c['mode'][0]:.4g}Hz"
    else:
        c["delay_samples"] = float(np.exp(rng.uniform(np.log(0.5), np.log(30.0))))
        c["name"] = c["name"].replace("fresh", "fdelay", 1) + f"_delay{c['delay_samples']:.3g}"
    return c


def draw_creep(rng, k):
    rate = float(rng.choice([1e3, 1e4]))
    n = int(rng.integers(5, 9))
    hold = float(rng.uniform(2.0, 5.0))
    levels = [float(x) for x in rng.uniform(0.05, 1.0, n)]
    pre = {"r0_frac": float(rng.uniform(0.05, 0.2)), "m_sigma_frac": float(rng.uniform(0.2, 0.8)),
           "m_center_frac": float(rng.uniform(0.35, 0.55))}
    size = float(np.exp(rng.uniform(np.log(10.0), np.log(60.0))))
    rest = "demag" if rng.random() < 1 / 3 else "descending"
    return dict(name=f"fresh{k}_creep{size:.0f}_steps_{rate:g}Hz", kind="creep", rig="p888", shape="steps",
                levels=levels, hold=hold, rate=rate, dur=0.5 + n * hold, preisach=pre, rest=rest, size=size,
                seed=int(rng.integers(1000, 10**6)))


def build(c):
    p = gen.RIGS[c["rig"]]
    t = np.arange(int(round(c["dur"] * c["rate"]))) / c["rate"]
    vmax = p["drive_max"]
    lead = c.get("lead_s", 0.5)
    drive = (gen.drive_sine(c["f"], vmax, rest=lead) if c["shape"] == "sine" else
             gen.drive_triangle(c["f"], vmax, rest=lead) if c["shape"] == "tri" else
             gen.drive_steps(c["levels"], c["hold"], vmax))
    kw = dict(preisach=c["preisach"], rest=c["rest"])
    clean = gen.simulate(c["rig"], t, drive, **kw)
    sim, size = clean, None
    if c["kind"] == "mode":
        sim = gen.simulate(c["rig"], t, drive, mode=tuple(c["mode"]), **kw)
        size = batch._size(sim["x"] - clean["x"], clean["x"], p["noise_x"])
    elif c["kind"] == "delay":
        tau = c["delay_samples"] / c["rate"]
        sim = dict(clean, x=np.interp(t - tau, t, clean["x"]))
        size = batch._size(sim["x"] - clean["x"], clean["x"], p["noise_x"])
    if c["kind"] == "creep":
        s1 = gen.simulate(c["rig"], t, drive, creep_gamma=0.02, **kw)
        g = 0.02 * c["size"] / batch._size(s1["x"] - clean["x"], clean["x"], p["noise_x"])
        sim = gen.simulate(c["rig"], t, drive, creep_gamma=g, **kw)
        size = batch._size(sim["x"] - clean["x"], clean["x"], p["noise_x"])
    rec = gen.add_noise(sim, c["rig"], c["seed"], gauge=c["rig"] == "p888")
    meta = {"series_resistor_ohm": p["R"]}
    if c["rig"] == "p888":
        meta["serial"] = "SN637"
    return rec, meta, p["plant"], size


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--draw-seed", type=int, required=True)
    ap.add_argument("--n-clean", type=int, default=8)
    ap.add_argument("--n-creep", type=int, default=3)
    ap.add_argument("--trees", nargs="+", required=True)
    ap.add_argument("--out", default=None)
    ap.add_argument("--list", action="store_true")
    ap.add_argument("--cycles", type=float, nargs=2, default=None, metavar=("LO", "HI"),
                    help="periodic records' cycle count, log-uniform over [LO, HI] (default: the integer 5-9)")
    ap.add_argument("--rest", choices=("yes", "no", "both"), default="yes",
                    help="with --cycles: the 0.5 s rest before the drive, none, or either (default yes)")
    ap.add_argument("--n-mode", type=int, default=0)
    ap.add_argument("--n-delay", type=int, default=0)
    ap.add_argument("--only", type=int, nargs="+", default=None, help="run only these case indices")
    a = ap.parse_args()
    rng = np.random.default_rng(a.draw_seed)
    cases = [draw_clean(rng, k, a.cycles, a.rest) for k in range(a.n_clean)] + [draw_creep(rng, a.n_clean + k) for k in range(a.n_creep)]
    if a.n_mode or a.n_delay:
        cyc = a.cycles or (5.0, 9.0)
        n0 = len(cases)
        cases += [draw_periodic_effect(rng, n0 + k, "mode", cyc, a.rest) for k in range(a.n_mode)]
        cases += [draw_periodic_effect(rng, n0 + a.n_mode + k, "delay", cyc, a.rest) for k in range(a.n_delay)]
    if a.only is not None:
        cases = [cases[i] for i in a.only]
    if a.list:
        for c in cases:
            print(json.dumps(c))
        return
    out = Path(a.out or HERE / "logs" / f"fresh_{a.draw_seed}.jsonl")
    d = Path(os.environ.get("FRESH_TMP", "/tmp/s34f_fresh"))
    d.mkdir(exist_ok=True)
    for c in cases:
        rec, meta, plant, size = build(c)
        csv = d / f"{c['name']}.csv"
        gen.write_csv(csv, rec, meta)
        for spec in a.trees:
            tree, _, extra = spec.partition("::")          # TREE::EXTRA CLI ARGS (e.g. "::--rest-state used")
            tag = Path(tree).name + (extra.replace(" ", "").replace("--", "_") if extra else "")
            js = d / f"{c['name']}__{tag}.json"
            cmd = [PY, "-m", "workbench", "calibrate", str(csv), "--plant", str(Path(tree) / plant), "--json", str(js)]
            cmd += extra.split()
            t0 = time.time()
            env = {**os.environ, "PYTHONPATH": tree, "OPENBLAS_NUM_THREADS": "1"}
            pr = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
            ans = json.loads(js.read_text()) if pr.returncode == 0 and js.exists() else {}
            right = {"clean": None, "creep": "creep", "mode": "resonance", "delay": "delay"}[c["kind"]]
            line = {"case": c, "size": size, "tree": spec, "rc": pr.returncode, "s": round(time.time() - t0, 1),
                    "effect": ans.get("effect"), "channel": ans.get("channel"), "agreement": ans.get("agreement"),
                    "stages": [s.get("effect") + "/" + s.get("channel") for s in ans.get("stages", [])],
                    "reason": ans.get("reason"), "rest_state": (ans.get("base_fit") or {}).get("rest_state"),
                    "err": pr.stderr[-400:] if pr.returncode else ""}
            eff = line["effect"]
            line["verdict"] = ("refused" if pr.returncode == 2 else "crash" if pr.returncode else
                               ("none" if eff in ("none", "inconclusive") else
                                "right" if eff == right else "wrong"))
            print(f"{c['name']:42s} {c['rest']:10s} {tag:28s} {line['verdict']:6s} {eff} "
                  f"{line['channel']} {line['agreement']} stages {line['stages']} ({line['s']} s)", flush=True)
            with open(out, "a") as fh:
                fh.write(json.dumps(line) + "\n")


if __name__ == "__main__":
    main()
