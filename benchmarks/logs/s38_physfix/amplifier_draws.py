"""s38_physfix: the drawn-amplifier window test's numbers (seeds 3802-3810), printed per step.

Run from the worktree root: PYTHONPATH=. python benchmarks/logs/s38_physfix/amplifier_draws.py
"""
from dataclasses import replace

import numpy as np

from tests.verify.test_rout_window import AMPLIFIER_DRAWS, _c_max_f, _step
from workbench.controller import Controller
from workbench.plant import load_plant
from workbench.verify import scenarios as S

design = Controller.load("controllers/sn637_loopshape.json").as_lti()
for p in AMPLIFIER_DRAWS:
    name, i_src, i_snk, steps = p.values
    plant = load_plant(f"plants/{name}.toml", overrides={"electrical.series_resistor_in": False,
                                                        "electrical.current_limit_source_a": i_src,
                                                        "electrical.current_limit_sink_a": i_snk})
    pz = plant.pzt
    c_max = _c_max_f(pz)
    w_c = Controller.from_lti(design, plant, name="r")
    bare = Controller.from_lti(design, plant, window=False, name="r").firmware()
    free_p = replace(plant, pzt=pz.terminal_driven())
    for dx in steps:
        run_s = 0.3 + 3.0 * abs(dx) * (100.0 / S.stroke_m(pz)) * c_max / min(i_src, i_snk)
        w, f, o = _step(plant, w_c.firmware(), dx, run_s), _step(free_p, bare, dx, run_s), _step(plant, bare, dx, run_s)
        du = np.diff(w["u"])
        print(f"{p.id} {name} +{i_src*1e3:.2f}/-{i_snk*1e3:.2f} mA step {dx*1e6:+.2f} um run {run_s:.2f} s | window ov "
              f"{w['ov']:.3f} % st {w['st']*1e3:.1f} ms clipped {w['limit_s']*1e3:.1f} ms C_max du/(I T) up "
              f"{c_max*du.max()/(i_src*1e-4):.6f} down {-c_max*du.min()/(i_snk*1e-4):.6f} | no window ov {o['ov']:.2f} % "
              f"st {o['st']*1e3:.1f} ms clipped {o['limit_s']*1e3:.1f} ms | unlimited ov {f['ov']:.3f} % st "
              f"{f['st']*1e3:.1f} ms", flush=True)
