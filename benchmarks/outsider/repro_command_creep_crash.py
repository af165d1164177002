"""Finding: `workbench calibrate` stops with a traceback (TypeError in plant_update._core_with_branches,
``lo, hi = core["range_v"]`` on None) on a command-logged, displacement-only record against a PZT plant file.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/outsider/repro_command_creep_crash.py [OUTDIR]
writes OUTDIR/real_cmd.csv (the shared real record, `# input: command`) and OUTDIR/synth_cmd_creep.csv (SN637 with a
drawn creep, size 5, seed 3, 0.5 Hz sine through an amplifier of gain 20 and a 1 ms lag, logged as the command, the
displacement only) and runs the CLI on each against plants/p888_51_sn637.toml.
"""
import subprocess
import sys
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

sys.path.insert(0, str(Path(__file__).parent))
from harness import sine  # noqa: E402
from workbench.calibrate.synthetic import plant_with_effect, simulate_record, write_record  # noqa: E402
from workbench.plant import load_plant  # noqa: E402

out = Path(sys.argv[1] if len(sys.argv) > 1 else "/tmp/s22o_crash")
out.mkdir(parents=True, exist_ok=True)
real = out / "real_cmd.csv"
real.write_text("# input: command\nindex,time[s],displacement[um],voltage[V]\n"
                + Path("/work/shared/data/real/hysteresis_v_150_1hz.csv").read_text())
t, v = sine(1e3, 12.0, 0.5, 0, 100)
u = v / 20.0
a = 1.0 - np.exp(-1.0 / (1e3 * 1e-3))
v_out = 20.0 * lfilter([a], [1.0, a - 1.0], u, zi=[(1.0 - a) * u[0]])[0]
plant, truth = plant_with_effect(load_plant("plants/p888_51_sn637.toml"), "creep", 3, duration_s=12.0, size=5.0)
r = simulate_record(plant, t, v_out, seed=3)
synth = write_record(out / "synth_cmd_creep.csv", {"time_s": t, "voltage_v": u, "displacement_m": r["displacement_m"]},
                     {"input": "command"})
for p in (real, synth):
    c = subprocess.run([sys.executable, "-m", "workbench", "calibrate", str(p), "--plant", "plants/p888_51_sn637.toml",
                        "--json", str(p.with_suffix(".json"))], capture_output=True, text=True)
    print(p.name, "exit", c.returncode, "traceback" if "Traceback" in c.stderr else "", "::", c.stderr.strip().splitlines()[-1][:200])
