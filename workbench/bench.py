"""Benchmarks of the compiled PZT and closed loop against python-control's ``input_output_response``.

The compiled run steps the SN637 model (dynamic form, its plays, creep branches,
the 70 kHz mode) at 10 kHz for ``steps`` samples, compile time excluded (one warm
call first) and best of ``repeats`` timed calls, keeping every 1000th sample.

The reference wraps the very same step function, run by the interpreter (numba's
JIT disabled in a child process), as a discrete-time
``control.NonlinearIOSystem`` and times ``control.input_output_response`` over a
shorter span; the ratio is per step, both measured in this one run.

The closed-loop benchmark is the 1000 s hold at the 10 kHz servo rate: 10^7 periods of
:class:`workbench.verify.closed_loop.ClosedLoop` (the full creep plant, gauge noise on,
the exported controller as firmware runs it), mid-stroke reference, decimate 1000. Its
reference is the same loop's own ``_loop`` run by the interpreter (JIT disabled in a
child process) for ONE period per ``update`` of a discrete ``control.NonlinearIOSystem``
whose state is the plant state plus the controller state (cascade, voltage model,
pending output); inputs are the reference, the force and the gauge noise's standard
normal, drawn as ``ClosedLoop.run`` draws them, so the reference's final state is checked against the
compiled run of the same length. The reference starts after the hold's slew from rest
(:func:`_settled_period`; those periods run first, untimed), so both sides time hold periods.
Both wall and CPU ratios are kept: under load the child's wall time stretches with the
machine's load (measured 3x at a load of 8 on 2 cores) while the compiled side keeps the best
of its repeats, so the CPU ratio is the stable figure. The C reference is the same loop in plain C
(``benchmarks/closed_loop_vs_c.py``, built with gcc where one exists), timed in this run
on the same inputs, its trajectory checked word for word against the compiled one.
Targets (issue 17): <= 3x the C loop, >= 3000x python-control, ~0.6 s per 10^7 periods
on this machine; peak RSS of a 10^8-period hold < 500 MB
(``benchmarks/closed_loop_memory.py``, in a child process). Timings are wall clock, best
of the repeats, with the thread's CPU time beside them (less sensitive to other load).
"""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["run_bench", "closed_loop_bench"]

SAMPLE_S = 1e-4
CONTROLLER = "controllers/sn637_loopshape.json"
X_HOLD_M = 7.5e-6                     # mid-stroke
HOLD_DECIMATE = 1000
TARGET_RATIO = 3000.0
TARGET_SECONDS_PER_1E7 = 0.6
TARGET_C_RATIO = 3.0
MEMORY_DECIMATE = 10_000
MEMORY_SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "closed_loop_memory.py"
C_SCRIPT = MEMORY_SCRIPT.with_name("closed_loop_vs_c.py")


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


def _hold(plant_path, controller_path, **kw):
    """A fresh ClosedLoop on the plant file and controller JSON, and the mid-stroke reference (V)."""
    from .plant import load_plant
    from .verify.closed_loop import ClosedLoop, controller_from_json
    from .verify.scenarios import _to_volts

    plant = load_plant(plant_path)
    ctrl = controller_from_json(json.loads(Path(controller_path).read_text()))
    return ClosedLoop(plant, ctrl, **kw), float(_to_volts(X_HOLD_M, plant.gauge))


class _Draw:
    """Stands in for the Generator ``_loop`` draws its gauge noise from: returns the period's input ``z``.

    The interpreted loop calls ``rng.standard_normal()`` once a period; here that draw is an input
    of the python-control system (drawn up front from the same seeded generator), so the system is a
    pure function of its state and inputs, whatever order python-control evaluates it in.
    """

    z = 0.0

    def standard_normal(self):
        return self.z


