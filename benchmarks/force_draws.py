"""Force self-sensing on held-out force steps: bias, force and noise drawn, each with its own identification record.

Per draw: V_pea held at a bias drawn in [10, 100] V, a force step of 20-500 N (log-uniform,
either sign) at 30 s, 60 s at 1 kHz; the identification record (F_e = 0) simulated with its own
noise seed. Prints the force error from 1 s after the step to the end of the record, from the
reset and tared over the second before the step, for the displacement estimator's stage 4 read
as charge and for the force path's compensation in coulombs (workbench/selfsense/charge_drift.py).

    PYTHONPATH=. .venv/bin/python benchmarks/force_draws.py --n 8 --seed 777
    PYTHONPATH=. .venv/bin/python benchmarks/force_draws.py --n 12 --seed 20261123 --dt 5e-4 --hold 300
"""

import argparse
from pathlib import Path

import numpy as np

from workbench.plant import load_plant
from workbench.selfsense.charge_amp import ChargeAmpParams
from workbench.selfsense.charge_drift import identify_charge_drift
from workbench.selfsense.force import FORCE_STAGE, force_step_errors, simulate_force_step
from workbench.selfsense.identify import identify, simulate_identification

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plant", default=str(ROOT / "plants/p888_51_sn637_creep.toml"))
    ap.add_argument("--n", type=int, default=8, help="number of draws")
    ap.add_argument("--seed", type=int, default=777, help="seed of the draw")
    ap.add_argument("--dt", type=float, default=1e-4, help="plant step, s (the CLI's default)")
    ap.add_argument("--hold", type=float, default=700.0, help="identification holds, s (the CLI's default)")
    a = ap.parse_args(argv)
    pzt = load_plant(a.plant).pzt
    amp = ChargeAmpParams()
    rng = np.random.default_rng(a.seed)
    rows = []
    for k in range(a.n):
        bias = rng.uniform(10.0, 100.0)
        force = np.exp(rng.uniform(np.log(20.0), np.log(500.0))) * rng.choice([-1, 1])
        seed = int(rng.integers(1000, 10 ** 6))
        idrec = simulate_identification(pzt, amp, hold_s=a.hold, seed=seed + 100, dt_s=a.dt)
        ident = identify(idrec, amp)
        drift = identify_charge_drift(idrec, ident)
        rec, f = simulate_force_step(pzt, amp, dt_s=a.dt, seed=seed, bias_v=bias, force_n=force)
        e = force_step_errors(rec, f, ident, pzt, 30.0, ("hysteresis_creep", FORCE_STAGE), drift)
        s4, fc = e["hysteresis_creep"], e[FORCE_STAGE]
        row = (s4["abs_error_max_n"]["1s_end"], s4["tared_error_max_n"]["1s_end"],
               fc["abs_error_max_n"]["1s_end"], fc["tared_error_max_n"]["1s_end"])
        rows.append(row)
        print(f"{k + 1}/{a.n}  bias {bias:5.1f} V  step {force:+7.1f} N | stage 4: {row[0]:5.2f} N from reset, "
              f"{row[1]:5.2f} N tared | coulombs: {row[2]:5.2f} N, {row[3]:5.2f} N | alpha "
              f"{drift.alpha_c_per_m * pzt.k_q2x_m_per_c - 1:+.1e} (sem {drift.alpha_sem_c_per_m / drift.alpha_c_per_m:.1e})",
              flush=True)
    r = np.array(rows)
    print(f"max over {a.n} draws | stage 4: {r[:, 0].max():.2f} N from reset, {r[:, 1].max():.2f} N tared | "
          f"coulombs: {r[:, 2].max():.2f} N, {r[:, 3].max():.2f} N | within 2 N (both): "
          f"stage 4 {int(np.sum(np.max(r[:, :2], axis=1) <= 2.0))}/{a.n}, coulombs {int(np.sum(np.max(r[:, 2:], axis=1) <= 2.0))}/{a.n}")


if __name__ == "__main__":
    main()
