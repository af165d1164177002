"""The closed-loop benchmark's claims in reduced form: the optimized loop is the reference formulation to
rounding, chunking is invisible, memory does not grow with the run.

No timing assertions (figures come from `workbench bench` and benchmarks/closed_loop_vs_c.py).
"""

import importlib.util
import json
import shutil

import numpy as np
import pytest

from workbench.bench import _hold
from workbench.design.antiwindup import hanus
from workbench.plant import kernels as K
from workbench.verify import closed_loop
from workbench.verify.closed_loop import CHUNK, ClosedLoop, controller_from_json

from tests.compiled_loops import fresh_llvm, refcounts_in_loops
from tests.conftest import FULL, load_benchmark


def _controllers(root):
    data = json.loads((root / "controllers" / "sn637_loopshape.json").read_text())
    fixed = controller_from_json(data)
    h = hanus(fixed.linear(), fixed.output_limits_v, (np.inf, np.inf))
    hanus_json = {**data, "anti_windup": h.as_dict(fixed.voltage_model)}
    hanus_json.pop("fixed_point")
    return {"fixed": fixed, "float": controller_from_json(data, "float"), "hanus": controller_from_json(hanus_json)}


def _drive(rng, n, plant):
    """A reference (firmware V) and force (N) over the whole range: steps to six levels spread over the DAC
    range and 20 % past it, the top one first (from a start at 100 V the output limit holds within ~0.15 s;
    every step engages the current-limit window), the others in a random order, a random walk on them,
    force steps."""
    top = plant.gauge.dac_range_v
    levels = np.linspace(-1.2 * top, 1.2 * top, 6)
    levels = np.concatenate([levels[-1:], rng.permutation(levels[:-1])])
    steps = levels.repeat(-(-n // 6))[:n]
    walk = np.cumsum(rng.normal(0.0, 1e-4 * top, size=n))
    force = rng.uniform(-20.0, 20.0, size=n // 1500 + 1).repeat(1500)[:n]
    return steps + walk, force


def _loop_vs_reference(root, plant, monkeypatch, rng, form, n_sub, anti_windup, n, beta_per_m=0.0):
    from dataclasses import replace
    ctrl = replace(_controllers(root)[form], gauge_curvature_per_m=beta_per_m)
    ref, force = _drive(rng, n, plant)
    runs = {}
    for name, loop in (("optimized", closed_loop._loop), ("reference", closed_loop._loop_reference)):
        monkeypatch.setattr(closed_loop, "_loop", loop)
        cl = ClosedLoop(plant, ctrl, n_sub=n_sub, anti_windup=anti_windup, seed=11)
        cl.reset(u0=100.0)
        tr = cl.run(ref, force_n=force)
        runs[name] = (tr, cl)
    (a, ca), (b, cb) = runs["optimized"], runs["reference"]
    # the plant: the same trajectory to rounding (1e-12 of the stroke; measured ~1e-15)
    x_scale = np.max(np.abs(b.x_m))
    assert np.max(np.abs(a.x_m - b.x_m)) <= 1e-12 * x_scale
    assert np.max(np.abs(a.i_a - b.i_a)) <= 1e-9 * np.max(np.abs(b.i_a))
    keep = np.ones(ca.sim.st.size, bool)                 # the plant state but the modes' scratch copy
    o_x, n_m = int(ca.sim.m[K.OS_XM]), int(ca.sim.m[K.N_M])
    keep[o_x + n_m:o_x + 2 * n_m] = False
    keep[[K.S_PL, K.S_PU, K.S_Y1]] = False               # the fast step's band (the reference voids it)
    np.testing.assert_allclose(ca.sim.st[keep], cb.sim.st[keep], rtol=1e-10, atol=1e-12 * x_scale)
    np.testing.assert_allclose(a.peak_current_a, b.peak_current_a, rtol=1e-9)
    # the gauge quantizes the position to the servo DAC's 16 bits, so a rounding difference far below its
    # step gives the same readings, and so the same controller, every period (a reading within ~1e-16 of a
    # code boundary would differ: the odds are ~1e-12 a period)
    for field in ("reading_v", "u_v", "error_v", "force_n"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    assert (a.periods_at_current_limit, a.samples_rate_limited, a.samples_range_limited) == \
           (b.periods_at_current_limit, b.samples_rate_limited, b.samples_range_limited)
    for attr in ("_hx", "_csf", "_csi", "_vmf", "_vmi"):
        np.testing.assert_array_equal(getattr(ca, attr), getattr(cb, attr), err_msg=attr)
    # the draw reached the branches the comparison is about: output range, current limit, window
    assert a.samples_range_limited > 0 and a.periods_at_current_limit > 0
    if anti_windup:
        assert a.samples_rate_limited > 0


@pytest.mark.parametrize("form", ["fixed", "float", "hanus"])
@pytest.mark.parametrize("n_sub, anti_windup", [(1, True), (3, True), (4, False)])
def test_the_optimized_loop_is_the_reference_formulation(root, sn637_creep, monkeypatch, rng, form, n_sub,
                                                         anti_windup):
    # _loop (compiled: the plant step's capacitance and exp per capacitance segment, exact creep and mode
    # steps, no division in the step, the bridge as two ratios of lines in x) against _loop_reference (the
    # loop as first written, per-step divisions and exp, run by the interpreter): the physics must not change
    _loop_vs_reference(root, sn637_creep, monkeypatch, rng, form, n_sub, anti_windup, 12_000)


@pytest.mark.parametrize("form", ["fixed", "float"])
def test_the_optimized_loop_linearizes_the_gauge_as_the_reference_formulation(root, sn637_creep, monkeypatch, rng,
                                                                              form):
    # a controller whose sensor block carries the bridge curvature: both loops convert each reading with
    # plant.gauge.linearized_displacement (the sensor loop's conversion), the same readings and words
    from workbench.plant.gauge import bridge_curvature_per_m
    _loop_vs_reference(root, sn637_creep, monkeypatch, rng, form, 1, True, 12_000,
                       bridge_curvature_per_m(sn637_creep.gauge))


def test_the_optimized_loop_is_the_reference_formulation_over_1e5_periods(root, sn637_creep, monkeypatch, rng):
    # the benchmark's form (fixed point, one plant step a period) over 10 s: rounding does not accumulate
    _loop_vs_reference(root, sn637_creep, monkeypatch, rng, "fixed", 1, True, 100_000)


@pytest.fixture(scope="module")
def memory(root):
    spec = importlib.util.spec_from_file_location("closed_loop_memory", root / "benchmarks" / "closed_loop_memory.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_hold_is_the_same_in_one_call_or_two(root):
    n, first, dec = 200_000, 70_000, 1000
    assert n > CHUNK > first          # the one call crosses a chunk boundary, the split one elsewhere
    paths = (root / "plants" / "p888_51_sn637_creep.toml", root / "controllers" / "sn637_loopshape.json")
    one, ref = _hold(*paths, noise=False)
    whole = one.run(ref, decimate=dec, periods=n)
    two, _ = _hold(*paths, noise=False)
    two.run(ref, decimate=dec, periods=first)
    tail = two.run(ref, decimate=dec, periods=n - first)
    assert two.u == pytest.approx(one.u, abs=1e-12, rel=0)
    assert tail.x_m[-1] == pytest.approx(whole.x_m[-1], abs=1e-12, rel=0)
    assert tail.t_s[-1] == pytest.approx(whole.t_s[-1])


@pytest.mark.slow
def test_peak_memory_does_not_grow_with_the_run(memory, root, monkeypatch):
    monkeypatch.chdir(root)
    if FULL:                                        # two children: a 200k- and a 2M-period hold
        short, _ = memory.peak_rss_mb(200_000, 1000)
        long, _ = memory.peak_rss_mb(2_000_000, 1000)
        assert long - short < 30.0
    else:                                           # one child: its peak after a 1000-period warm-up, then 2M
        fig = memory.child_figures(2_000_000, 1000)
        assert fig["peak_rss_mb"] - fig["peak_rss_before_mb"] < 30.0


def test_the_plain_c_loop_of_the_benchmark_is_the_same_computation(root, tmp_path):
    # benchmarks/closed_loop_vs_c.py times the loop against C that must be the same loop: from rest to the
    # mid-stroke hold (a 50 V slew through the current-limit window, then gauge noise), every output word,
    # trace row, statistic and the final plant and controller state agree exactly
    if shutil.which("gcc") is None:
        pytest.skip("no gcc: the benchmark's C reference cannot be built here")
    spec = importlib.util.spec_from_file_location("closed_loop_vs_c", root / "benchmarks" / "closed_loop_vs_c.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    cl, _ = mod._hold()
    fn = mod.build(cl, tmp_path)
    out = mod.agreement(fn, 20_000, 1)
    assert out["rows"] == out["rows_identical"] == out["output_words_identical"] == 20_000
    assert out["plant_state_identical"] and out["controller_words_identical"] and out["stats_identical"]


@pytest.mark.parametrize("noise", [True, False])
def test_the_loop_draws_one_standard_normal_a_period_from_its_generator(root, noise):
    # the gauge noise is drawn inside the compiled loop (numba's Generator support): one standard normal a
    # period from the run's generator, whatever the chunking, and none without noise; the generator's state
    # after a run that crosses a chunk boundary is that of a fresh one after standard_normal(n) (that the
    # numbers are numpy's own, the C reference that calls numpy's routine shows word for word above)
    paths = (root / "plants" / "p888_51_sn637_creep.toml", root / "controllers" / "sn637_loopshape.json")
    n = CHUNK + 30_000
    cl, ref = _hold(*paths, noise=noise, seed=5)
    fresh = np.random.Generator(np.random.PCG64(5))
    cl.run(ref, periods=n)
    if noise:
        fresh.standard_normal(n)
    assert cl._rng.bit_generator.state == fresh.bit_generator.state


def test_the_breakdown_pieces_are_the_loops_own_computation(tmp_path):
    # benchmarks/closed_loop_breakdown.py times the plant step, the gauge chain and the controller alone on
    # inputs recorded from the loop: fed those inputs (here from rest: the 50 V slew held by the current-limit
    # window, then the hold; noise off, as the gauge piece draws none), each piece gives the loop's own numbers
    # exactly (the plant's final state, every DAC code, every output), free or chained (the chain adds y * 0.0),
    # and so do the C pieces beside the C loop
    mod = load_benchmark("closed_loop_breakdown")
    n = 6000
    cl, ref, (st0, cs0, vm0, x0), tr = mod.recorded_hold(n, settle=0, noise=False)
    assert tr.samples_rate_limited > 3000           # the window held the slew's commands (it keeps I below the limit)
    dac_lsb = 2.0 * cl._gp[9] / 2.0 ** cl._gp[10]
    code = np.rint(tr.reading_v / dac_lsb)
    x = np.concatenate([[x0], tr.x_m])
    for chained in (False, True):
        plant, gauge, _, controller = mod.kernels(chained)
        st = st0.copy()
        plant(cl.sim.m, st, np.ascontiguousarray(tr.u_v), 0.0)
        assert np.array_equal(st, cl.sim.st)
        out = np.full(n + 1, np.nan)
        gauge(x, cl._gp, cl._r0, out, 0.0)
        assert np.array_equal(out[1:], code)
        cs, vm = cs0.copy(), vm0.copy()
        out[:] = np.nan
        controller(code, ref, dac_lsb * cl._in_scale, cl._in_scale, cl._fin, cs, cl._fb, cl._fa, cl._fshift,
                   cl._ffrac, cl._limw, vm, cl._out_scale, out, 0.0)
        assert np.array_equal(out[:n - 1], tr.u_v[1:]) and out[n - 1] == cl.u
        assert np.array_equal(cs, cl._csi) and vm[0] == cl._vmi[0]
    if shutil.which("gcc") is None:
        return
    # the C pieces of benchmarks/closed_loop_vs_c.c, the same numbers
    import ctypes
    vs_c = load_benchmark("closed_loop_vs_c")
    vs_c.build(cl, tmp_path)
    pieces = mod.c_pieces(ctypes.CDLL(str(tmp_path / vs_c.LIB_NAME)))
    dp, ip = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int64)
    for j in (0, 1):
        st = st0.copy()
        u = np.ascontiguousarray(tr.u_v)
        pieces["plant"][j](cl.sim.m.ctypes.data_as(dp), st.ctypes.data_as(dp), u.ctypes.data_as(dp), n, 0.0)
        assert np.array_equal(st, cl.sim.st)
        out = np.full(n + 1, np.nan)
        pieces["gauge"][j](x.ctypes.data_as(dp), x.size, cl._gp.ctypes.data_as(dp), cl._r0.ctypes.data_as(dp),
                           out.ctypes.data_as(dp), 0.0)
        assert np.array_equal(out[1:], code)
        cs, vm = cs0.copy(), vm0.copy()
        pieces["ctrl"][j](code.ctypes.data_as(dp), n, ref, dac_lsb * cl._in_scale, cl._in_scale, cl._fin,
                          cs.ctypes.data_as(ip), vm.ctypes.data_as(ip), cl._out_scale, out.ctypes.data_as(dp), 0.0)
        assert np.array_equal(out[:n - 1], tr.u_v[1:]) and out[n - 1] == cl.u
        assert np.array_equal(cs, cl._csi) and vm[0] == cl._vmi[0]


def test_the_closed_loop_takes_no_reference_count_or_atomic_per_period(root, sn637_creep):
    # numba passes an array to an inlined step as a new reference unless its pruning drops the pair; a locked
    # increment per period is a full barrier that kept the periods from overlapping (README, the breakdown).
    # No NRT_incref/NRT_decref call or atomic in any block on a cycle of _loop (the period loop and every loop
    # inside it); the control that such a count is found: tests/plant/test_kernel_arithmetic.py
    cl = ClosedLoop(sn637_creep, _controllers(root)["fixed"], noise=True, seed=3)
    cl.reset(u0=50.0)
    cl.run(np.zeros(50))
    ir = fresh_llvm(closed_loop._loop, closed_loop._loop.signatures[0], error_model="numpy")
    n_blocks, n_cyclic, hits = refcounts_in_loops(ir, "closed_loop5_loopB")
    assert n_cyclic > 100 and hits == []