def _closed_loop_reference(plant_path, controller_path, periods, start=0):
    """Run in a child process with NUMBA_DISABLE_JIT=1: python-control on the closed loop's own period.

    The loop first runs ``start`` periods by itself (the slew from rest to the hold, not
    timed), so the reference times periods of the hold, as most of the compiled run's are.
    Returns the wall and CPU seconds of ``input_output_response`` over ``periods`` updates
    and the state after ``start + periods - 1`` periods (python-control drops the last
    update's result). The arguments mirror ``ClosedLoop.run``'s call of ``_loop`` (private
    attributes): if that call changes, this breaks or the state check in
    :func:`closed_loop_bench` shows it.
    """
    import control

    from .verify.closed_loop import _loop

    loop = getattr(_loop, "py_func", _loop)        # JIT disabled: _loop is already the Python function
    cl, ref = _hold(plant_path, controller_path)
    if start:
        cl.run(ref, periods=start)
    # the arrays _loop updates in place (plant, cascade, Hanus and voltage-model states, io), in the state vector
    parts = [cl.sim.st, cl._hx, cl._csf, cl._csi, cl._vmf, cl._vmi, cl._io]
    ends = np.cumsum([a.size for a in parts])
    i_x, i_u = ends[-2] + 1, ends[-2]               # io = [pending output, last x, ...]
    c = cl.controller
    fixed_args = (cl._gp, cl._r0, cl._form, cl._ha, cl._hb, cl._hc, cl._hd, cl._hx, float(c.gain), cl._sos,
                  cl._fb, cl._fa, cl._fshift, cl._ffrac, cl._fin, cl._in_scale, cl._out_scale, cl._csf, cl._csi,
                  cl._vmf, cl._vmi, cl._lim, cl._limw, cl.anti_windup, 1, cl._io)
    rec, stats = np.zeros((1, 6)), np.zeros(5)
    draw = _Draw()

    def update(t, x, u, params):
        for a, seg in zip(parts, np.split(x, ends[:-1])):
            a.flat[:] = seg                          # int64 words are exact in float64 (int32 range)
        cl._io[2:] = 0.0                             # a fresh one-row trace each period
        draw.z = u[2]                                # the period's standard normal, an input of the system
        loop(cl.sim.m, cl.sim.st, cl.n_sub, u[0:1], u[1:2], draw, cl.sigma_v, *fixed_args, rec, stats)
        return np.concatenate([a.ravel() for a in parts]).astype(float)

    def output(t, x, u, params):
        return x[i_x:i_x + 1]

    sys_ = control.NonlinearIOSystem(update, output, inputs=3, outputs=1, states=int(ends[-1]),
                                     dt=c.dt_s, name="closed_loop")
    # inputs: reference, force, the gauge noise's standard normal (the draws ClosedLoop.run makes, in order)
    noise = cl._rng.standard_normal(periods)
    u = np.vstack([np.full(periods, ref), np.zeros(periods), noise])
    t = np.arange(periods) * c.dt_s
    x0 = np.concatenate([a.ravel() for a in parts]).astype(float)
    c0, t0 = time.thread_time(), time.perf_counter()
    resp = control.input_output_response(sys_, t, u, X0=x0, return_states=True)
    sec, cpu = time.perf_counter() - t0, time.thread_time() - c0
    return {"seconds": sec, "cpu_seconds": cpu, "x_m": float(resp.states[i_x, -1]),
            "u_v": float(resp.states[i_u, -1])}


