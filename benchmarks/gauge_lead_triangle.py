"""The gauge design's 0.1 Hz triangle in both verify harnesses, with and without the firmware settings its
sensor block carries (the reference lead 1/K_v and the bridge curvature).

``workbench study`` exports every controller with its sensor block and firmware's three startup settings
(``verify/sensors.py: with_firmware_startup``); verify's gauge scenarios (``verify/closed_loop.py``) honour
the lead and the curvature when the block carries them, as the sensor loop (``verify/sensors.py``) does. This
runs ``triangle_0p1hz`` of the gauge scenarios with the block stripped (bare), with each setting alone and with
both, then the sensor loop's gauge triangle (20 s hold, no sweep) on the same export, for a few noise draws.

    workbench study studies/sn637_servo.toml --out /tmp/gauge_study --only loopshape
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. .venv/bin/python benchmarks/gauge_lead_triangle.py \\
        /tmp/gauge_study/controllers/sn637_loopshape.json [--seeds 0 1 2]
"""

import argparse
from dataclasses import replace

from workbench.controller import Controller
from workbench.plant import load_plant
from workbench.verify.scenarios import run_scenario
from workbench.verify.sensors import run_sensor_loop, sensor_setup


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("controller", help="a gauge export whose sensor block carries ref_lead_s and "
                                       "gauge_curvature_per_m (workbench study's)")
    ap.add_argument("--plant", default="plants/p888_51_sn637_creep.toml")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    a = ap.parse_args()
    plant = load_plant(a.plant)
    full = Controller.load(a.controller, plant=plant)
    sb = full.sensor
    if sb is None or sb.ref_lead_s is None or sb.gauge_curvature_per_m is None:
        raise SystemExit(f"{a.controller}: the sensor block carries no ref_lead_s / gauge_curvature_per_m; "
                         f"export it with workbench study")
    variants = {"bare": replace(full, sensor=None),
                "lead only": replace(full, sensor=replace(sb, gauge_curvature_per_m=None)),
                "curvature only": replace(full, sensor=replace(sb, ref_lead_s=None)),
                "lead and curvature": full}
    print(f"lead {sb.ref_lead_s * 1e3:.4f} ms, beta {sb.gauge_curvature_per_m:.3f} 1/m, wait {sb.startup_wait_s} s")
    setup = sensor_setup(plant, full, ident_hold_s=150.0)      # the gauge loop does not read the charge channel
    for seed in a.seeds:
        row = [f"{k} {run_scenario(plant, c.firmware(), 'triangle_0p1hz', seed=seed)[0]['error_rms_percent_of_stroke']:.4f} %"
               for k, c in variants.items()]
        r = run_sensor_loop(setup, full, "gauge", hold_s=20.0, seed=seed, sweep=False)
        row.append(f"sensor loop {r['triangle_rms_percent_stroke']:.4f} %")
        print(f"seed {seed}: closed_loop.py " + ", ".join(row), flush=True)


if __name__ == "__main__":
    main()
