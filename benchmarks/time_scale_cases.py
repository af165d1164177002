"""The time-column check on legal records review 4 found refused (bugs 2-3), and their 1000x slips.

For each record: ``a`` = :func:`workbench.calibrate.run.charge_scale` (the recorded charge over the
plant's, offset and leakage taken out) as recorded, with the time column read 1000 times slower
(ms under time[s]) and 1000 times faster (s under time[ms]), and whether ``_check_time_scale``
passes it as recorded. Records come from the simulator through ``tests/calibrate/test_time_scale.py``'s
``_record`` (the plant file's values, a stronger lab amplifier, R = 0, leakage) on 20,000 rows.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/time_scale_cases.py`` from the repository root.
"""

import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "calibrate")]

import test_time_scale as T                                    # noqa: E402  the tests' record maker
from workbench.calibrate.record import Record                  # noqa: E402
from workbench.calibrate.synthetic import simulate_record      # noqa: E402
from workbench.errors import DataFileError                     # noqa: E402
from workbench.plant import load_plant                         # noqa: E402

run = T.run


def _step(limit_factor, rate_hz):
    """SN637, a 0-100 V step at 10 % of the record, driven by ``limit_factor`` times the file's limits."""
    plant = load_plant(ROOT / "plants" / "p888_51_sn637.toml")
    pz = plant.pzt
    lab = dataclasses.replace(plant, pzt=dataclasses.replace(pz, current_limit_source_a=pz.current_limit_source_a
                                                             * limit_factor, current_limit_sink_a=
                                                             pz.current_limit_sink_a * limit_factor))
    t = np.arange(T.ROWS) / rate_hz
    r = simulate_record(lab, t, np.where(t > 0.1 * t[-1], 100.0, 0.0), seed=0, n_sub=2, gauge=False)
    ch = {k: r[k] for k in ("voltage_v", "current_a", "displacement_m")}
    return plant, Record(Path("r.csv"), {}, r["time_s"], ch, 1.0 / rate_hz)


def _row(name, plant, rec):
    res = plant.pzt.series_resistance_ohm
    a = [run.charge_scale(T._rescaled(rec, f), plant.pzt, res) for f in (1.0, 1e3, 1e-3)]
    try:
        T._check(plant, rec)
        verdict = "passes"
    except DataFileError:
        verdict = "refused"
    print(f"| {name} | {a[0]:.3g} | {a[1]:.4g} | {a[2]:.3g} | {verdict} |")


def main():
    print("| record | a as recorded | time x1000 | time /1000 | check as recorded |")
    for limit in (10.0, 50.0):
        for rate in (1e4, 1e5):
            _row(f"SN637 0-100 V step, {limit:g}x current limits, {rate:g} Hz", *_step(limit, rate))
    for off in (1e-4, 1e-3):
        plant, rec = T._record(100.0, "sine", 0)
        ch = dict(rec.channels, current_a=rec.channels["current_a"] + off)
        _row(f"200 s sine, {off * 1e3:+g} mA current offset", plant, dataclasses.replace(rec, channels=ch))
    for leak in (2e6, 2e5, 2e4, 2e3):
        for drive in ("sine", "steps"):
            _row(f"200 s {drive}, leakage {leak:g} ohm", *T._record(100.0, drive, 0, leakage_ohm=leak))
    for drive in ("sine", "steps"):
        _row(f"R = 0, {drive}, 10 kHz", *T._record(1e4, drive, 0, resistance_ohm=0.0))


if __name__ == "__main__":
    main()