def _child(call):
    """Evaluate ``call`` (an expression in workbench.bench) in a child process with numba's JIT disabled."""
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    code = f"import json,sys; from workbench import bench; print(json.dumps(bench.{call}))"
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"python-control reference failed:\n{done.stderr}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _memory_module(script=MEMORY_SCRIPT):
    """A script of benchmarks/ (beside the package, not part of it) as a module."""
    import importlib.util

    if not script.is_file():
        raise FileNotFoundError(f"{script} is missing (the benchmark scripts run from a source checkout)")
    spec = importlib.util.spec_from_file_location(script.stem, script)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _settled_period(plant_path, controller_path, window_s=1.0):
    """The first period of the hold after its slew from rest: where the error stays inside the noise.

    The compiled loop runs ``window_s`` at decimate 1; the slew is over at the period after the last
    one whose |error| exceeds 10 standard deviations of the reading's noise plus one DAC step (on the
    SN637 hold: ~3240 periods, the ~3260 the current-limit window holds). 0 without noise or slew.
    """
    cl, ref = _hold(plant_path, controller_path)
    g = cl.plant.gauge
    tr = cl.run(ref, periods=max(1, round(window_s / cl.controller.dt_s)))
    band = 10.0 * cl.sigma_v * g.trim_scale + 2.0 * g.dac_range_v / 2.0 ** g.dac_bits
    out = np.nonzero(np.abs(tr.error_v) > band)[0]
    return int(out[-1]) + 1 if out.size else 0


