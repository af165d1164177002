"""s34_outsider: records from gen.py (an independent simulator) calibrated by the CLI, one at a time.

    cd WORKTREE && OPENBLAS_NUM_THREADS=1 /work/main/.venv/bin/python benchmarks/outsider2/batch.py [--only NAME ...]
        [--list] [--keep DIR]

Each case: a rig (RIGS), a configuration (rate, drive, length), zero, one or two effects at a target size
(x the sensor's white-noise RMS on the effect's channel). The record is written as the CLI's CSV and run as
``python -m workbench calibrate REC --plant PLANT --json OUT`` (no --out: no figures, no plant file);
one line per record is appended to logs/results.jsonl.

Size: the effect's contribution to its channel (the record minus its clean twin, same drive and noise), less
its least-squares affine fit in the clean channel (what a gain/offset absorbs), RMS over the whole record,
over the channel's noise RMS.
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
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))
import gen  # noqa: E402

PY = "/work/main/.venv/bin/python"
LOG = HERE / "logs" / "results.jsonl"

# expected name per effect (None: no name fits; the right answer is none/inconclusive)
RIGHT = {"creep": "creep", "drift_lin": "drift", "drift_sine": "drift", "bow": "gauge_nonlinearity",
         "delay": "delay", "mode": "resonance", "hum": None, "slew": None, "quant": None, "glitch": None,
         "gain": None}
CHANNEL = {"creep": "displacement", "drift_lin": "displacement", "drift_sine": "displacement", "bow": "gauge",
           "delay": "displacement", "mode": "displacement", "hum": "displacement", "slew": "displacement",
           "quant": "displacement", "glitch": "displacement", "gain": "displacement"}


def config(name):
    """(rig, t, drive, gauge?, mode params by rate)"""
    C = {
        "p_1k_proto": ("p888", 1e3, "proto", None), "p_100_proto": ("p888", 100, "proto", None),
        "p_10k_proto": ("p888", 1e4, "proto", None), "p_1k_tri": ("p888", 1e3, ("tri", 0.5), 20.0),
        "p_10k_sine": ("p888", 1e4, ("sine", 2.0), 5.0), "p_100k_sine": ("p888", 1e5, ("sine", 20.0), 1.5),
        "p_100_msine": ("p888", 100, ("msine", 0.02, 3.0), 60.0), "p_1k_steps": ("p888", 1e3, ("steps",), 30.0),
        "s_1k_sine": ("small", 1e3, ("sine", 1.0), 20.0), "s_10k_tri": ("small", 1e4, ("tri", 5.0), 4.0),
        "s_100_msine": ("small", 100, ("msine", 0.02, 3.0), 60.0), "s_1k_steps": ("small", 1e3, ("steps",), 30.0),
        "s_1k_proto": ("small", 1e3, "proto", None),
        # extra clean drives (cases_extra)
        "p_1k_sine0.2": ("p888", 1e3, ("sine", 0.2), 30.0), "p_1k_sine1": ("p888", 1e3, ("sine", 1.0), 12.0),
        "p_1k_sine5": ("p888", 1e3, ("sine", 5.0), 4.0), "p_10k_sine10": ("p888", 1e4, ("sine", 10.0), 2.0),
        "p_100_sine0.5": ("p888", 100, ("sine", 0.5), 30.0), "s_10k_sine5": ("small", 1e4, ("sine", 5.0), 3.0),
        "s_100k_sine50": ("small", 1e5, ("sine", 50.0), 0.8), "p_1k_tri0.2": ("p888", 1e3, ("tri", 0.2), 30.0),
        "p_10k_tri2": ("p888", 1e4, ("tri", 2.0), 5.0), "s_1k_tri1": ("small", 1e3, ("tri", 1.0), 20.0),
        "p_1k_msine": ("p888", 1e3, ("msine", 0.1, 20.0), 20.0), "s_1k_msine": ("small", 1e3, ("msine", 0.1, 20.0), 20.0),
    }
    rig, rate, dspec, dur = C[name]
    vmax = gen.RIGS[rig]["drive_max"]
    if dspec == "proto":
        t, drive = gen.drive_protocol(rate, vmax)
    else:
        t = np.arange(int(round(dur * rate))) / rate
        kind = dspec[0]
        if kind == "tri":
            drive = gen.drive_triangle(dspec[1], vmax)
        elif kind == "sine":
            drive = gen.drive_sine(dspec[1], vmax)
        elif kind == "msine":
            drive = gen.drive_multisine(dspec[1], dspec[2], vmax, seed=3)
        else:
            drive = gen.drive_steps([.3, .7, 1, .5, .1, .8, .2], 4.0, vmax)
    return rig, rate, t, drive


def mode_for(rate, where):
    """A structural mode below (a third of Nyquist) or above Nyquist (1.3x)."""
    ny = rate / 2
    return (ny / 3, 0.03) if where == "below" else (1.3 * ny, 0.03)


def _size(contrib, clean, noise):
    A = np.column_stack([np.ones_like(clean), clean])
    coef, *_ = np.linalg.lstsq(A, contrib, rcond=None)
    return float(np.sqrt(np.mean((contrib - A @ coef) ** 2)) / noise)


def build(case):
    rig, rate, t, drive = config(case["config"])
    p = gen.RIGS[rig]
    seed = case.get("seed", 1)
    effects = case.get("effects", [])
    kw = {}
    params = {}
    gauge = rig == "p888"
    if "preisach" in case:
        _sim = gen.simulate
        def _pi(*a_, **k_):
            return _sim(*a_, preisach=case["preisach"], rest=case.get("rest", "descending"), **k_)
        gen.simulate = _pi
    clean = gen.simulate(rig, t, drive, seed=seed)
    # physical effects (in the simulation)
    for e in effects:
        name, target = e["name"], e.get("size")
        if name == "creep":
            g0 = 0.02
            s1 = gen.simulate(rig, t, drive, creep_gamma=g0)
            sz = _size(s1["x"] - clean["x"], clean["x"], p["noise_x"])
            kw["creep_gamma"] = g0 * target / sz
            params["creep_gamma"] = kw["creep_gamma"]
        elif name == "mode":
            kw["mode"] = mode_for(rate, e.get("where", "below"))
            params["mode"] = kw["mode"]
        elif name == "slew":
            kw["slew_v_per_s"] = e["v_per_s"]
            params["slew_v_per_s"] = e["v_per_s"]
    if case.get("command"):          # the logged voltage is the amplifier's command: target = g cmd + o
        g_, o_ = case["command"]
        kw.update(cmd_gain=g_, cmd_offset=o_)
        clean = gen.simulate(rig, t, lambda tt: drive(tt) / g_, seed=seed, cmd_gain=g_, cmd_offset=o_)
        drive_ = lambda tt: drive(tt) / g_
    else:
        drive_ = drive
    sim = gen.simulate(rig, t, drive_, seed=seed, **kw) if kw else clean
    if "preisach" in case:
        gen.simulate = _sim
    x_d = sim["x"].copy()
    x_g = sim["x"].copy()
    rng = np.random.default_rng(seed + 101)
    dur = t[-1] - t[0]
    for e in effects:
        name, target = e["name"], e.get("size")
        if name in ("drift_lin", "drift_sine", "hum", "delay", "gain"):
            if name == "drift_lin":
                unit = (t - t[0]) / dur
            elif name == "drift_sine":
                P = 0.7 * dur
                unit = np.sin(2 * np.pi * (t - t[0]) / P + 1.0)
                params["drift_period_s"] = P
            elif name == "hum":
                f = e.get("f", 50.0)
                unit = np.sin(2 * np.pi * f * t + 0.3)
                params["hum_hz"] = f
            elif name == "delay":
                tau0 = 0.1 / rate
                unit = (np.interp(t - tau0, t, sim["x"]) - sim["x"]) / tau0
            else:
                unit = sim["x"] - sim["x"].mean()
            if name == "gain":          # a gain error is affine by definition: size = the percent given
                k = target / 100.0
            else:
                k = target / _size(unit, clean["x"], p["noise_x"])
            params[name] = k
            if name == "delay":
                x_d = np.interp(t - k, t, x_d)
                params["delay_s"] = k
                params["delay_samples"] = k * rate
            else:
                x_d = x_d + k * unit
        elif name == "bow":
            if gauge:
                unit = ((x_g - p["gauge_x0"]) / p["gauge_m_per_v"]) ** 2
                sz = _size(unit, clean["x"], p["noise_g"])
                k = target / sz     # V of bow per V^2 of reading
                x_g = x_g + k * unit * p["gauge_m_per_v"]
                params["bow_v_per_v2"] = k
            else:
                mid = 0.5 * (x_d.min() + x_d.max())
                unit = (x_d - mid) ** 2
                k = target / _size(unit, clean["x"], p["noise_x"])
                x_d = x_d + k * unit
                params["bow_per_m"] = k
    sim2 = dict(sim)
    rec = gen.add_noise(dict(sim, x=x_d), rig, seed, gauge=False)
    if gauge:
        grec = gen.add_noise(dict(sim, x=x_g), rig, seed, gauge=True)
        rec["gauge[V]"] = grec["gauge[V]"]
    for e in effects:
        if e["name"] == "quant":
            lsb = e["lsb_noise"] * p["noise_x"]
            rec["displacement[m]"] = np.round(rec["displacement[m]"] / lsb) * lsb
            params["lsb_m"] = lsb
        elif e["name"] == "glitch":
            idx = rng.choice(t.size, size=e.get("n", 10), replace=False)
            rec["displacement[m]"][idx] += e["amp_noise"] * p["noise_x"] * rng.choice([-1, 1], idx.size)
            params["glitch_rows"] = idx.size
            params["glitch_amp_m"] = e["amp_noise"] * p["noise_x"]
    if case.get("command"):
        rec["voltage[V]"] = sim["cmd"] + 1e-3 * np.random.default_rng(seed + 5).standard_normal(t.size)
    if case.get("drop_current"):
        del rec["current[A]"]
    # measured sizes on the effect channels (record minus clean twin with the same noise)
    twin = gen.add_noise(clean, rig, seed, gauge=gauge)
    sizes = {}
    for ch in {CHANNEL[e["name"]] for e in effects}:
        if ch == "gauge" and "gauge[V]" not in rec:
            ch = "displacement"      # no gauge on this rig: the bow is the displacement sensor's
        key = "gauge[V]" if ch == "gauge" else "displacement[m]"
        nz = p["noise_g"] if ch == "gauge" else p["noise_x"]
        if any(e["name"] == "gain" for e in effects):   # its raw size: RMS of the change over the noise
            d_ = rec[key] - twin[key]
            sizes[ch] = float(np.sqrt(np.mean((d_ - d_.mean()) ** 2)) / nz)
        else:
            sizes[ch] = _size(rec[key] - twin[key], twin[key], nz)
    meta = {"series_resistor_ohm": p["R"]}
    if case.get("command"):
        meta["input"] = "command"
    if rig == "p888":
        meta["serial"] = "SN637"
    return rec, meta, p["plant"], params, sizes


def run_case(case, keep):
    t0 = time.time()
    rec, meta, plant, params, sizes = build(case)
    keep.mkdir(parents=True, exist_ok=True)
    csv = keep / f"{case['name']}.csv"
    js = keep / f"{case['name']}.json"
    gen.write_csv(csv, rec, meta)
    t_gen = time.time() - t0
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    if js.exists():
        js.unlink()
    cmd = [PY, "-m", "workbench", "calibrate", str(csv), "--plant", case.get("plant", plant), "--json", str(js)]
    cmd += case.get("args", [])
    pr = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    out = {"name": case["name"], "args": case.get("args", []), "config": case["config"], "effects": case.get("effects", []), "params": params,
           "sizes": sizes, "rc": pr.returncode, "traceback": "Traceback" in pr.stderr,
           "stderr_tail": pr.stderr.strip().splitlines()[-3:] if pr.returncode else [],
           "gen_s": round(t_gen, 1), "cli_s": round(time.time() - t0 - t_gen, 1), "cmd": " ".join(cmd)}
    if js.exists():
        d = json.loads(js.read_text())
        bf = d.get("base_fit", {})
        out.update(effect=d.get("effect"), channel=d.get("channel"), agreement=d.get("agreement"),
                   stages=[(s.get("effect"), s.get("channel")) for s in d.get("stages", [])],
                   error_before=d["error_before"]["rms"], error_after=d["error_after"]["rms"],
                   error_after_source=d.get("error_after_source"),
                   error_after_model=(d.get("error_after_model") or {}).get("rms"),
                   leading=d.get("leading"), reason=d.get("reason"), parameters=d.get("parameters"),
                   warnings=d.get("warnings", []),
                   channels={k: {"rms": v.get("rms"), "noise_floor": v.get("noise_floor"),
                                 "line": (bf.get("line") or {}).get(k, {}).get("rms"),
                                 "after": (v.get("error_after") or {}).get("rms")}
                             for k, v in (bf.get("channels") or {}).items()},
                   working_capacitance_f=bf.get("working_capacitance_f"), voltage_source=bf.get("voltage_source"))
    with open(LOG, "a") as fh:
        fh.write(json.dumps(out, default=float) + "\n")
    eff = "+".join(e["name"] + (f"@{e['size']}" if e.get("size") else "") for e in case.get("effects", [])) or "clean"
    print(f"{case['name']:28s} {eff:24s} rc={out['rc']} -> {out.get('effect')} {out.get('agreement')} "
          f"stages={out.get('stages')} size={ {k: round(v, 1) for k, v in sizes.items()} } "
          f"before={out.get('error_before', float('nan')):.3g} after={out.get('error_after', float('nan')):.3g} "
          f"warn={len(out.get('warnings', []))} [{out['cli_s']} s]", flush=True)
    return out


def cases_extra():
    """A second batch: more clean drives, records logged as an amplifier command, larger effects."""
    L = []
    for c in ["p_1k_sine0.2", "p_1k_sine1", "p_1k_sine5", "p_10k_sine10", "p_100_sine0.5", "s_10k_sine5", "s_100k_sine50",
              "p_1k_tri0.2", "p_10k_tri2", "s_1k_tri1", "p_1k_msine", "s_1k_msine"]:
        L.append({"name": f"{c}__clean", "config": c})
    for c, g_, o_ in [("p_1k_proto", 10.0, 0.3), ("p_1k_sine1", 12.0, -0.2), ("s_1k_sine", 15.0, 0.5), ("p_1k_msine", 10.0, 0.0)]:
        L.append({"name": f"{c}__clean_command", "config": c, "command": (g_, o_)})
    L.append({"name": "p_1k_proto__slew200_command", "config": "p_1k_proto", "command": (10.0, 0.3),
              "effects": [{"name": "slew", "v_per_s": 200.0}]})
    for c, e, s in [("p_1k_proto", "creep", 100), ("p_10k_proto", "creep", 100), ("p_1k_proto", "drift_lin", 100),
                    ("p_1k_proto", "delay", 30), ("p_1k_proto", "delay", 100), ("p_1k_msine", "creep", 30),
                    ("p_1k_msine", "delay", 30), ("p_1k_sine1", "drift_sine", 30)]:
        L.append({"name": f"{c}__{e}{s}", "config": c, "effects": [{"name": e, "size": s}]})
    # A2's control: the same creep on the engine's own hysteresis family (density of r only, the PI's rest)
    for c, s in [("p_1k_steps", 30), ("p_1k_proto", 30), ("p_1k_proto", 100)]:
        L.append({"name": f"{c}__creep{s}_PIdensity_demag", "config": c, "effects": [{"name": "creep", "size": s}],
                  "preisach": {"m_sigma_frac": 1e3}, "rest": "demag"})
    # ... and without the current column (no charge to veto a creep the charge does not show)
    L.append({"name": "p_1k_proto__creep100_PIdensity_demag_nocurrent", "config": "p_1k_proto",
              "effects": [{"name": "creep", "size": 100}], "preisach": {"m_sigma_frac": 1e3}, "rest": "demag",
              "drop_current": True})
    for c, s in [("p_1k_steps", 30), ("p_1k_proto", 100)]:
        L.append({"name": f"{c}__creep{s}_nocurrent", "config": c, "effects": [{"name": "creep", "size": s}],
                  "drop_current": True})
    return L


def cases():
    L = []
    P = ["p_1k_proto", "p_100_proto", "p_10k_proto", "p_1k_tri", "p_10k_sine", "p_100k_sine", "p_100_msine",
         "p_1k_steps"]
    S = ["s_1k_sine", "s_10k_tri", "s_100_msine", "s_1k_steps", "s_1k_proto"]
    for c in P + S:
        L.append({"name": f"{c}__clean", "config": c})
    sizes = [3, 10, 30, 100]

    def add(c, effs, tag=""):
        nm = c + "__" + "+".join(e["name"] + (str(e.get("size", "")) if e.get("size") else "") for e in effs) + tag
        L.append({"name": nm, "config": c, "effects": effs})

    k = 0
    for eff, confs in [("creep", ["p_1k_proto", "p_100_proto", "p_1k_steps", "p_100_msine", "s_1k_steps", "s_1k_proto"]),
                       ("drift_lin", ["p_1k_proto", "p_1k_tri", "p_100_msine", "s_1k_sine", "s_100_msine"]),
                       ("drift_sine", ["p_1k_proto", "p_10k_sine", "p_1k_steps", "s_1k_sine", "s_1k_steps"]),
                       ("bow", ["p_1k_proto", "p_100_proto", "p_1k_tri", "p_10k_sine", "s_1k_sine"]),
                       ("delay", ["p_1k_proto", "p_10k_sine", "p_100k_sine", "p_1k_tri", "s_10k_tri"]),
                       ("hum", ["p_1k_proto", "p_100_proto", "p_1k_tri", "s_1k_sine"]),
                       ("gain", ["p_1k_proto", "s_1k_sine"])]:
        for c in confs:
            add(c, [{"name": eff, "size": sizes[k % 3 + (1 if eff in ("creep", "drift_lin", "drift_sine") and k % 2 else 0)]}])
            k += 1
    for c, where in [("p_1k_proto", "below"), ("p_100_proto", "below"), ("p_100_proto", "above"), ("p_10k_proto", "below"),
                     ("p_100k_sine", "below"), ("p_1k_steps", "below"), ("s_10k_tri", "below")]:
        L.append({"name": f"{c}__mode_{where}", "config": c, "effects": [{"name": "mode", "where": where}]})
    for c, sr in [("p_1k_proto", 200.0), ("p_1k_steps", 100.0), ("s_1k_steps", 300.0)]:
        L.append({"name": f"{c}__slew{int(sr)}", "config": c, "effects": [{"name": "slew", "v_per_s": sr}]})
    for c, lsb in [("p_1k_proto", 20), ("p_1k_tri", 8), ("s_1k_sine", 20)]:
        L.append({"name": f"{c}__quant{lsb}", "config": c, "effects": [{"name": "quant", "lsb_noise": lsb}]})
    for c, amp in [("p_1k_proto", 60), ("p_10k_sine", 100), ("s_1k_steps", 60)]:
        L.append({"name": f"{c}__glitch{amp}", "config": c, "effects": [{"name": "glitch", "amp_noise": amp, "n": 12}]})
    # pairs
    add("p_1k_proto", [{"name": "creep", "size": 30}, {"name": "delay", "size": 30}])
    add("p_1k_proto", [{"name": "drift_sine", "size": 30}, {"name": "bow", "size": 30}])
    add("p_1k_proto", [{"name": "creep", "size": 30}, {"name": "hum", "size": 10}])
    add("p_1k_steps", [{"name": "creep", "size": 30}, {"name": "drift_lin", "size": 30}])
    add("p_100_proto", [{"name": "delay", "size": 30}, {"name": "bow", "size": 30}])
    add("s_1k_steps", [{"name": "creep", "size": 30}, {"name": "drift_lin", "size": 30}])
    L.append({"name": "p_1k_proto__mode_below+creep30", "config": "p_1k_proto",
              "effects": [{"name": "mode", "where": "below"}, {"name": "creep", "size": 30}]})
    # the control: the same generator with a Preisach density of r only (a PI operator), clean
    for c in ["p_1k_tri", "p_10k_sine", "p_100k_sine", "s_1k_proto", "p_1k_proto"]:
        L.append({"name": f"{c}__clean_PIdensity", "config": c, "preisach": {"m_sigma_frac": 1e3}})
    # and with the PI's rest state too (demagnetised): the engine's own model family up to the sensors
    for c in ["p_10k_sine", "p_100k_sine", "p_1k_tri"]:
        L.append({"name": f"{c}__clean_PIdensity_demag", "config": c, "preisach": {"m_sigma_frac": 1e3}, "rest": "demag"})
        L.append({"name": f"{c}__clean_demag", "config": c, "preisach": {}, "rest": "demag"})
    return L


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", nargs="*")
    ap.add_argument("--skip-done", action="store_true")
    ap.add_argument("--exact", action="store_true", help="--only names match whole case names")
    ap.add_argument("--all", action="store_true", help="cases() and cases_extra() together")
    ap.add_argument("--list", action="store_true")
    ap.add_argument("--extra", action="store_true", help="the second batch (cases_extra)")
    ap.add_argument("--keep", type=Path, default=Path("/tmp/s34o_recs"))
    ap.add_argument("--cli-args", default="", help="extra calibrate arguments, e.g. '--split blocks'")
    ap.add_argument("--seed", type=int, help="the noise (and glitch) seed of every case (default: each case's, 1)")
    ap.add_argument("--suffix", default="", help="appended to each case's name (the same record, other arguments)")
    a = ap.parse_args()
    todo = cases() + cases_extra() if a.all else (cases_extra() if a.extra else cases())
    if a.cli_args:
        for c in todo:
            c["args"] = c.get("args", []) + a.cli_args.split()
    if a.seed is not None:
        for c in todo:
            c["seed"] = a.seed
    if a.suffix:
        for c in todo:
            c["base_name"] = c["name"]
            c["name"] += a.suffix
    if a.list:
        for c in todo:
            print(c["name"])
        print(len(todo))
        sys.exit()
    if a.only:
        nm = lambda c: c.get("base_name", c["name"])
        todo = [c for c in todo if (nm(c) in a.only if a.exact else any(o in nm(c) for o in a.only))]
    if a.skip_done and LOG.exists():
        done = {json.loads(l)["name"] for l in LOG.read_text().splitlines() if l.strip()}
        todo = [c for c in todo if c["name"] not in done]
    for c in todo:
        try:
            run_case(c, a.keep)
        except Exception as exc:     # a generator bug must not stop the batch
            print(f"{c['name']}: GENERATOR ERROR {exc!r}", flush=True)
