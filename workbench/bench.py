"""Benchmark of the compiled PZT against python-control's ``input_output_response``.

The compiled run steps the SN637 model (dynamic form, 10 plays, creep branches,
the 70 kHz mode) at 10 kHz for ``steps`` samples, compile time excluded (one warm
call first) and best of ``repeats`` timed calls, keeping every 1000th sample.

The reference wraps the very same step function, run by the interpreter (numba's
JIT disabled in a child process), as a discrete-time
``control.NonlinearIOSystem`` and times ``control.input_output_response`` over a
shorter span; the ratio is per step, both measured in this one run.
"""

import json
import os
import subprocess
import sys
import time

import numpy as np

__all__ = ["run_bench"]

SAMPLE_S = 1e-4


def _drive(n):
    """A servo-like command: a 1 Hz 10-90 V sine with a step every 0.5 s."""
    t = np.arange(n) * SAMPLE_S
    return 50 + 35 * np.sin(2 * np.pi * t) + 5 * np.sign(np.sin(2 * np.pi * 1 * t + 0.3))


def _reference(plant_path, steps):
    """Run in a child process with NUMBA_DISABLE_JIT=1: python-control on the same step."""
    import control

    from .plant import load_plant
    from .plant.kernels import pzt_step
    from .plant.simulator import PZTSimulator

    sim = PZTSimulator(load_plant(plant_path).pzt, SAMPLE_S)
    m = sim.m
    out = np.empty(6)

    def update(t, x, u, params):
        st = np.array(x, dtype=float)
        pzt_step(m, st, u[0], u[1], out)
        return st

    def output(t, x, u, params):
        return x[:1]

    sys_ = control.NonlinearIOSystem(update, output, inputs=2, outputs=1, states=sim.st.size,
                                     dt=SAMPLE_S, name="pzt")
    u = np.vstack([_drive(steps), np.zeros(steps)])
    t = np.arange(steps) * SAMPLE_S
    t0 = time.perf_counter()
    control.input_output_response(sys_, t, u, X0=sim.st.copy())
    return time.perf_counter() - t0


def run_bench(plant_path="plants/p888_51_sn637_creep.toml", *, steps=10_000_000, reference_steps=2000,
              repeats=3, progress=None):
    """Time the compiled model and the python-control reference; return a JSON-ready dict.

    Parameters
    ----------
    plant_path : str or Path
    steps : int
        Steps of the compiled run (10^7 = 1000 s at 10 kHz).
    reference_steps : int
        Steps of the python-control reference.
    repeats : int
        Timed calls of the compiled run; the best is kept.
    progress : callable, optional
        Receives one line per stage.
    """
    from .plant import load_plant
    from .plant.simulator import PZTSimulator

    say = progress or (lambda line: None)
    plant = load_plant(plant_path)
    sim = PZTSimulator(plant.pzt, SAMPLE_S)
    say("compiling the kernel (cached after the first run)...")
    sim.run(_drive(100))
    v = _drive(steps)
    times = []
    for k in range(repeats):
        sim.reset()
        t0 = time.perf_counter()
        sim.run(v, decimate=1000)
        times.append(time.perf_counter() - t0)
        say(f"compiled run {k + 1}/{repeats}: {times[-1]:.3f} s")
    best = min(times)
    say(f"python-control reference over {reference_steps} steps (interpreted, child process)...")
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    code = ("import json,sys; from workbench.bench import _reference; "
            f"print(json.dumps(_reference({str(plant_path)!r}, {int(reference_steps)})))")
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"python-control reference failed:\n{done.stderr}")
    ref_s = float(json.loads(done.stdout.strip().splitlines()[-1]))
    sps = steps / best
    ref_sps = reference_steps / ref_s
    pz = plant.pzt
    return {
        "model": (f"{plant.name}: dynamic form, {pz.hysteresis.size} plays, "
                  f"{0 if pz.creep is None else pz.creep.size} creep branches, {len(pz.modes)} modes"),
        "plant": str(plant_path),
        "sample_time_s": SAMPLE_S,
        "steps": steps,
        "seconds": best,
        "seconds_all_repeats": times,
        "steps_per_second": sps,
        "python_control_steps": reference_steps,
        "python_control_seconds": ref_s,
        "python_control_steps_per_second": ref_sps,
        "ratio_vs_python_control": sps / ref_sps,
        "control_version": __import__("control").__version__,
        "numba_version": __import__("numba").__version__,
    }
