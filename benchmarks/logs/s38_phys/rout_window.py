"""Large step on R-out plants: the current-limit window with alpha = 1, h = I T / C for C = C_max / C_min,
against no window (session 37) and against the same loop with an unlimited amplifier.

The controller: controllers/sn637_loopshape.json's cascade (the workbench's loop-shaped PI + lead + roll-off),
re-quantized for each R-out plant (Controller.from_lti with the plant), window set explicitly.
Run: PYTHONPATH=. python benchmarks/logs/s38_phys/rout_window.py [step_um ...]
"""
import glob
import sys
from dataclasses import replace

import numpy as np

from workbench.controller import Controller
from workbench.design.antiwindup import _largest_capacitance_f
from workbench.export.fixed_point import quantize
from workbench.plant import load_plant
from workbench.verify import scenarios as S
from workbench.verify.closed_loop import ClosedLoop


def c_min_f(pz):
    w0 = float(pz.hysteresis.weights[0])
    return 1.0 / (1.0 / w0 + 1.0 / pz.c_pp_f)


def with_window(c, model):
    fxp = quantize(c.gain, np.array(c.sos), c.dt_s, input_range_v=c.fixed.input_range_v,
                   output_limits_v=c.output_limits_v, f_max_hz=c.fixed.f_max_hz, voltage_model=model)
    return replace(c, fixed=fxp, voltage_model=model, window_source="file" if model else "none")


def step(plant, fw, dx, anti_windup=True):
    g = plant.gauge
    dt = fw.dt_s
    cl = ClosedLoop(plant, fw, noise=False, anti_windup=anti_windup, seed=0)
    S._approach(cl, g, S.X_START_M, dt)
    x1 = S.X_START_M + dx
    n = int(0.5 / dt)
    r = cl.run(S._to_volts(np.full(n, x1), g))
    ov, st = S._step_metrics(r.t_s, r.x_m, S.X_START_M, x1)
    rise = S._rise_time(r.t_s - r.t_s[0] + dt, r.x_m, S.X_START_M, x1)
    du = np.diff(r.u_v)
    return dict(ov=ov, st=st, rise=rise, lim_periods=r.periods_at_current_limit, held=r.samples_rate_limited,
                du_up=du.max(), du_dn=-du.min(), ipk=r.peak_current_a)


ref = Controller.load("controllers/sn637_loopshape.json")
K = ref.as_lti()
steps = [float(s) * 1e-6 for s in sys.argv[1:]] or [5e-6]
for f in sorted(glob.glob("plants/p888_51_*.toml")):
    plant = load_plant(f, overrides={"electrical.series_resistor_in": False})
    pz = plant.pzt
    dt = 1.0 / plant.gauge.modulation_hz
    base = Controller.from_lti(K, plant, window=False, name="rout")
    cmax, cmin = _largest_capacitance_f(pz), c_min_f(pz)
    unlimited = replace(plant, pzt=pz.terminal_driven())
    rows = {
        "unlimited amp": step(unlimited, with_window(base, None).firmware(), 0),
    }
    for dx in steps:
        rows = {
            "unlimited amp, no window": step(unlimited, with_window(base, None).firmware(), dx),
            "no window (s37)": step(plant, with_window(base, None).firmware(), dx),
            "range clip only (--no-anti-windup)": step(plant, with_window(base, None).firmware(), dx, anti_windup=False),
            "window C_max": step(plant, with_window(base, (1.0, pz.current_limit_source_a * dt / cmax,
                                                             pz.current_limit_sink_a * dt / cmax)).firmware(), dx),
            "window C_min": step(plant, with_window(base, (1.0, pz.current_limit_source_a * dt / cmin,
                                                             pz.current_limit_sink_a * dt / cmin)).firmware(), dx),
        }
        print(f"{f.split('/')[-1]} R out, step {dx * 1e6:g} um, C_max {cmax * 1e6:.4g} uF, C_min {cmin * 1e6:.4g} uF, "
              f"I T / C_max {pz.current_limit_source_a * dt / cmax * 1e3:.4g} mV up")
        for k, m in rows.items():
            print(f"  {k:36s} overshoot {m['ov']:6.2f} %  settling {m['st'] * 1e3:7.1f} ms  rise {m['rise'] * 1e3:6.1f} ms  "
                  f"periods at the limit {m['lim_periods']:6.0f}  held by window {m['held']:5d}  "
                  f"max du/sample +{m['du_up'] * 1e3:.4g}/-{m['du_dn'] * 1e3:.4g} mV  peak i {m['ipk'][0] * 1e3:.3g}/{m['ipk'][1] * 1e3:.3g} mA")
        sys.stdout.flush()
