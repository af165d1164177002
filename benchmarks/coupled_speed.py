"""Steps per second of the coupled stack + structure kernel against PZTSimulator, same run, same input.

Three cases on SN637 at 1 us steps (20 Hz, 40 V sine about 50 V): today's PZTSimulator (spring with
the 70 kHz mode filter), the coupled kernel on the bare spring, and the coupled kernel on the
assumed flexure structure (plants/p888_51_sn637_on_flexure.toml, two modes). Best of ``--repeat``
after a compile run; the ratio is what to read (machines differ).

    .venv/bin/python benchmarks/coupled_speed.py [--steps N] [--repeat R]
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))     # run from a checkout without install
from workbench.plant import PZTSimulator, load_plant  # noqa: E402
from workbench.plant.coupled import CoupledSimulator  # noqa: E402
from workbench.plant.structure import spring  # noqa: E402


def best(make, v, repeat):
    make().run(v[:1000])                       # compile / warm
    times = []
    for _ in range(repeat):
        sim = make()
        t0 = time.perf_counter()
        sim.run(v, decimate=100)
        times.append(time.perf_counter() - t0)
    return v.size / min(times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    dt = 1e-6
    v = 50 + 40 * np.sin(2 * np.pi * 20 * np.arange(a.steps) * dt)
    pz = load_plant(ROOT / "plants" / "p888_51_sn637.toml").pzt
    fl = load_plant(ROOT / "plants" / "p888_51_sn637_on_flexure.toml")
    ref = best(lambda: PZTSimulator(pz, dt), v, a.repeat)
    bare = best(lambda: CoupledSimulator([pz], spring(pz.stiffness_n_per_m), dt), v, a.repeat)
    flex = best(lambda: CoupledSimulator([fl.pzt], fl.structure, dt), v, a.repeat)
    rows = [("PZTSimulator (spring + 70 kHz mode filter)", ref), ("CoupledSimulator, spring", bare),
            ("CoupledSimulator, flexure (2 modes)", flex)]
    for name, sps in rows:
        print(f"{name:45s} {sps / 1e6:7.2f} M steps/s   {sps / ref:5.2f} x PZTSimulator")


if __name__ == "__main__":
    main()
