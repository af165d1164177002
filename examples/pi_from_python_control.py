"""A PI designed in python-control, turned into firmware form and verified (README: "my own controller")."""
import control
import numpy as np

import workbench as wb

plant = wb.load_plant("plants/p888_51_sn637_creep.toml")
P = wb.nominal_loop_plant(plant)                  # PZT V -> reading V, discrete, as firmware sees it
s, fc_hz = control.tf("s"), 100.0                 # PI: crossover fc, zero at fc / 3
pi = (s + 2 * np.pi * fc_hz / 3) / s
z = np.exp(2j * np.pi * fc_hz * P.dt)
kp = 1 / abs(control.sample_system(pi, P.dt, "tustin")(z) * P(z)).item()   # |L| = 1 at fc
ctrl = wb.Controller.from_lti(kp * pi, plant, name="pi_example")           # Tustin, words, window
print(ctrl.describe())
print(wb.margins_of(ctrl.as_lti(quantized=True) * P))
result = wb.verify(plant, ctrl, ["small_step", "large_step"], hold_s=10.0)
print(result)
for name, t in result.targets.items():
    print(f"  {name}: {t['value'] if t['value'] is not None else t['why']} (limit {t['limit']:g} {t['unit']})")
