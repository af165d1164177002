"""Where the closed loop's time per period goes: ablations in both loops, and its pieces alone.

The hold of ``workbench bench`` (SN637 with creep, 7.5 um, gauge noise on, the fixed-point
loop-shaping controller with its current-limit window, n_sub 1, decimate 1000), in one process:

1. **Ablations, compiled loop and C loop** (``benchmarks/closed_loop_vs_c.c``, built here as
   ``closed_loop_vs_c.py`` builds it): the same :class:`ClosedLoop` with one piece switched off by
   configuration, so both loops run their real code on it: no gauge noise (no draw), no anti-windup
   window, no creep branches, no mode, neither, trace rows every period (decimate 1). CPU time of the
   thread per period, best of the rounds (rounds interleave the variants so load hits them alike).
   A difference from the full loop is that piece's marginal cost in the loop (its work plus whatever of
   its latency the rest of the period cannot hide).
2. **Pieces alone, compiled** (numba, inputs recorded from the settled hold at decimate 1): the plant
   step (:func:`workbench.plant.kernels.pzt_advance`), the gauge chain (bridge, ADC clip, demodulation,
   trim, DAC; the lines of ``_loop``), the noise draw (``Generator.standard_normal``), the controller
   (error word and :func:`workbench.export.fixed_point.fixed_step`). Each twice: ``free`` (inputs from
   the record: the core overlaps consecutive iterations, a throughput) and ``chained`` (each input made
   to depend on the previous output through ``+ y * zero`` with ``zero`` a run-time 0.0, so the piece's
   latency shows; the chain's own multiply-add, timed alone, is subtracted). The loop is one dependency
   chain per period (the next command needs this reading): the sum of the chained latencies of the
   pieces on it (plant, gauge, controller) is what a period costs when they run in series, and the
   measured loop is within a few ns of it.

Ratios within this run, not absolute claims; the machine's load is printed.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/closed_loop_breakdown.py [--periods 2e6] [--rounds 3]
"""

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from numba import njit

ROOT = Path(__file__).resolve().parents[1]
if __name__ == "__main__" and str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))       # time this checkout's workbench, not whichever one is installed

PLANT = ROOT / "plants" / "p888_51_sn637_creep.toml"
CONTROLLER = ROOT / "controllers" / "sn637_loopshape.json"
from workbench.export.fixed_point import fixed_step  # noqa: E402
from workbench.plant import kernels as K  # noqa: E402

SETTLE = 5000                     # periods run untimed first: the slew from rest (~3240 periods) is over


def _vs_c():
    """benchmarks/closed_loop_vs_c.py (its build and c_run), loaded by path: this script's C loop is that one."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("closed_loop_vs_c", Path(__file__).with_name("closed_loop_vs_c.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _loop_for(plant=None, **kw):
    """A fresh ClosedLoop of the bench's hold on ``plant`` (default: the SN637 creep file) and its reference."""
    from workbench.bench import X_HOLD_M
    from workbench.plant import load_plant
    from workbench.verify.closed_loop import ClosedLoop, controller_from_json
    from workbench.verify.scenarios import _to_volts

    plant = plant or load_plant(PLANT)
    ctrl = controller_from_json(json.loads(CONTROLLER.read_text()))
    return ClosedLoop(plant, ctrl, **kw), float(_to_volts(X_HOLD_M, plant.gauge))


def variants():
    """name -> (plant, ClosedLoop keywords, decimate) of the ablations."""
    from workbench.plant import load_plant

    base = load_plant(PLANT)
    pz = base.pzt
    no_creep = dataclasses.replace(base, pzt=dataclasses.replace(pz, creep=None))
    no_modes = dataclasses.replace(base, pzt=dataclasses.replace(pz, modes=()))
    neither = dataclasses.replace(base, pzt=dataclasses.replace(pz, creep=None, modes=()))
    return {
        "full": (base, {}, 1000),
        "no gauge noise (no draw)": (base, {"noise": False}, 1000),
        "no anti-windup window": (base, {"anti_windup": False}, 1000),
        "no creep (5 branches)": (no_creep, {}, 1000),
        "no mode (2 states)": (no_modes, {}, 1000),
        "no creep, no mode": (neither, {}, 1000),
        "trace row every period": (base, {}, 1),
    }


