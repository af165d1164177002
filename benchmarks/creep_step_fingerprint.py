"""Every creep code path's outputs hashed (s12_tidy item 3): run before and after a change to the creep step; the same
sha256 means bit for bit. Usage: PYTHONPATH=. python benchmarks/creep_step_fingerprint.py OUT.npz"""
import dataclasses, sys, hashlib
import numpy as np
from workbench.plant import load_plant, PZTSimulator
from workbench.plant import kernels as K
from workbench.plant.coupled import CoupledSimulator
from workbench.plant.structure import spring
from workbench.selfsense.force import estimate_force
from workbench.selfsense.instron_sequence import serial_sequence

out = {}
creep = load_plant("plants/p888_51_sn637_creep.toml")
pz = creep.pzt
rng = np.random.default_rng(5)
for dt, n_sub in ((1e-6, 1), (1e-4, 3), (1e-2, 1)):
    n = 3000
    t = np.arange(n) * dt
    v = 50 + 60 * np.sin(2 * np.pi * 3 / (n * dt) * t) + rng.normal(0, 5, n)
    f = 300 * np.sin(2 * np.pi * 5 / (n * dt) * t)
    for r_name, p in (("dyn", pz), ("qs", pz.with_resistance(0.0)), ("open", pz.with_resistance(2e14))):
        sim = PZTSimulator(p, dt, n_sub)
        tr = sim.run(v, f)
        out[f"run_{r_name}_{dt}"] = np.column_stack([tr.x_m, tr.q_c, tr.i_a, tr.v_h_v, tr.v_t_v])
        out[f"st_{r_name}_{dt}"] = sim.st.copy()
        # the reference step
        sim2 = PZTSimulator(p, dt, 1)
        o = np.empty(K.N_OUT)
        rows = []
        for k in range(300):
            K.pzt_step_reference(sim2.m, sim2.st, v[k], f[k], o)
            rows.append(o.copy())
        out[f"ref_{r_name}_{dt}"] = np.array(rows)
    bare = dataclasses.replace(pz, modes=())
    for term in ("amplifier", "open"):
        cs = CoupledSimulator([bare], spring(bare.stiffness_n_per_m), dt, n_sub=n_sub, terminations=[term])
        got = cs.run(v, f)
        out[f"coupled_{term}_{dt}"] = np.column_stack([got.x_m[:, 0], got.v_t_v[:, 0], got.q_c[:, 0]])
    tr = PZTSimulator(pz, dt).run(v, f)
    est = estimate_force(tr.t_s, tr.v_t_v, tr.q_c, pz)
    out[f"force_{dt}"] = np.column_stack([est.v_h_v, est.x_m, est.f_e_n])
runs = [("R_out", -800.0), ("R_in", -1200.0), ("R_out", -500.0), ("R_in", -300.0)]
for i, s in enumerate(serial_sequence(pz, runs, drain_s=3.0)):
    out[f"seq_{i}"] = np.array([float(x) for x in dataclasses.astuple(s) if np.ndim(x) == 0 and isinstance(x, (int, float))] +
                               [float(np.sum(np.asarray(x, float))) for x in dataclasses.astuple(s) if np.ndim(x) > 0])
np.savez(sys.argv[1], **out)
h = hashlib.sha256()
for k in sorted(out):
    h.update(k.encode()); h.update(np.ascontiguousarray(out[k]).tobytes())
print(len(out), h.hexdigest())
