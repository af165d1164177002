"""Kirchhoff's current law at the terminal: the fixed plant step against the step before the fix.

SN637 with creep (modes left out: they filter x only), dt = 10 us:

* open leads: hold 100 V 10 s at 80 ohm, short (0 V) 1 s, then the leads open (2e14 ohm, 0 V) for 10 s;
  the terminal charge's drift over the open stretch against the charge the 2e14 ohm itself passes;
* 80 ohm without current limiting (ramps, holds, a 0.5 V 5 Hz sine): the largest change in V_t, q, x
  against the bound R I_creep (tests/plant/test_kcl.py);
* 80 ohm through a 100 V step's current-limited slew: the largest change in q and x, and after it.

The step before the fix is ``_pre_fix_step`` of tests/plant/test_kcl.py (the baseline of its bounds).

    PYTHONPATH=. .venv/bin/python benchmarks/kcl_creep.py
"""

import dataclasses
import importlib.util
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from workbench.plant import PZTSimulator, load_plant  # noqa: E402
from workbench.plant import kernels as K  # noqa: E402


def _tests():
    spec = importlib.util.spec_from_file_location("test_kcl", ROOT / "tests" / "plant" / "test_kcl.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def open_lead_drift(pz, step, dt):
    """Terminal charge drift over 10 s of open leads after 10 s at 100 V and 1 s shorted, and the 2e14 ohm's charge."""
    T = _tests()
    sim = PZTSimulator(pz, dt)
    z = lambda n: np.zeros(n)                                        # noqa: E731
    T._run(step, sim.m, sim.st, np.full(int(10 / dt), 100.0), z(int(10 / dt)))
    T._run(step, sim.m, sim.st, z(int(1 / dt)), z(int(1 / dt)))
    q0 = sim.st[K.S_QH] + sim.st[K.S_QC]
    op = PZTSimulator(pz.with_resistance(T.R_OPEN_OHM), dt)
    op.st[:] = sim.st
    rec = T._run(step, op.m, op.st, z(int(10 / dt)), z(int(10 / dt)))
    return np.max(np.abs(rec[:, 1] - q0)), np.sum(np.abs(rec[:, 5])) * dt / T.R_OPEN_OHM, rec[0, 3], rec[-1, 3]


def main():
    T = _tests()
    pz = dataclasses.replace(load_plant(ROOT / "plants" / "p888_51_sn637_creep.toml").pzt, modes=())
    dt = 1e-5
    for name, step in (("before the fix", T._pre_fix_step), ("after the fix", K.pzt_step)):
        drift, leak, vh0, vh1 = open_lead_drift(pz, step, dt)
        print(f"open leads, {name}: terminal charge drift {drift:.4g} C over 10 s (the 2e14 ohm passes at most "
              f"{leak:.3g} C); V_h {vh0:.4f} -> {vh1:.4f} V")
    n = int(1 / dt)
    t = np.arange(n) * dt
    r = pz.series_resistance_ohm
    v = np.concatenate([np.linspace(0.0, 60.0, 3 * n), np.full(n, 60.0), 60.0 + 0.5 * np.sin(2 * np.pi * 5 * t),
                        np.linspace(60.0, 40.0, n), np.full(n, 40.0)])
    new, old = T._both(pz, v, dt)
    ic = T._creep_current_bound_a(pz, new[:, 3], old[:, 3])
    print(f"80 ohm, ramps/holds/sine (no current limit): max |dV_t| {np.max(np.abs(new[:, 5] - old[:, 5])) * 1e3:.3f} mV "
          f"(bound R I_creep {r * ic * 1e3:.2f} mV), max |dq| {np.max(np.abs(new[:, 1] - old[:, 1])) * 1e9:.1f} nC "
          f"(bound {T._c_big_f(pz) * r * ic * 1e9:.0f} nC), max |dx| {np.max(np.abs(new[:, 0] - old[:, 0])) * 1e9:.3f} nm "
          f"of {np.max(new[:, 0]) * 1e6:.2f} um")
    v = np.concatenate([np.full(int(1.5 / dt), 100.0), np.full(int(0.5 / dt), 20.0)])
    new, old = T._both(pz, v, dt)
    k = int(1.5 / dt) - 1
    print(f"80 ohm, 0 -> 100 V -> 20 V steps (2 mA / 14 mA slews): max |dq| {np.max(np.abs(new[:, 1] - old[:, 1])) * 1e9:.1f} nC, "
          f"max |dx| {np.max(np.abs(new[:, 0] - old[:, 0])) * 1e9:.1f} nm; |dx| at 1.5 s {abs(new[k, 0] - old[k, 0]) * 1e9:.2f} nm, "
          f"at 2 s {abs(new[-1, 0] - old[-1, 0]) * 1e9:.2f} nm")


if __name__ == "__main__":
    main()