def ablations(periods, rounds, fn, say=print):
    """CPU ns per period of each variant, compiled loop and C loop (None without gcc); dict name -> [numba, c]."""
    c_run = _vs_c().c_run
    cases = variants()
    best = {name: [np.inf, np.inf] for name in cases}
    for r in range(rounds):
        for name, (plant, kw, dec) in cases.items():
            a, ref = _loop_for(plant, **kw)
            a.run(ref, periods=SETTLE)
            c0 = time.thread_time()
            a.run(ref, decimate=dec, periods=periods)
            best[name][0] = min(best[name][0], (time.thread_time() - c0) / periods * 1e9)
            if fn is not None:
                b, _ = _loop_for(plant, **kw)
                c_run(fn, b, ref, SETTLE, 1)
                c0 = time.thread_time()
                c_run(fn, b, ref, periods, dec)
                best[name][1] = min(best[name][1], (time.thread_time() - c0) / periods * 1e9)
        say(f"ablations round {r + 1}/{rounds} done")
    return {k: [float(v[0]), None if fn is None else float(v[1])] for k, v in best.items()}


# ---- the pieces alone (compiled). ``chained``: each input waits on the last output through ``+ y * zero``
# (``zero`` 0.0 at run time, which the compiler cannot fold); not chained: the inputs are the record's alone

@njit(cache=True, error_model="numpy")
def _chain_only(a, zero):
    y = 0.0
    for k in range(a.shape[0]):
        y = a[k] + y * zero
    return y


def kernels(chained):
    """The piece kernels with ``chained`` fixed at compile time (a closure constant): (plant, gauge, draw,
    controller). Not cached (closures); each compiles in about a second."""
    @njit(error_model="numpy")
    def _plant(m, st, u, zero):
        m, st = K._borrowed(m), K._borrowed(st)        # as _loop takes them: no reference count per step
        p = K.plant_params(m)
        x = 0.0
        acc = 0.0
        for k in range(u.shape[0]):
            uk = u[k] + x * zero if chained else u[k]
            x, _, i, _, _ = K.pzt_advance(p, m, st, uk, 0.0)
            acc += i
        return x + acc

    @njit(error_model="numpy")
    def _gauge(x, gp, r0, out, zero):
        # the gauge chain of verify.closed_loop._loop at n_sub 1 (quarter and three-quarter points between x_{k-1}
        # and x_k), without the noise draw: bridge, amplifier and ADC clip, demodulation, trim, DAC quantization
        L, W, kgf, vm, amp, adc_fs = gp[0], gp[1], gp[2], gp[3], gp[4], gp[5]
        demod, trim_s, trim_b, dac_fs, dac_bits = gp[6], gp[7], gp[8], gp[9], int(gp[10])
        kw = kgf * (W / L)
        r0a, r0b, r0c, r0d = r0[0], r0[1], r0[2], r0[3]
        n10, n11 = r0d - r0a, (r0d * kgf + r0a * kw) / L
        d10, d11 = r0d + r0a, (r0d * kgf - r0a * kw) / L
        n20, n21 = r0b - r0c, -(r0b * kw + r0c * kgf) / L
        d20, d21 = r0b + r0c, (r0c * kgf - r0b * kw) / L
        k_br = amp * vm
        k_dem = trim_s * (0.5 * demod)
        dac_lsb = 2.0 * dac_fs / (2.0 ** dac_bits)
        dac_top = dac_fs - dac_lsb
        inv_lsb = 1.0 / dac_lsb
        xb = x[0]
        code = 0.0
        acc = 0.0
        for k in range(1, x.shape[0]):
            xj = x[k] + code * zero if chained else x[k]
            xq = xb + (xj - xb) * 0.25
            xt = xb + (xj - xb) * 0.75
            xb = xj
            vp = min(max((((n10 + n11 * xq) / (d10 + d11 * xq)) - ((n20 + n21 * xq) / (d20 + d21 * xq))) * k_br,
                         -adc_fs), adc_fs)
            vn = min(max((((n10 + n11 * xt) / (d10 + d11 * xt)) - ((n20 + n21 * xt) / (d20 + d21 * xt))) * -k_br,
                         -adc_fs), adc_fs)
            reading = min(max(k_dem * (vp - vn) + trim_b, -dac_fs), dac_top)
            code = np.floor(reading * inv_lsb + 0.5)
            out[k] = code
            acc += code
        return acc * dac_lsb

    @njit(error_model="numpy")
    def _draw(rng, n, sigma, zero):
        y = 0.0
        acc = 0.0
        for _ in range(n):
            y = rng.standard_normal() * sigma + y * zero if chained else rng.standard_normal() * sigma
            acc += y
        return acc

    @njit(error_model="numpy")
    def _controller(code, ref, lsb_in, in_scale, f_in, cs, fb, fa, fshift, ffrac, limw, vm, out_scale, out, zero):
        cs, fb, fa, fshift = K._borrowed(cs), K._borrowed(fb), K._borrowed(fa), K._borrowed(fshift)
        limw, vm = K._borrowed(limw), K._borrowed(vm)
        peak = np.zeros((0, 3), np.int64)
        u = 0.0
        acc = 0.0
        for k in range(code.shape[0]):
            ck = code[k] + u * zero if chained else code[k]
            v = min(max(np.int64(np.rint(ref * in_scale - ck * lsb_in)), -f_in), f_in)
            u = fixed_step(cs, v, fb, fa, fshift, ffrac, limw, vm, True, peak) * out_scale
            out[k] = u
            acc += u
        return acc

    return _plant, _gauge, _draw, _controller


