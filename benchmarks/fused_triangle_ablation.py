"""What the fused loop's 0.1 Hz triangle depends on: the closing time, the ramp lead and the gauge linearization.

The verify harness (``workbench.verify.sensors.run_sensor_loop``) adds three things around the exported
controller: it waits until the reading has settled before closing (``settle_s``), feeds the sensor step the
triangle led by its slope over K_v (``ramp_feedforward``) and takes the bridge's curvature out of the gauge
reading (``gauge_linearized``). This runs the committed fused export on the SN637 creep plant (700 s
identification, seed 0 noise, 20 s hold, no sweep) with each of them on and off, and prints the triangle RMS
(% of the quasi-static stroke), the commanded RMS and the hold drift.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. .venv/bin/python benchmarks/fused_triangle_ablation.py [--seed N]
"""

import argparse

from workbench.controller import Controller
from workbench.plant import load_plant
from workbench.verify.sensors import run_sensor_loop, sensor_setup

CASES = (
    ("default (waits for the settle, lead, linearized)", {}),
    ("closes at 1 s, lead and linearization on", dict(settle_s=1.0)),
    ("closes at 1 s, neither", dict(settle_s=1.0, ramp_feedforward=False, gauge_linearized=False)),
    ("waits for the settle, no lead, not linearized", dict(ramp_feedforward=False, gauge_linearized=False)),
    ("default, noise off", dict(noise=False)),
)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--hold", type=float, default=20.0, help="hold after the triangle, s")
    a = ap.parse_args()
    plant = load_plant("plants/p888_51_sn637_creep.toml")
    c = Controller.load("controllers/sn637_fused_loopshape.json")
    setup = sensor_setup(plant, c)
    print("| fused loop, seed %d | closes at | triangle RMS (%% of stroke) | commanded | hold drift |" % a.seed)
    print("|---|---|---|---|---|")
    for tag, kw in CASES:
        r = run_sensor_loop(setup, c, "fused", hold_s=a.hold, seed=a.seed, sweep=False, **kw)
        print(f"| {tag} | {r['settle_s']:.2f} s | {r['triangle_rms_percent_stroke']:.4f} | "
              f"{r['triangle_commanded_rms_percent_stroke']:.4f} | {r['hold_drift_m'] * 1e9:+.2f} nm |", flush=True)


if __name__ == "__main__":
    main()
