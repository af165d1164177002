"""The compiled closed loop against a plain C version of the same loop, timed in one run.

The C (``closed_loop_vs_c.c`` beside this file) is the closed loop of
:mod:`workbench.verify.closed_loop` written out by hand: the same plant step (plays,
current limit, creep branches, modes), the same per-period gauge chain, and the
controller step of the exported C header, rendered here from the very controller JSON
the loop runs (:func:`workbench.export.writers._header`). It is built with gcc
(``-O2 -march=native -ffp-contract=off``, linked with numpy's ``libnpyrandom.a``) into a
shared library and called through ctypes on the same inputs: the mid-stroke hold of
``workbench bench`` (SN637 with creep, gauge noise on, the fixed-point loop-shaping
controller). Both loops draw the gauge noise inside the loop, one standard normal a period
from the run's own ``numpy.random.Generator`` (the C calls numpy's ``random_standard_normal``
on its bit generator, numba its own implementation of the same ziggurat): the same numbers,
in the same order, and the noise's cost is inside both timings.

Three timings per repeat, interleaved so the machine's load hits them alike:

* ``numba``: :meth:`ClosedLoop.run` end to end (chunks, the compiled loop);
* ``c_total``: the same chunking in Python, the C kernel per chunk;
* ``c_kernel``: the time inside the C calls only (the strict reference: plain C, inputs ready).

The ratio of the issue is ``numba / c_kernel`` (best over repeats of each; the spread is
printed). The two trajectories are checked: over a short run at decimate 1 every
controller output word, and over the whole run the decimated traces and final state.
With no C compiler the script says so and exits 0 (nothing to compare against).

    .venv/bin/python benchmarks/closed_loop_vs_c.py [--periods 1e7] [--repeats 3] [--json OUT]
"""

import argparse
import ctypes
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if __name__ == "__main__" and str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))       # time this checkout's workbench, not whichever one is installed
PLANT = ROOT / "plants" / "p888_51_sn637_creep.toml"
CONTROLLER = ROOT / "controllers" / "sn637_loopshape.json"
C_SOURCE = Path(__file__).with_suffix(".c")
CFLAGS = ("-O2", "-march=native", "-ffp-contract=off")
TARGET_RATIO = 3.0
LIB_NAME = "closed_loop_c.so"          # the shared library build() leaves in its workdir (its pieces: closed_loop_breakdown)

_d = ctypes.POINTER(ctypes.c_double)
_i = ctypes.POINTER(ctypes.c_int64)


