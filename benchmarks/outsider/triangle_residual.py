"""Where the base's displacement residual sits on a clean triangle (finding 1): by phase from the nearest corner.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/outsider/triangle_residual.py
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from harness import triangle  # noqa: E402
from workbench.calibrate.base_fit import fit_base  # noqa: E402
from workbench.calibrate.record import Record  # noqa: E402
from workbench.calibrate.splits import make_split  # noqa: E402
from workbench.calibrate.synthetic import SensorNoise, plant_with_effect, simulate_record  # noqa: E402
from workbench.plant import load_plant  # noqa: E402

p0 = load_plant("plants/p888_51_sn637.toml")
pl, _ = plant_with_effect(p0, "none", 1)
rate, f, dur = 2.5e3, 0.5, 10.0
t, v = triangle(rate, dur, f)
r = simulate_record(pl, t, v, seed=1, noise=SensorNoise(0, 0, 0), gauge_noise=False)
rec = Record(Path("x.csv"), {"current": "averaged", "gauge": "averaged"}, t,
             {k: r[k] for k in ("voltage_v", "current_a", "displacement_m")}, 1 / rate)
sp = make_split(t, r["voltage_v"], "blocks")
b = fit_base(rec, 80.0, train=sp.train, test=sp.test, pzt=pl.pzt, dac_range_v=pl.gauge.dac_range_v)
m = b.channels["displacement"]
res = m.residual
ph = np.clip(t - 0.1 * dur, 0, None) * f
dist = np.abs(ph - np.round(ph * 2) / 2) / f          # s from the nearest corner (corners every half period)
on = t > 0.1 * dur + 0.5
for lo, hi in [(0, 0.01), (0.01, 0.03), (0.03, 0.1), (0.1, 0.3), (0.3, 0.5)]:
    sel = on & (dist >= lo) & (dist < hi) & m.valid
    print(f"{lo:>5}-{hi:<5} s from a corner: rms {np.sqrt(np.mean(res[sel] ** 2)):.3g} m  ({sel.sum()} rows)")
print("whole: %.3g m; displacement span %.3g m" % (np.sqrt(np.mean(res[m.valid & on] ** 2)), np.ptp(r["displacement_m"])))
# after the corner, sign of the residual at top vs bottom corners
top = on & (dist < 0.05) & (np.abs(v - 100) < 10)
bot = on & (dist < 0.05) & (v < 10)
print("mean residual within 50 ms of top corners %.3g, of bottom corners %.3g" % (res[top].mean(), res[bot].mean()))
