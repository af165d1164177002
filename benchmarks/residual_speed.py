"""Time of :func:`workbench.calibrate.residual.analyze_residual` on a long record (target: well under 2 s).

A synthetic 350,000-sample record at 10 kHz: a staircase with 5 s holds joined by ramps, then a
slow triangle whose per-sample step is just inside the hold tolerance (the case that cost a
Python iteration every few samples in the hold search), a residual with creep-like drift and
white noise. Prints the first call (it may include numba compiling the hold search once per
machine; the result is cached) and the best of ``--repeat``.

    .venv/bin/python benchmarks/residual_speed.py [--samples N] [--max-lag L] [--repeat R]
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))     # run from a checkout without install
from workbench.calibrate.residual import analyze_residual  # noqa: E402


def synthetic(n, fs_hz=10_000.0, seed=0):
    """(t_s, u_v, y_meas_m, y_model_m) of ``n`` samples."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs_hz
    half = n // 2
    levels = np.repeat(np.arange(0.0, 100.0, 10.0), 2)[1:]          # 0 10 10 20 20 ...: holds and ramps
    knots_t = np.arange(levels.size) * 2.5
    stair = np.interp(t[:half], knots_t, levels, period=knots_t[-1] + 2.5)
    step = 0.9e-3 * 100.0                                            # just inside the default tolerance
    tri = np.abs((np.arange(n - half) * step) % 200.0 - 100.0)
    u = np.r_[stair, tri]
    y_model = 1.5e-7 * u
    y = y_model + 2e-9 * np.log1p(t) + 1e-9 * rng.standard_normal(n)
    return t, u, y, y_model


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=350_000)
    parser.add_argument("--max-lag", type=int, default=50)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args(argv)
    t, u, y, y_model = synthetic(args.samples)
    times = []
    for _ in range(max(1, args.repeat)):
        t0 = time.perf_counter()
        rep = analyze_residual(t, u, y, y_model, max_lag=args.max_lag)
        times.append(time.perf_counter() - t0)
    print(f"analyze_residual, {args.samples} samples, max_lag {args.max_lag}: first call "
          f"{times[0]:.3f} s, best of {len(times)} {min(times):.3f} s ({len(rep.holds)} holds)")


if __name__ == "__main__":
    main()