def recorded_hold(periods, plant=None, settle=SETTLE, **kw):
    """The hold at decimate 1 after ``settle`` untimed periods: (ClosedLoop, its state after them as (plant state,
    cascade words, voltage-model word, last x), the trace of the next ``periods``). ``kw``: ClosedLoop's."""
    cl, ref = _loop_for(plant, **kw)
    if settle:
        cl.run(ref, periods=settle)
    state = (cl.sim.st.copy(), cl._csi.copy(), cl._vmi.copy(), float(cl._io[1]))
    return cl, ref, state, cl.run(ref, periods=periods)


def c_pieces(lib):
    """The C library's gauge and controller pieces (closed_loop_vs_c.c) as {"gauge": (free, chained), ...}."""
    import ctypes
    d, i = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int64)
    out = {}
    for name, args in (("plant", [d, d, d, ctypes.c_long, ctypes.c_double]),
                       ("gauge", [d, ctypes.c_long, d, d, d, ctypes.c_double]),
                       ("ctrl", [d, ctypes.c_long, ctypes.c_double, ctypes.c_double, ctypes.c_double, ctypes.c_int64,
                                 i, i, ctypes.c_double, d, ctypes.c_double])):
        fs = []
        for kind in ("free", "chained"):
            f = getattr(lib, f"{name}_{kind}")
            f.restype, f.argtypes = ctypes.c_double, args
            fs.append(f)
        out[name] = tuple(fs)
    return out


