"""Which C for the R-out slew window: C = f C_max for f from C_min / C_max to 1, noise-free scenarios of `workbench verify`.

Controller: the loop-shaped design `workbench study studies/sn637_servo.toml --only loopshape --set
electrical.series_resistor_in=false` exported (copy in controllers/sn637_rout_loopshape.json here).
Plant: p888_51_sn637_creep.toml with series_resistor_in = false. Also: no window (session 37) and the
unlimited amplifier. Run: PYTHONPATH=. python benchmarks/logs/s38_phys/rout_c_sweep.py
"""
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from workbench.controller import Controller
from workbench.design.antiwindup import _largest_capacitance_f
from workbench.export.fixed_point import quantize
from workbench.plant import load_plant
from workbench.verify.scenarios import run_scenario

HERE = Path(__file__).parent
plant = load_plant("plants/p888_51_sn637_creep.toml", overrides={"electrical.series_resistor_in": False})
pz = plant.pzt
dt = 1.0 / plant.gauge.modulation_hz
c0 = Controller.load(HERE / "controllers" / "sn637_rout_loopshape.json")
cmax = _largest_capacitance_f(pz)
cmin = 1.0 / (1.0 / float(pz.hysteresis.weights[0]) + 1.0 / pz.c_pp_f)


def fw_with(model):
    fxp = quantize(c0.gain, np.array(c0.sos), c0.dt_s, input_range_v=c0.fixed.input_range_v,
                   output_limits_v=c0.output_limits_v, f_max_hz=c0.fixed.f_max_hz, voltage_model=model)
    return replace(c0, fixed=fxp, voltage_model=model).firmware()


cases = [("no window (s37)", plant, None)]
for f in (1.0, 0.9, 0.8, 0.7, 0.6, cmin / cmax):
    c = f * cmax
    cases.append((f"window C = {f:.3f} C_max ({c * 1e6:.2f} uF)", plant,
                  (1.0, pz.current_limit_source_a * dt / c, pz.current_limit_sink_a * dt / c)))
cases.append(("unlimited amplifier, no window", replace(plant, pzt=pz.terminal_driven()), None))
print(f"C_max {cmax * 1e6:.4g} uF, C_min {cmin * 1e6:.4g} uF; noise off")
for label, pl, model in cases:
    fw = fw_with(model)
    out = []
    for sc in ("small_step", "large_step", "triangle_1hz", "force_step"):
        m, _ = run_scenario(pl, fw, sc, noise=False)
        if sc.endswith("step") and sc != "force_step":
            out.append(f"{sc} ov {m['overshoot_percent']:.2f} % st {m['settling_s'] * 1e3:.1f} ms rise {m['rise_s'] * 1e3:.1f} ms")
        elif sc == "force_step":
            out.append(f"force peak {m['peak_deviation_m'] * 1e9:.0f} nm")
        else:
            out.append(f"tri1Hz err {m['error_rms_m'] * 1e9:.1f} nm rms, hyst ratio {m['hysteresis_ratio']:.3f}")
        out[-1] += f" [I-lim {m.get('time_at_current_limit_s', 0) * 1e3:.1f} ms]"
    print(f"{label:42s} " + " | ".join(out))
    sys.stdout.flush()