def build(cl, workdir, cflags=CFLAGS):
    """Compile the C loop for ``cl``'s controller into ``workdir``; the ctypes function, or None without gcc."""
    from workbench.export.writers import _header

    cc = shutil.which(os.environ.get("CC", "gcc"))
    if cc is None or cl.controller.form != "fixed":
        return None
    name = "ctl"
    header = Path(workdir) / f"{name}.h"
    header.write_text(_header(name, cl.controller.fixed))
    lib = Path(workdir) / LIB_NAME
    npyrandom = Path(np.__file__).parent / "random" / "lib" / "libnpyrandom.a"
    done = subprocess.run([cc, *cflags, "-shared", "-fPIC", "-I", np.get_include(), "-include", str(header),
                           f"-DCTRL={name}", "-o", str(lib), str(C_SOURCE), str(npyrandom), "-lm"],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{cc} failed on {C_SOURCE}:\n{done.stderr}")
    fn = ctypes.CDLL(str(lib)).cl_run
    fn.restype = None
    fn.argtypes = [_d, _d, ctypes.c_long, ctypes.c_long, _d, _d, ctypes.c_void_p, ctypes.c_double, _d, _d, _i, _i, _i, ctypes.c_double,
                   ctypes.c_double, ctypes.c_int64, _d, ctypes.c_long, _d, ctypes.c_long, _d]
    return fn


def _p(a, t):
    return a.ctypes.data_as(t)


def c_run(fn, cl, ref, periods, decimate=1):
    """Run the C loop on ``cl``'s state as :meth:`ClosedLoop.run` would (constant reference, no force).

    Advances ``cl``'s plant, cascade words and io in place. Returns (rec, stats, total s, kernel s).
    """
    from workbench.verify.closed_loop import CHUNK, TRACE_NAMES

    t0 = time.perf_counter()
    n = int(periods)
    rec = np.zeros((n // decimate, len(TRACE_NAMES)))
    stats = np.zeros(5)
    cl._io[2:] = 0.0
    cs = np.ascontiguousarray(cl._csi, dtype=np.int64)
    bitgen = cl._rng.bit_generator.ctypes.bit_generator     # the C loop draws from the run's own generator
    kernel = 0.0
    for start in range(0, n, CHUNK):
        k = min(n, start + CHUNK) - start
        r_chunk, f_chunk = np.full(k, float(ref)), np.full(k, 0.0)
        t1 = time.perf_counter()
        fn(_p(cl.sim.m, _d), _p(cl.sim.st, _d), cl.n_sub, k, _p(r_chunk, _d), _p(f_chunk, _d), bitgen, cl.sigma_v,
           _p(cl._gp, _d), _p(cl._r0, _d), _p(cs, _i), _p(cl._vmi, _i), _p(cl._limw, _i), cl._in_scale,
           cl._out_scale, cl._fin, _p(cl._io, _d), decimate, _p(rec, _d), rec.shape[0], _p(stats, _d))
        kernel += time.perf_counter() - t1
    cl._csi[...] = cs
    cl._k += n
    return rec, stats, time.perf_counter() - t0, kernel


def _hold(**kw):
    from workbench.bench import _hold as hold

    return hold(PLANT, CONTROLLER, **kw)


def agreement(fn, periods, decimate):
    """Compiled loop vs C on one input: output words, traces and final plant state; a dict."""
    a, ref = _hold()
    b, _ = _hold()
    tr = a.run(ref, decimate=decimate, periods=periods)
    rec, stats, _, _ = c_run(fn, b, ref, periods, decimate)
    mine = np.column_stack([tr.x_m, tr.reading_v, tr.u_v, tr.error_v, tr.force_n, tr.i_a])
    words_a = np.rint(tr.u_v / a._out_scale).astype(np.int64)
    words_b = np.rint(rec[:, 2] / b._out_scale).astype(np.int64)
    return {
        "periods": periods, "decimate": decimate,
        "rows_identical": int(np.sum(np.all(mine == rec, axis=1))), "rows": int(rec.shape[0]),
        "output_words_identical": int(np.sum(words_a == words_b)),
        "max_abs_x_difference_m": float(np.max(np.abs(mine[:, 0] - rec[:, 0]))),
        "max_abs_u_difference_v": float(np.max(np.abs(mine[:, 2] - rec[:, 2]))),
        "plant_state_identical": bool(np.array_equal(a.sim.st, b.sim.st)),
        "controller_words_identical": bool(np.array_equal(a._csi, b._csi) and a._vmi[0] == b._vmi[0]),
        "stats_identical": bool(np.array_equal(stats, [tr.peak_current_a[0], tr.peak_current_a[1],
                                                       tr.periods_at_current_limit * a.n_sub,
                                                       tr.samples_rate_limited, tr.samples_range_limited])),
    }


def _load():
    try:
        return os.getloadavg()
    except OSError:
        return None


def compare(periods=10_000_000, repeats=3, decimate=1000, check_periods=200_000, say=print):
    """Time the compiled loop and the C loop in this run and check they agree; a dict (None without gcc)."""
    cl, ref = _hold()
    with tempfile.TemporaryDirectory() as tmp:
        fn = build(cl, tmp)
        if fn is None:
            say("no C compiler (gcc) found: nothing to compare against")
            return None
        cl.run(ref, periods=1000)                    # numba: compile / load the cache outside the timing
        load_before = _load()
        times = {"numba": [], "c_total": [], "c_kernel": [], "numba_cpu": [], "c_cpu": []}
        for k in range(repeats):
            a, ref = _hold()
            c0, t0 = time.thread_time(), time.perf_counter()
            a.run(ref, decimate=decimate, periods=periods)
            times["numba"].append(time.perf_counter() - t0)
            times["numba_cpu"].append(time.thread_time() - c0)
            b, _ = _hold()
            c0 = time.thread_time()
            _, _, total, kernel = c_run(fn, b, ref, periods, decimate)
            times["c_cpu"].append(time.thread_time() - c0)
            times["c_total"].append(total)
            times["c_kernel"].append(kernel)
            say(f"repeat {k + 1}/{repeats}: compiled loop {times['numba'][-1]:.3f} s, C {total:.3f} s "
                f"(kernel {kernel:.3f} s) for {periods:.0e} periods")
        load_after = _load()
        say("agreement: decimate 1 over a short run, then the decimated traces of the whole run...")
        short = agreement(fn, check_periods, 1)
        whole = agreement(fn, periods, decimate)
    best = {k: min(v) for k, v in times.items()}
    ratio = best["numba"] / best["c_kernel"]
    return {
        "scenario": f"SN637 with creep, hold at 7.5 um, gauge noise on, {cl.controller.describe()}, "
                    f"decimate {decimate}",
        "periods": periods, "repeats": repeats,
        "c_compiler": shutil.which(os.environ.get("CC", "gcc")), "cflags": list(CFLAGS),
        "seconds": times, "best_seconds": best,
        "ns_per_period": {k: v / periods * 1e9 for k, v in best.items()},
        "ratio_vs_c_kernel": ratio,
        "ratio_vs_c_kernel_per_repeat": [n / c for n, c in zip(times["numba"], times["c_kernel"])],
        "ratio_vs_c_end_to_end": best["numba"] / best["c_total"],
        "ratio_cpu_time": best["numba_cpu"] / best["c_cpu"],
        "load_average_before_after": [load_before, load_after],
        "agreement_decimate_1": short, "agreement_whole_run": whole,
        "target_ratio_max": TARGET_RATIO, "meets_target": ratio <= TARGET_RATIO,
    }


def run(periods=10_000_000, repeats=3, decimate=1000, check_periods=200_000, python_control_periods=2000,
        say=print):
    """:func:`compare` plus python-control's ``input_output_response`` on the same loop (``workbench.bench``)."""
    from workbench import bench

    out = compare(periods, repeats, decimate, check_periods, say)
    if out is None:
        return {"c_compiler": None}
    start = bench._settled_period(PLANT, CONTROLLER)
    say(f"python-control reference over {python_control_periods} periods of the hold from period {start} "
        f"(interpreted, child process)...")
    pc = bench._child(f"_closed_loop_reference({str(PLANT)!r}, {str(CONTROLLER)!r}, {int(python_control_periods)}, "
                      f"{start})")
    out.update({"python_control_periods": python_control_periods, "python_control_start_period": start,
                "python_control_seconds": pc["seconds"], "python_control_cpu_seconds": pc["cpu_seconds"],
                "ratio_vs_python_control": pc["seconds"] / python_control_periods
                / (out["best_seconds"]["numba"] / periods),
                "ratio_vs_python_control_cpu": pc["cpu_seconds"] / python_control_periods
                / (out["best_seconds"]["numba_cpu"] / periods),
                "numba_seconds_per_1e7_periods": out["best_seconds"]["numba"] * 1e7 / periods})
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--periods", type=float, default=1e7)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--check-periods", type=float, default=2e5)
    p.add_argument("--json", type=Path, help="write the figures here")
    args = p.parse_args(argv)
    out = run(int(args.periods), args.repeats, check_periods=int(args.check_periods), say=print)
    if out.get("c_compiler") is None:
        return 0
    ns = out["ns_per_period"]
    per_repeat = ", ".join(f"{r:.2f}" for r in out["ratio_vs_c_kernel_per_repeat"])
    print(f"compiled loop {ns['numba']:.1f} ns/period, C kernel {ns['c_kernel']:.1f} ns/period (wall): ratio "
          f"{out['ratio_vs_c_kernel']:.2f} (per repeat {per_repeat};"
          f" target <= {TARGET_RATIO:g}); vs C end to end {out['ratio_vs_c_end_to_end']:.2f}; "
          f"CPU time {ns['numba_cpu']:.1f} vs {ns['c_cpu']:.1f} ns/period, ratio {out['ratio_cpu_time']:.2f}")
    print(f"10^7 periods: {out['numba_seconds_per_1e7_periods']:.3f} s; python-control "
          f"{out['ratio_vs_python_control']:.0f}x slower (wall), {out['ratio_vs_python_control_cpu']:.0f}x (CPU time); load {out['load_average_before_after']}")
    for key in ("agreement_decimate_1", "agreement_whole_run"):
        print(key, json.dumps(out[key]))
    if args.json:
        from workbench.report.output import write_text
        write_text(args.json, json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
