"""Wall time of `workbench calibrate` on protocol records (issue 6: within 60 s each).

Simulates the 35.5 s, 10 kHz calibration protocol (355,000 rows, 5 columns) with one effect
drawn per record, writes it as CSV, and times the whole command (read, base fit, every
candidate, figures, report, updated plant) in a fresh process.

    python benchmarks/calibrate_speed.py [effect ...]
"""

import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from workbench.calibrate.protocol import calibration_protocol  # noqa: E402
from workbench.calibrate.synthetic import plant_with_effect, simulate_record, write_record  # noqa: E402
from workbench.plant import load_plant  # noqa: E402


def main(effects):
    plant_file = ROOT / "plants" / "p888_51_sn637.toml"
    base = load_plant(plant_file)
    t, v = calibration_protocol()
    exe = Path(sys.executable).with_name("workbench")
    with tempfile.TemporaryDirectory() as tmp:
        for k, effect in enumerate(effects):
            plant, _ = plant_with_effect(base, effect, 100 + k)
            data = write_record(Path(tmp) / f"{effect}.csv", simulate_record(plant, t, v, seed=100 + k))
            t0 = time.perf_counter()
            out = subprocess.run([str(exe), "calibrate", str(data), "--plant", str(plant_file), "--out",
                                  str(Path(tmp) / effect)], capture_output=True, text=True)
            dt = time.perf_counter() - t0
            first = out.stdout.splitlines()[0] if out.stdout else out.stderr.strip()
            print(f"{effect:22s} {dt:6.1f} s  {t.size} rows  {first.split(': ', 1)[-1]}")


if __name__ == "__main__":
    main(sys.argv[1:] or ["none", "creep", "resonance"])