def pieces(periods, rounds, say=print, lib=None):
    """ns per call of each piece alone, [free, chained less the chain's own multiply-add], best of ``rounds``."""
    from workbench.plant import load_plant

    cl, ref, (st0, cs0, vm0, x0), tr = recorded_hold(periods)
    u = np.ascontiguousarray(tr.u_v)
    x = np.concatenate([[x0], tr.x_m])
    dac_lsb = 2.0 * cl._gp[9] / 2.0 ** cl._gp[10]
    code = np.rint(tr.reading_v / dac_lsb)
    lsb_in = dac_lsb * cl._in_scale
    rng = np.random.Generator(np.random.PCG64(1))
    m, st = cl.sim.m, st0.copy()
    cs, vm = cs0.copy(), vm0.copy()
    out = np.empty(x.size)
    # the same stack with neither creep nor mode: the least plant step the loop could take (G's plays, RC)
    bare = load_plant(PLANT)
    bare = dataclasses.replace(bare, pzt=dataclasses.replace(bare.pzt, creep=None, modes=()))
    cl_b, _, (st_b0, _, _, _), tr_b = recorded_hold(periods, bare)
    u_b, st_b = np.ascontiguousarray(tr_b.u_v), st_b0.copy()

    def reset():
        st[:] = st0
        st_b[:] = st_b0
        cs[...] = cs0
        vm[...] = vm0

    def calls(ks):
        plant, gauge, draw, controller = ks
        return {
            "plant step (pzt_advance: 12 plays, RC, 5 creep branches, mode)": lambda: plant(m, st, u, 0.0),
            "plant step, no creep, no mode (12 plays, RC)": lambda: plant(cl_b.sim.m, st_b, u_b, 0.0),
            "gauge chain (bridge x2, clips, demod, trim, DAC)": lambda: gauge(x, cl._gp, cl._r0, out, 0.0),
            "noise draw (standard_normal; off the chain)": lambda: draw(rng, periods, cl.sigma_v, 0.0),
            "controller (error word, 2-section fixed_step, window)": lambda: controller(
                code, ref, lsb_in, cl._in_scale, cl._fin, cs, cl._fb, cl._fa, cl._fshift, cl._ffrac, cl._limw, vm,
                cl._out_scale, out, 0.0),
        }

    free, chained = calls(kernels(False)), calls(kernels(True))
    if lib is not None:
        import ctypes
        cp = c_pieces(lib)
        dp, ip = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int64)

        def c_calls(j):
            pl, g, c = cp["plant"][j], cp["gauge"][j], cp["ctrl"][j]
            return {
                "C: plant step": lambda: pl(m.ctypes.data_as(dp), st.ctypes.data_as(dp), u.ctypes.data_as(dp), u.size,
                                            0.0),
                "C: plant step, no creep, no mode": lambda: pl(cl_b.sim.m.ctypes.data_as(dp), st_b.ctypes.data_as(dp),
                                                               u_b.ctypes.data_as(dp), u_b.size, 0.0),
                "C: gauge chain": lambda: g(x.ctypes.data_as(dp), x.size, cl._gp.ctypes.data_as(dp),
                                            cl._r0.ctypes.data_as(dp), out.ctypes.data_as(dp), 0.0),
                "C: controller (the header's step)": lambda: c(
                    code.ctypes.data_as(dp), code.size, ref, lsb_in, cl._in_scale, cl._fin, cs.ctypes.data_as(ip),
                    vm.ctypes.data_as(ip), cl._out_scale, out.ctypes.data_as(dp), 0.0),
            }
        free.update(c_calls(0))
        chained.update(c_calls(1))
    _chain_only(u[:10], 0.0)                             # compile / load outside the timing
    for f in (*free.values(), *chained.values()):
        reset()
        f()
    chain = np.inf
    best = {name: [np.inf, np.inf] for name in free}
    for r in range(rounds):
        c0 = time.thread_time()
        _chain_only(u, 0.0)
        chain = min(chain, time.thread_time() - c0)
        for name in free:
            for j, f in enumerate((free[name], chained[name])):
                reset()
                c0 = time.thread_time()
                f()
                best[name][j] = min(best[name][j], time.thread_time() - c0)
        say(f"pieces round {r + 1}/{rounds} done")
    chain_ns = chain / periods * 1e9
    return {k: [v[0] / periods * 1e9, v[1] / periods * 1e9 - chain_ns] for k, v in best.items()}, chain_ns


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--periods", type=float, default=2e6)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--json", type=Path, help="write the figures here")
    args = p.parse_args(argv)
    n = int(args.periods)
    load0 = os.getloadavg()
    cl, ref = _loop_for()
    cl.run(ref, periods=1000)                      # compile / load the loop's cache
    with tempfile.TemporaryDirectory() as tmp:
        vs_c = _vs_c()
        fn = vs_c.build(cl, tmp)
        if fn is None:
            print("no C compiler (gcc): the ablations and pieces run in the compiled loop only")
        abl = ablations(n, args.rounds, fn)
        import ctypes
        lib = None if fn is None else ctypes.CDLL(str(Path(tmp) / vs_c.LIB_NAME))
        pcs, chain_ns = pieces(n, args.rounds, lib=lib)
    load1 = os.getloadavg()
    full = abl["full"]
    print(f"\nablations, CPU ns per period (best of {args.rounds} rounds of {n:.0e} periods; "
          f"difference from the full loop in brackets)")
    print("| variant | compiled loop | C loop |\n|---|---|---|")
    for name, (a, c) in abl.items():
        da = "" if name == "full" else f" ({a - full[0]:+.1f})"
        dc = "" if c is None else ("" if name == "full" else f" ({c - full[1]:+.1f})")
        print(f"| {name} | {a:.1f}{da} | {'-' if c is None else f'{c:.1f}'}{dc} |")
    print(f"\npieces alone, compiled (C: the same lines in closed_loop_vs_c.c), ns per call (chained: less the "
          f"chain's own {chain_ns:.1f} ns)")
    print("| piece | free | chained |\n|---|---|---|")
    for name, (f, ch) in pcs.items():
        print(f"| {name} | {f:.1f} | {ch:.1f} |")
    names = list(pcs)
    on_chain = pcs[names[0]][1] + pcs[names[2]][1] + pcs[names[4]][1]
    floor = pcs[names[1]][1] + pcs[names[2]][1] + pcs[names[4]][1]
    print(f"sum of the chained pieces on the period's chain (plant, gauge, controller): {on_chain:.1f} ns; "
          f"the full loop {full[0]:.1f} ns (C {full[1] if full[1] is not None else float('nan'):.1f}); "
          f"with the bare plant step (no creep, no mode): {floor:.1f} ns")
    if "C: gauge chain" in pcs:
        c_sum = pcs["C: gauge chain"][1] + pcs["C: controller (the header's step)"][1]
        print(f"C: the same sums {pcs['C: plant step'][1] + c_sum:.1f} ns and "
              f"{pcs['C: plant step, no creep, no mode'][1] + c_sum:.1f} ns; gauge chain and controller alone "
              f"{c_sum:.1f} ns (compiled: {pcs[names[2]][1] + pcs[names[4]][1]:.1f} ns)")
    print(f"load {load0} -> {load1}")
    if args.json:
        Path(args.json).write_text(json.dumps({"ablations_ns": abl, "pieces_ns": pcs, "chain_ns": chain_ns,
                                               "sum_on_chain_ns": on_chain, "sum_bare_plant_ns": floor,
                                               "periods": n, "rounds": args.rounds, "load": [load0, load1]},
                                              indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
