"""The creep plant's R -> 0 gap (review s37 minor 3): dynamic form at R = 1e-4 ohm vs quasi-static R = 0, per dt,
against both forms at a fine dt. A raised-cosine 0 -> 60 V over 1 s, then held 1 s (the limit never binds).
Run: PYTHONPATH=. python benchmarks/logs/s38_phys/creep_r0_gap.py
"""
import numpy as np

from workbench.plant import load_plant
from workbench.plant.simulator import PZTSimulator

p = load_plant("plants/p888_51_sn637_creep.toml").pzt


def run(r, dt):
    n = int(round(2.0 / dt))
    t = np.arange(1, n + 1) * dt
    v = np.where(t < 1.0, 30.0 * (1 - np.cos(np.pi * np.minimum(t, 1.0))), 60.0)
    tr = PZTSimulator(p.with_resistance(r), dt).run(v)
    k1 = int(round(1.0 / dt)) - 1
    return tr.q_c[k1], tr.q_c[-1], tr.v_t_v[k1], tr.x_m[-1]


ref = {}
for dt in (1e-4, 1e-5, 1e-6):
    qs, dy = run(0.0, dt), run(1e-4, dt)
    ref[dt] = (qs, dy)
    print(f"dt {dt:g}: q(1 s) quasi-static {qs[0]:.10e} dynamic R=1e-4 {dy[0]:.10e} gap {dy[0] - qs[0]:+.3e} C | "
          f"q(2 s) gap {dy[1] - qs[1]:+.3e} C | x(2 s) gap {dy[3] - qs[3]:+.3e} m")
q_fine = 0.5 * (ref[1e-6][0][0] + ref[1e-6][1][0])
for dt in (1e-4, 1e-5):
    print(f"dt {dt:g}: q(1 s) minus dt 1e-6 (mean of the forms): quasi-static {ref[dt][0][0] - q_fine:+.3e} C, "
          f"dynamic {ref[dt][1][0] - q_fine:+.3e} C")
