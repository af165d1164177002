"""Measure the per-unit cost of the runs a flag sizes, against the pre-flight estimate's constants.

`workbench.preflight.RUN_COSTS` holds seconds and bytes per unit of work (a servo period of the
verify hold, a second of the selfsense staircase, a describing-function point of linearize, a
sample of freefree). This runs each library entry point at two sizes in this process (compile
and start-up excluded by a warm-up run at the small size), takes the difference of wall time and
of the peak memory (tracemalloc's, or the process's peak RSS, whichever is larger), and prints measured / assumed per unit. The
estimate only has to tell a minute from a day, so a ratio within about 0.3-3 is what it needs.

    PYTHONPATH=$PWD python benchmarks/preflight_estimates.py
"""

import resource
import time
import tracemalloc
from pathlib import Path

import numpy as np

from workbench.preflight import RUN_COSTS

ROOT = Path(__file__).resolve().parents[1]
PLANT = ROOT / "plants" / "p888_51_sn637.toml"
CREEP = ROOT / "plants" / "p888_51_sn637_creep.toml"
CTRL = ROOT / "controllers" / "sn637_loopshape.json"


def measure(fn, size):
    """(seconds, bytes): wall time, and the larger of tracemalloc's peak and the process's peak RSS
    (numba's own buffers are not traced; the RSS peak only grows, so sizes run small to large)."""
    tracemalloc.start()
    t0 = time.perf_counter()
    fn(size)
    seconds = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return seconds, max(peak, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)


def slope(name, fn, small, large, units_per_size):
    fn(small)                                   # warm-up: numba compile, caches
    s0, b0 = measure(fn, small)
    s1, b1 = measure(fn, large)
    du = (large - small) * units_per_size
    per_s, per_b = (s1 - s0) / du, max(b1 - b0, 0) / du
    ref_s, ref_b = RUN_COSTS[name]
    print(f"{name:18s} {per_s:.3g} s/unit (assumed {ref_s:.3g}, ratio {per_s / ref_s:.2f}); "
          f"{per_b:.3g} B/unit (assumed {ref_b:.3g}{f', ratio {per_b / ref_b:.2f}' if ref_b else ''}); "
          f"{s0:.2f} s at {small}, {s1:.2f} s at {large}", flush=True)


def main():
    from workbench.identify.freefree import run_freefree
    from workbench.linearize.run import run_linearize
    from workbench.linearize.uncertainty import FamilySpec
    from workbench.plant import load_plant
    from workbench.selfsense.run import run_selfsense
    from workbench.verify.run import run_verify

    plant = load_plant(PLANT)
    fs = plant.gauge.modulation_hz
    slope("freefree_sample", lambda c: run_freefree(plant, cycles=c, freq_hz=0.1), 2, 20, fs / 0.1)
    slope("verify_period", lambda h: run_verify(CREEP, CTRL, ("hold",), hold_s=h), 20.0, 400.0, 10_000.0)
    slope("selfsense_second", lambda d: run_selfsense(CREEP, duration_s=d, loop=False), 200.0, 1200.0, 1.0)
    from workbench.controller import Controller
    from workbench.verify.sensors import run_sensor_loop, sensor_setup
    creep = load_plant(CREEP)
    fused = Controller.load(ROOT / "controllers" / "sn637_fused_loopshape.json")
    setup = sensor_setup(creep, fused)
    # the open loop and the 20 s triangle are the same at both holds: the difference is the hold's periods
    slope("verify_sensor_period", lambda h: run_sensor_loop(setup, fused, "fused", hold_s=h, sweep=False), 3.0, 60.0,
          10_000.0)
    amps = (1.0, 10.0)
    slope("linearize_point",
          lambda n: run_linearize(PLANT, spec=FamilySpec(amplitudes_v=amps, freq_hz=tuple(np.geomspace(1, 2000, n)))),
          4, 16, len(amps))


if __name__ == "__main__":
    main()
