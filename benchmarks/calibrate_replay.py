"""The updated plant file's replay on confusion-benchmark records, calibrated as ``workbench calibrate`` does.

The confusion benchmark (``calibrate_confusion.py``) scores the tracing model (``trace_effect``) and never writes
or replays the plant file; this runs the CLI's function (``run_calibrate``, figures off) on the same records
(``calibrate_confusion.cases``: the seed's draw, numbered as there), each simulated and written as the CLI's CSV,
and prints the answer, the file's replay on the test rows (the JSON's ``error_after``) against ``error_before``,
the stages the file carries and those it does not, and the count of records whose replay is above
``error_before`` while an effect is named.

    OPENBLAS_NUM_THREADS=1 python benchmarks/calibrate_replay.py --seed S --index K [K ...] [--rates HZ ...]
"""

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from calibrate_confusion import END_RATES_HZ, ROWS, cases  # noqa: E402
from workbench.calibrate.run import run_calibrate  # noqa: E402
from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record, write_record  # noqa: E402


def one(plant0, plant_path, e, rate, proto, size, seed, tmp):
    effects = () if e == "none" else ((e,) if isinstance(e, str) else tuple(e))
    t, v = benchmark_protocol(proto, rate, ROWS[rate])
    plant, _ = plant_with_effect(plant0, effects or "none", seed, duration_s=float(t[-1]), size=size)
    r = simulate_record(plant, t, v, seed=seed)
    p = Path(tmp) / "record.csv"
    write_record(p, {k: r[k] for k in ("time_s", "voltage_v", "current_a", "displacement_m", "gauge_v")})
    return run_calibrate(p, plant_path, figures=False)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--index", type=int, nargs="*", default=None, help="1-based, as numbered in the benchmark")
    ap.add_argument("--rates", type=float, nargs="*", default=None)
    a = ap.parse_args(argv)
    from workbench.plant import load_plant
    plant_path = ROOT / "plants" / "p888_51_sn637.toml"
    plant0 = load_plant(plant_path)
    todo = [(k + 1, c) for k, c in enumerate(cases(1, a.seed, ends=bool(a.rates) and any(
        r in END_RATES_HZ for r in a.rates)))]
    if a.rates:
        todo = [(k, c) for k, c in todo if c[1] in a.rates]
    if a.index:
        todo = [(k, c) for k, c in todo if k in a.index]
    named = above = 0
    t0 = time.perf_counter()
    for k, (e, rate, proto, size, seed) in todo:
        eff = e if isinstance(e, str) else "+".join(e)
        with tempfile.TemporaryDirectory() as tmp:
            try:
                d = one(plant0, plant_path, e, rate, proto, size, seed, tmp)
            except Exception as exc:      # noqa: BLE001 -- reported, the run goes on
                print(f"[#{k}] {eff} {rate / 1e3:.4g} kHz {proto} x{size:.3f}: CRASH {type(exc).__name__}: {exc}",
                      flush=True)
                continue
        eb, ea, em = d["error_before"]["rms"], d["error_after"]["rms"], d["error_after_model"]["rms"]
        stages = [s["effect"] + ("" if s["channel"] == d["channel"] else f"({s['channel']})") for s in d["stages"]]
        carried = d.get("updated_plant_stages")
        dropped = [f"{s['effect']}({s['channel']})" for s in (carried or []) if not s.get("written", True)]
        is_named = d["effect"] not in ("none", "inconclusive")
        up = is_named and d["error_after_source"] == "updated plant" and ea > eb
        named += is_named
        above += up
        print(f"[#{k} {time.perf_counter() - t0:.0f} s] {eff:30s} {rate / 1e3:5.4g} kHz {proto:11s} x{size:7.3f} -> "
              f"{d['effect']:22s} {str(d['agreement']):7s} stages {'+'.join(stages) or '-'} on {d['channel']}; "
              f"before {eb:.4g} model {em:.4g} file {ea:.4g} ({d['error_after_source']}) file/before {ea / eb:.3g}"
              + (f" NOT WRITTEN {dropped}" if dropped else "") + (" REPLAY ABOVE BEFORE" if up else "")
              + f" core {(d.get('updated_plant_core') or {}).get('core')} ({d['elapsed_s']:.1f} s)", flush=True)
    print(f"\nrecords {len(todo)}; effect named {named}; the written file's replay above error_before: {above}")


if __name__ == "__main__":
    main()
