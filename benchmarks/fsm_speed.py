"""Servo periods per second of the three-stack mirror with its five modes (issue 15 target: 10^7 in <= 5 s).

The mirror of plants/fsm_p888_51.toml (three stacks with amplifiers, five structural modes at
416-1083 Hz) stepped at the 10 kHz servo period (studies/sn637_servo.toml), inputs held over a
period, ``--n-sub`` kernel sub-steps per period. Drive: from rest (0 V) a 13 Hz tip and a 31 Hz
tilt sine through K^-1, +/-0.5 V on the stacks (small enough that the 2 mA source limit never
slews it, so the accuracy check sees the modes, not the limiter). Reports the time for ``--periods`` (best of
``--repeat`` after a compile run), the time 10^7 periods take at that rate, the ratio to
PZTSimulator (one stack, its 70 kHz mode filter) on the same number of steps in the same run, and
the accuracy of ``--n-sub`` against 16 sub-steps (largest tip/tilt difference over 0.2 s, in
urad and as a fraction of the swing). Wall time and the thread's CPU time are both given (best of
the repeats each), with the load average: on a shared machine the wall time is the CPU time
times the queue.

    PYTHONPATH=. .venv/bin/python benchmarks/fsm_speed.py [--periods N] [--n-sub K] [--repeat R]
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))     # run from a checkout without install
from workbench.plant import PZTSimulator  # noqa: E402
from workbench.plant.mirror import load_mirror, mirror_run  # noqa: E402


def drive(m, n, dt):
    t = np.arange(n) * dt
    q = np.zeros((n, 3))
    q[:, 0] = 4e-4 * np.sin(2 * np.pi * 13 * t)
    q[:, 1] = 3e-4 * np.sin(2 * np.pi * 31 * t)
    x = q @ m.inverse_kinematics.T
    return 0.5 * x / np.abs(x).max()          # about 0 V: from rest, no bias slew


def timed(make, run, repeat):
    """(best wall s, best CPU s of this thread) over ``repeat`` runs after a compile run."""
    run(make(), warm=True)
    best, best_cpu = np.inf, np.inf
    for _ in range(repeat):
        sim = make()
        c0, t0 = time.thread_time(), time.perf_counter()
        run(sim)
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.thread_time() - c0)
    return best, best_cpu


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--periods", type=int, default=1_000_000)
    ap.add_argument("--n-sub", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    dt = 1e-4
    m = load_mirror(ROOT / "plants" / "fsm_p888_51.toml")
    v = drive(m, a.periods, dt)

    def run_fsm(sim, warm=False):
        mirror_run(sim, v[:1000] if warm else v, decimate=1 if warm else 100)

    def run_ref(sim, warm=False):
        sim.run(v[:1000, 0] if warm else v[:, 0], decimate=1 if warm else 100)

    load = os.getloadavg()
    (t_fsm, c_fsm) = timed(lambda: m.simulator(dt, a.n_sub), run_fsm, a.repeat)
    (t_ref, c_ref) = timed(lambda: PZTSimulator(m.stacks[0], dt / a.n_sub), lambda s, warm=False: s.run(
        np.repeat(v[:1000 if warm else None, 0], a.n_sub), decimate=1 if warm else 100), a.repeat)
    # accuracy of n_sub against 16 sub-steps
    n_acc = int(0.2 / dt)
    ref = mirror_run(m.simulator(dt, 16), v[:n_acc])
    got = mirror_run(m.simulator(dt, a.n_sub), v[:n_acc])
    err = max(np.abs(got.tip_rad - ref.tip_rad).max(), np.abs(got.tilt_rad - ref.tilt_rad).max())
    swing = max(np.ptp(ref.tip_rad), np.ptp(ref.tilt_rad))
    print(f"mirror, 3 stacks + 5 modes, n_sub = {a.n_sub}: {a.periods} periods in {t_fsm:.2f} s wall, "
          f"{c_fsm:.2f} s CPU ({a.periods / c_fsm / 1e6:.2f} M periods/s of CPU); 10^7 periods: "
          f"{t_fsm * 1e7 / a.periods:.1f} s wall, {c_fsm * 1e7 / a.periods:.1f} s CPU (target 5 s)")
    print(f"PZTSimulator, 1 stack, same {a.periods * a.n_sub} steps: {t_ref:.2f} s wall, {c_ref:.2f} s CPU; "
          f"mirror / reference = {t_fsm / t_ref:.2f} (CPU {c_fsm / c_ref:.2f})")
    print(f"load average before / after: {load[0]:.1f} / {os.getloadavg()[0]:.1f} (2 cores)")
    print(f"accuracy vs n_sub = 16 over 0.2 s: {err * 1e6:.3g} urad ({err / swing:.2e} of the {swing * 1e6:.0f} urad swing)")


if __name__ == "__main__":
    main()
