"""s22_outsider: records outside the confusion benchmark's draws, calibrated as `workbench calibrate` does.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/outsider/harness.py CASE [--seed S ...]

Each case simulates a record (workbench.calibrate.synthetic.simulate_record) of a plant with or without an
effect (plant_with_effect), writes it as the CLI's CSV, calibrates it through run_calibrate (the CLI's
function, figures off), and prints the answer; with an effect, the clean twin (same drive, same noise)
is calibrated too and the effect's size is sqrt(before^2 - floor^2) / floor on its channel (as the
confusion benchmark measures it, here on the run's own split).
"""
import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
from workbench.calibrate.run import run_calibrate  # noqa: E402
from workbench.calibrate.synthetic import plant_with_effect, simulate_record, write_record  # noqa: E402
from workbench.plant import load_plant  # noqa: E402

CHANNEL = {"creep": "displacement", "dielectric_absorption": "charge", "leakage": "charge",
           "resonance": "displacement", "delay": "displacement", "drift": "displacement",
           "gauge_nonlinearity": "gauge"}
TMP = Path(tempfile.mkdtemp(prefix="s22_outsider_"))


# ---------------------------------------------------------------- drives (t, v) in terminal-ish volts
def triangle(rate, dur, f, lo=0.0, hi=100.0, rest=0.1):
    t = np.arange(int(round(dur * rate))) / rate
    ph = np.clip(t - rest * dur, 0, None) * f
    tri = 2 * np.abs(ph - np.floor(ph + 0.5))          # 0..1
    return t, lo + (hi - lo) * tri


def multisine(rate, dur, f0, f1, n=12, lo=0.0, hi=100.0, seed=0, rest=0.05):
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(dur * rate))) / rate
    fs = np.geomspace(f0, f1, n)
    s = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f in fs)
    s = (s - s.min()) / (s.max() - s.min())
    w = np.clip(t / (rest * dur), 0, 1) if rest else 1.0   # ramp in from rest
    return t, lo + (hi - lo) * s * w if lo == 0 else lo + (hi - lo) * s


def sine(rate, dur, f, lo=0.0, hi=100.0, phase=-np.pi / 2, rest=0.0):
    t = np.arange(int(round(dur * rate))) / rate
    s = 0.5 * (1 + np.sin(2 * np.pi * f * t + phase))
    return t, lo + (hi - lo) * s


def steps(rate, dur, levels, rest=0.05):
    t = np.arange(int(round(dur * rate))) / rate
    v = np.zeros_like(t)
    t0 = rest * dur
    hold = (dur - t0) / len(levels)
    for k, L in enumerate(levels):
        v[t >= t0 + k * hold] = L
    return t, v


def simulate(plant0, effect, t, v, seed, size, channels=None):
    plant, truth = plant_with_effect(plant0, effect, seed, duration_s=float(t[-1]), size=size)
    r = simulate_record(plant, t, v, seed=seed)
    if channels:
        r = {k: r[k] for k in ["time_s", "voltage_v", *channels]}
    return r, truth


def calibrate(r, plant_path, tag, split=None, meta=None):
    p = TMP / f"{tag}.csv"
    write_record(p, {k: r[k] for k in ("time_s", "voltage_v", "current_a", "displacement_m", "gauge_v") if k in r}, meta)
    t0 = time.perf_counter()
    try:
        out = run_calibrate(p, plant_path, split=split, figures=False)
    except Exception as e:                       # noqa: BLE001
        return {"error": f"{type(e).__name__}: {e}"[:300], "s": time.perf_counter() - t0}
    out["s"] = time.perf_counter() - t0
    return out


def base_rms(res, ch):
    c = (res.get("base_fit") or {}).get("channels", {}).get(ch)
    if not c:
        return None
    return c.get("rms_test", c.get("test", {}).get("rms") if isinstance(c.get("test"), dict) else None)


def summary(res):
    if "error" in res:
        return f"ERROR {res['error']}"
    st = [s["effect"] for s in res.get("stages", [])]
    eb, ea = res.get("error_before") or {}, res.get("error_after") or {}
    ratio = (ea.get("rms") / eb.get("rms")) if eb.get("rms") and ea.get("rms") else float("nan")
    warn = len((res.get("base_fit") or {}).get("warnings", []) or [])
    return (f"{res.get('effect'):<22} stages={'+'.join(st) or '-':<30} agr={res.get('agreement')} ch={res.get('channel')} "
            f"ratio={ratio:.3g} warn={warn} {res['s']:.1f}s")


def run_case(plant_path, effect, t, v, seed, size, tag, channels=None, split=None, meta=None, twin=True):
    plant0 = load_plant(plant_path)
    effects = () if effect == "none" else ((effect,) if isinstance(effect, str) else tuple(effect))
    r, truth = simulate(plant0, effects or "none", t, v, seed, size, channels)
    res = calibrate(r, plant_path, tag, split, meta)
    sizes = []
    if effects and twin and "error" not in res:
        r0, _ = simulate(plant0, "none", t, v, seed, size, channels)
        res0 = calibrate(r0, plant_path, tag + "_clean", split, meta)
        ch0 = res0.get("channels_rms") if "error" not in res0 else None
        for e in effects:
            ch = CHANNEL[e]
            b = _test_rms(res, ch)
            f = _test_rms(res0, ch)
            sizes.append(round(float(np.sqrt(max(b ** 2 - f ** 2, 0)) / f), 2) if (b and f) else None)
        res["_clean"] = summary(res0)
    named = [s["effect"] for s in res.get("stages", [])] if "error" not in res else []
    cls = "error" if "error" in res else ("none" if not named else ("WRONG" if any(n not in effects for n in named) else "right"))
    line = f"{tag:<40} {'+'.join(effects) or 'none':<28} sizes={sizes} -> {cls:<5} {summary(res)}"
    print(line, flush=True)
    if "_clean" in res:
        clean_named = res["_clean"].split()[0]
        if clean_named not in ("none", "inconclusive"):
            print(f"{'  (clean twin)':<40} none -> WRONG {res['_clean']}", flush=True)
    return res, cls, sizes, truth


def _test_rms(res, ch):
    if "error" in res:
        return None
    bf = res.get("base_fit") or {}
    c = (bf.get("channels") or {}).get(ch)
    if c is None:
        return None
    return c.get("rms")
