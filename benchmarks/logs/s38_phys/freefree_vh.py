"""V_h of eqs. 7-8 from the measured V_pea (this branch) vs from the command, against the simulator's V_h.

Run from a worktree: PYTHONPATH=. python benchmarks/logs/s38_phys/freefree_vh.py
"""
import glob
import numpy as np
from workbench.identify import run_freefree, v_h_from_measurements
from workbench.plant import load_plant

for f in sorted(glob.glob("plants/p888*.toml")):
    p = load_plant(f)
    noise_v = p.gauge.noise_rms_m * p.pzt.stiffness_n_per_m / p.pzt.transducer_constant_n_per_v
    for vp, fr, rin in ((100, 0.1, False), (100, 0.1, True), (100, 2.0, False), (60, 5.0, False), (100, 2.0, True)):
        r = run_freefree(p, v_peak_v=vp, freq_hz=fr, cycles=2, resistor_in=rin, seed=3)
        t_em, k_p = p.pzt.transducer_constant_n_per_v, p.pzt.stiffness_n_per_m
        cmd = v_h_from_measurements(r.v_cmd_v, r.x_meas_m, t_em, k_p)
        e_new = r.v_h_est_v - r.v_h_true_v
        e_cmd = cmd - r.v_h_true_v
        print(f"{f.split('/')[-1]:28s} {vp:4g} V {fr:4g} Hz R{'in ' if rin else 'out'} lag max {np.abs(r.v_cmd_v - r.v_pea_v).max():8.3g} V"
              f" | V_h err rms {np.sqrt(np.mean(e_new**2)):.3g} max {np.abs(e_new).max():.3g} V"
              f" | command-based rms {np.sqrt(np.mean(e_cmd**2)):.3g} max {np.abs(e_cmd).max():.3g} V"
              f" | gauge noise k_p/T_em sigma_x {noise_v:.3g} V | Cp err {100*(r.cp_recovered_f/r.cp_true_f-1):+.3f} %")
