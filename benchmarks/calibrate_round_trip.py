"""The updated plant's round trip over the confusion benchmark's two-effect records (issue 13, item 6).

Each pair record of a seed (``calibrate_confusion.cases``: creep + delay, leakage + dielectric
absorption, drift + resonance, at 1, 10 and 100 kHz under three protocols) is calibrated as
``workbench calibrate`` does (``trace_effect``, ``plant_update.choose_core``, the file's test error and
``plant_update.reported_error_after``: the reported ``error_after`` is the file's replay since session 15);
the final updated plant file is written to disk, loaded back and the record's drive replayed through it
(``plant_update.updated_plant_error``), as through the plant that made the record. Printed per record: the
stages found; the file's replay against the REPORTED ``error_after`` (the same replay path: 1.00x, an
invariant) and against the tracing model's own test error (the substantive one: the file must not be worse
than what was found, at most +10 %); the true plant's replay against the tracing model's. Then, per pair and
for sizes >= 3x, how many are within 10 %, how many at most 10 % above, the median and worst ratio, for each.

    OPENBLAS_NUM_THREADS=1 python benchmarks/calibrate_round_trip.py --seed 24 [--effects creep+delay ...]
        [--rates 100 ...] [--index K ...]

``--rates``: only the records at these rates (the confusion benchmark's, ``100`` and ``1e6`` its ends, run only
when named); ``--effects`` may name a single effect (``resonance``: its one-effect records, which are otherwise
skipped); ``--index``: only these records (the confusion benchmark's ``#K``).
"""

import argparse
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import calibrate_confusion as cc  # noqa: E402
from workbench.calibrate.plant_update import (choose_core, reported_error_after, unplaced_modes,  # noqa: E402
                                              updated_plant_error, updated_plant_text)
from workbench.calibrate.tracing import trace_effect  # noqa: E402
from workbench.plant import load_plant  # noqa: E402


def round_trip(plant0, plant_path, effect, rate, proto, size, seed):
    """One record: ``(result, the tracing model's error_after, the reported error_after, the file's replay,
    the true plant's replay, its core)`` (test RMS, m / C / V; None but the result without a stage).

    As ``workbench calibrate`` (``workbench.calibrate.run``): the core by ``choose_core`` on the development
    rows, the file's test error from that replay (or the written text replayed), ``reported_error_after``; then
    the final text (with its header) written to disk, loaded back and replayed on the test rows."""
    t, sp, base, plant, truth, r = cc.simulated_base(plant0, effect, rate, proto, size, seed)
    res = trace_effect(base, split=sp)
    if not res["stages"]:
        return res, None, None, None, None, None
    core, _, err = choose_core(plant_path, plant0, base, res, Path("record.csv"), sp.train, test=sp.test)
    ch = res["channel"]
    # a mode the record cannot place in its alias family is not written (as workbench calibrate leaves it out)
    omit = unplaced_modes(res["stages"])
    if omit:
        err = None
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "p.toml"
        if err is None:
            p.write_text(updated_plant_text(plant_path, plant0, base, res, Path("record.csv"), core=core, omit=omit),
                         encoding="utf-8")
            err = updated_plant_error(load_plant(p), base, ch, sp.test, train=sp.train)
        reported, _ = reported_error_after(res["error_after"], err)
        p.write_text(updated_plant_text(plant_path, plant0, base, res, Path("record.csv"), plant_error=err, core=core,
                                        omit=omit), encoding="utf-8")
        file_err = updated_plant_error(load_plant(p), base, ch, sp.test, train=sp.train)
    return (res, res["error_after"]["rms"], reported["rms"], file_err["rms"],
            updated_plant_error(plant, base, ch, sp.test, train=sp.train)["rms"],
            "refitted" if core["hysteresis"] is not None else "declared")


def _cells(x):
    return (f"{int(np.sum(np.abs(x - 1) <= 0.1))} / {int(np.sum(x <= 1.1))} / {x.size}, median {np.median(x):.2f}x, "
            f"worst {x.max():.2f}x")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, nargs="+", default=[24])
    ap.add_argument("--effects", nargs="*", default=None,
                    help="only these pairs, e.g. creep+delay, or single effects named here (resonance)")
    ap.add_argument("--rates", type=float, nargs="*", default=None,
                    help=f"only these sample rates, Hz; {', '.join(f'{r:g}' for r in cc.END_RATES_HZ)} only when named")
    ap.add_argument("--index", type=int, nargs="*", default=None, help="only these records (#K, 1-based)")
    a = ap.parse_args(argv)
    ends = bool(a.rates) and any(r in cc.END_RATES_HZ for r in a.rates)
    plant_path = ROOT / "plants" / "p888_51_sn637.toml"
    plant0 = load_plant(plant_path)
    rows = []
    for seed in a.seed:
        for k, (e, rate, proto, size, s) in enumerate(cc.cases(seed=seed, ends=ends)):
            name = e if isinstance(e, str) else "+".join(e)
            if (isinstance(e, str) and not (a.effects and e in a.effects)) or (a.effects and name not in a.effects) \
                    or (a.rates and rate not in a.rates) or (a.index and k + 1 not in a.index):
                continue
            res, ea, rep, upd, true, which = round_trip(plant0, plant_path, e, rate, proto, size, s)
            stages = ", ".join(f"{x['effect']}/{x['channel']}" + (" (not written: its alias family unresolved)"
                                                                  if x.get("alias_family") and
                                                                  not x["alias_family"]["resolved"] else "")
                               for x in res["stages"]) or res["effect"]
            line = f"{seed} #{k + 1} {name} {rate:g} Hz {proto} {size:.3g}x: {stages}"
            if ea:
                line += (f"; tracing model {ea:.4g}, reported error_after {rep:.4g}, updated plant ({which} core) "
                         f"{upd:.4g}: {upd / rep:.4f}x reported, {upd / ea:.2f}x the model; true plant {true:.4g} "
                         f"({true / ea:.2f}x the model)")
                rows.append((name, size, upd / rep, upd / ea, true / ea))
            print(line, flush=True)
    print("| pair | records with a stage | file / reported error_after: within 10 % / at most +10 % / all, median, "
          "worst | file / tracing model: the same | true plant / tracing model: the same |")
    print("|---|---|---|---|---|")
    for pair in sorted({r[0] for r in rows}) + [None]:
        for big in (False, True):
            sel = [r for r in rows if (pair is None or r[0] == pair) and (not big or r[1] >= 3.0)]
            if not sel:
                continue
            cells = [_cells(np.array([r[j] for r in sel])) for j in (2, 3, 4)]
            print(f"| {pair or 'all'}{' (>= 3x)' if big else ''} | {len(sel)} | {' | '.join(cells)} |")


if __name__ == "__main__":
    main()