def closed_loop_bench(plant_path="plants/p888_51_sn637_creep.toml", controller_path=CONTROLLER, *,
                      periods=10_000_000, reference_periods=2000, repeats=3, memory_periods=10**8, progress=None,
                      c_reference=True):
    """The closed-loop hold benchmark (see the module docstring); a JSON-ready dict.

    ``c_reference``: also time the plain C loop (needs gcc and a source checkout; the
    SN637 hold only, as that script builds it).
    """
    say = progress or (lambda line: None)
    reference_periods = max(2, int(reference_periods))   # its state check needs one compiled period
    say("compiling the closed loop (cached after the first run)...")
    cl, ref = _hold(plant_path, controller_path)
    cl.run(ref, periods=1000)                         # warm-up on its own object: compile/load excluded
    times, cpu = [], []
    for k in range(repeats):
        cl, ref = _hold(plant_path, controller_path)  # same seed, same noise each repeat
        c0, t0 = time.thread_time(), time.perf_counter()
        cl.run(ref, decimate=HOLD_DECIMATE, periods=periods)
        times.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)
        say(f"closed-loop hold {k + 1}/{repeats}: {times[-1]:.3f} s (CPU {cpu[-1]:.3f} s)")
    best = min(times)
    start = _settled_period(plant_path, controller_path)
    say(f"python-control closed-loop reference over {reference_periods} periods of the hold (from period "
        f"{start}, after the slew; interpreted, child process)...")
    r = _child(f"_closed_loop_reference({str(plant_path)!r}, {str(controller_path)!r}, {int(reference_periods)}, "
               f"{start})")
    # the compiled loop over the periods the reference's last state has seen: the same computation?
    chk, _ = _hold(plant_path, controller_path)
    tr = chk.run(ref, periods=start + reference_periods - 1)
    pps, ref_pps = periods / best, reference_periods / r["seconds"]
    ratio_cpu = (r["cpu_seconds"] / reference_periods) / (min(cpu) / periods)
    per_1e7 = best * 1e7 / periods
    out = {
        "controller": str(controller_path),
        "controller_form": cl.controller.describe(),
        "plant": str(plant_path),
        "scenario": f"hold at {X_HOLD_M * 1e6:g} um (reference {ref:+.4g} V), gauge noise on, n_sub {cl.n_sub}, "
                    f"anti-windup on, decimate {HOLD_DECIMATE}",
        "sample_time_s": cl.controller.dt_s,
        "periods": periods,
        "seconds": best,
        "seconds_all_repeats": times,
        "cpu_seconds_all_repeats": cpu,
        "seconds_per_1e7_periods": per_1e7,
        "periods_per_second": pps,
        "python_control_periods": reference_periods,
        "python_control_start_period": start,
        "python_control_seconds": r["seconds"],
        "python_control_cpu_seconds": r["cpu_seconds"],
        "python_control_periods_per_second": ref_pps,
        "ratio_vs_python_control": pps / ref_pps,
        "ratio_vs_python_control_cpu": ratio_cpu,
        "python_control_state_difference": {"x_m": abs(r["x_m"] - float(tr.x_m[-1])),
                                            "u_v": abs(r["u_v"] - chk.u)},
        "targets": {"ratio_min": TARGET_RATIO, "seconds_per_1e7_max": TARGET_SECONDS_PER_1E7},
        "meets_target": {"ratio": pps / ref_pps >= TARGET_RATIO, "ratio_cpu": ratio_cpu >= TARGET_RATIO,
                         "seconds": per_1e7 < TARGET_SECONDS_PER_1E7,
                         "seconds_cpu": min(cpu) * 1e7 / periods < TARGET_SECONDS_PER_1E7},
        "load_average": os.getloadavg() if hasattr(os, "getloadavg") else None,
    }
    c_mod = _memory_module(C_SCRIPT) if c_reference and C_SCRIPT.is_file() else None
    if c_mod is not None and (Path(plant_path).resolve(), Path(controller_path).resolve()) != (
            c_mod.PLANT.resolve(), c_mod.CONTROLLER.resolve()):
        say(f"no C reference: {C_SCRIPT.name} builds the SN637 hold with {c_mod.CONTROLLER.name} only")
        c_mod = None
    if c_mod is not None:
        say("the same loop in plain C (gcc), timed in this run...")
        c = c_mod.compare(periods, repeats, HOLD_DECIMATE, check_periods=min(200_000, periods), say=say)
        if c is not None:
            out["c_reference"] = {key: c[key] for key in (
                "cflags", "best_seconds", "ns_per_period", "ratio_vs_c_kernel", "ratio_vs_c_kernel_per_repeat",
                "ratio_vs_c_end_to_end", "ratio_cpu_time", "load_average_before_after",
                "agreement_decimate_1", "agreement_whole_run")}
            out["targets"]["ratio_vs_c_max"] = TARGET_C_RATIO
            out["meets_target"]["ratio_vs_c"] = c["ratio_vs_c_kernel"] <= TARGET_C_RATIO
    if memory_periods:
        mem = _memory_module()
        say(f"peak memory of a {memory_periods:.0e}-period hold (child process)...")
        peak, sec = mem.peak_rss_mb(memory_periods, MEMORY_DECIMATE, plant_path=plant_path,
                                    controller_path=controller_path)
        out["memory"] = {"periods": memory_periods, "decimate": MEMORY_DECIMATE, "peak_rss_mb": peak,
                         "seconds": sec, "limit_mb": mem.LIMIT_MB}
        out["targets"]["peak_rss_mb_max"] = mem.LIMIT_MB
        out["meets_target"]["memory"] = peak < mem.LIMIT_MB
    return out


def run_bench(plant_path="plants/p888_51_sn637_creep.toml", *, steps=10_000_000, reference_steps=2000,
              repeats=3, progress=None, controller_path=CONTROLLER, periods=None, reference_periods=None,
              memory_periods=10**8):
    """Time the compiled model, the closed loop and their python-control references; a JSON-ready dict.

    The open-loop figures are top-level keys; the closed-loop ones are under ``"closed_loop"``.

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
    controller_path : str or Path
        Exported controller JSON of the closed loop.
    periods, reference_periods : int, optional
        Servo periods of the closed-loop hold and of its python-control reference
        (default: ``steps`` and ``reference_steps``, one span for both benchmarks).
    memory_periods : int
        Periods of the peak-memory hold in a child process (10^8 = ~30 s); 0 skips it.
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
    ref_s = float(_child(f"_reference({str(plant_path)!r}, {int(reference_steps)})"))
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
        "closed_loop": closed_loop_bench(
            plant_path, controller_path, periods=steps if periods is None else periods,
            reference_periods=reference_steps if reference_periods is None else reference_periods,
            repeats=repeats, memory_periods=memory_periods, progress=progress),
    }
