"""Load time of a long record: 350,000 rows x 5 columns (the issue's target is under 2 s).

Writes a synthetic record (time, voltage, current, charge, displacement; prefixed units) to a
temporary directory, then times :func:`workbench.calibrate.read_record` on it: the first load and
the best of ``--repeat``.

    .venv/bin/python benchmarks/record_read.py [--rows N] [--repeat R]
"""

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))     # run from a checkout without install
from workbench.calibrate import read_record  # noqa: E402


def write_record(path, rows):
    """A 5-column record of ``rows`` rows; cells repeat every 1000 rows (time does not), for speed."""
    phase = 2 * np.pi * np.arange(1000) / 1000
    tail = [f",{100 * np.sin(p):.6f},{np.cos(p):.6f},{p * 1e-9:.4e},{np.sin(2 * p):.6f}" for p in phase]
    Path(path).write_text("# serial: SN637\n# series_resistor_ohm: 80\n"
                          "time[ms],voltage[V],current[mA],charge[C],displacement[um]\n"
                          + "\n".join([f"{k * 0.1:.1f}{tail[k % 1000]}" for k in range(rows)]) + "\n")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=350_000)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "record.csv"
        write_record(path, args.rows)
        times = []
        for _ in range(max(1, args.repeat)):
            start = time.perf_counter()
            record = read_record(path)
            times.append(time.perf_counter() - start)
        size_mb = path.stat().st_size / 1e6
    print(f"{record.n} rows x {1 + len(record.channels)} columns ({size_mb:.1f} MB): "
          f"first load {times[0]:.3f} s, best of {len(times)} {min(times):.3f} s")


if __name__ == "__main__":
    main()
