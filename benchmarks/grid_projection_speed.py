"""CPU time of a resonance's pair of searches (with a base projection, then plain) at the speed record's sizes.

355,000 samples at 10 kHz, a 240 Hz mode, every 7th row searched (~50,700 rows) and a projection
off 25 unit-RMS base-like columns on those rows (as :func:`workbench.calibrate.stages._joint_projection`).
Runs the pair with the grid projected one point at a time and costed by ``_lstsq`` per point (main's
code before session 18) and with ``effects._grid_blocks`` / ``_grid_costs`` (a block of up to 32
points at a time), alternating in one process, and prints each run's CPU time and the found modes
(the two must agree: the grid only ranks its points). Median of ``--repeat`` each.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python benchmarks/grid_projection_speed.py [--repeat R]
"""

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from workbench.calibrate import effects  # noqa: E402
from workbench.calibrate.effects import Resonance  # noqa: E402


def _point_at_a_time(columns, project, n_rows):
    for X in columns:
        yield [X.shape[1]], X, (X if project is None else project(X))


def _lstsq_costs(widths, XB, y):
    return [float(np.sum(effects._lstsq(XB, y)[1] ** 2))]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(3)
    n, dt = 355_000, 1e-4
    t = np.arange(n) * dt
    u = np.cumsum(rng.standard_normal(n)) / np.sqrt(n) * 1e-5 + 1e-5 * np.sin(2 * np.pi * 0.5 * t)
    e = 0.3 * Resonance._column(u, 240.0, 0.03, dt) + 1e-9 * rng.standard_normal(n)
    mask = np.zeros(n, bool)
    mask[::7] = True
    B = np.column_stack([u ** p for p in range(1, 6)] + [np.sin(2 * np.pi * f * t) for f in np.geomspace(0.1, 300, 19)]
                        + [np.ones(n)])[mask]
    E = B / np.sqrt(np.mean(B * B, axis=0))
    ginv = np.linalg.pinv(E.T @ E, rcond=1e-12)

    def project(X):
        return X - E @ (ginv @ (E.T @ X))

    def pair():
        eff = Resonance()
        memo = eff.__dict__.setdefault("_grid_costs", {})
        a, b = copy.deepcopy(eff, {id(memo): memo}), copy.deepcopy(eff, {id(memo): memo})
        return a.fit(t, u, e, mask, project=project), b.fit(t, u, e, mask, project=None)

    ways = {"one point at a time": (_point_at_a_time, _lstsq_costs),
            "blocks": (effects._grid_blocks, effects._grid_costs)}
    times = {k: [] for k in ways}
    for _ in range(args.repeat):
        for name, (blocks, costs) in ways.items():
            effects._grid_blocks, effects._grid_costs = blocks, costs
            t0 = time.process_time()
            found = pair()
            times[name].append(time.process_time() - t0)
            print(f"{name:20s} {times[name][-1]:5.2f} s CPU  modes {found[0]['f_n_hz']:.6f} / {found[1]['f_n_hz']:.6f} Hz",
                  flush=True)
    for name, v in times.items():
        print(f"{name:20s} median {float(np.median(v)):.2f} s CPU over {len(v)}")


if __name__ == "__main__":
    main()
