"""The plant kernels' fast arithmetic is the first formulation's physics.

``kernels.pzt_step`` (capacitance and exp(-dt/(R C)) once per capacitance segment, exact creep and
mode steps arranged off the dependency chain, no division) against ``kernels.pzt_step_reference``
(the step as first written, per-step divisions and exp) on drives over the whole range a user may
bring: every plant file with a stack, sub-steps from 1 us to 1 ms, levels past both voltage limits,
slews at the current limit, sines up to 2 kHz, force steps, the quasi-static (R = 0) form through its current
limit (session 37: G's plays its state too, so the two forms pass a state between them). And the
coupled kernel's cached segment entries against a fresh computation from its plays.
"""

import dataclasses

import numpy as np
import pytest
from numba import njit

from workbench.plant import PZTSimulator, load_plant
from workbench.plant import kernels as K
from workbench.plant.coupled import C_R, E_FDN, E_FDT, E_FUP, E_GDN, E_GUP, E_QH
from workbench.plant.hysteresis import pi_slope
from workbench.plant.mirror import load_mirror, mirror_run

from tests.compiled_loops import fresh_llvm, refcounts_in_loops
from tests.plant.step_runs import run_steps

PLANTS = ("p888_51_sn637.toml", "p888_51_sn637_creep.toml", "p888_51_sn618.toml", "p888_51_sn629.toml",
          "p888_51_sn637_on_flexure.toml")


def _drive(rng, n, pz):
    """Held levels from 20 % below the lower voltage limit to 20 % above the upper (every step slews
    at the current limit at the faster rates), a sine of random frequency (0.5 Hz-2 kHz) on top, force steps."""
    lo, hi = pz.voltage_min_v, pz.voltage_max_v
    span = hi - lo
    levels = rng.uniform(lo - 0.2 * span, hi + 0.2 * span, size=8)
    levels[:2] = lo - 0.2 * span, hi + 0.2 * span           # both limits reached
    v = levels.repeat(-(-n // 8))[:n]
    t = np.arange(n)
    v = v + rng.uniform(0.0, 0.1) * span * np.sin(2 * np.pi * rng.uniform(0.5, 2000.0) * t * 1e-5)
    f = rng.uniform(-50.0, 50.0, size=n // 500 + 1).repeat(500)[:n]
    return v, f


def _fast_against_reference(pz, dt_s, rng, n=20_000):
    """``pzt_step`` and ``pzt_step_reference`` on one drive (:func:`_drive`) from one state: outputs and the whole
    state (creep branches, plays, modes; the modes' scratch copy and the fast step's band aside, the reference voids
    it) held together to the dynamic form's tolerances. Returns ``(v, ref)``: the drive and the reference's rows."""
    v, f = _drive(rng, n, pz)
    a, b = PZTSimulator(pz, dt_s), PZTSimulator(pz, dt_s)
    fast = run_steps(K.pzt_step, a.m, a.st, v, f)
    ref = run_steps(K.pzt_step_reference, b.m, b.st, v, f)
    scale = np.max(np.abs(ref), axis=0)
    err = np.max(np.abs(fast - ref), axis=0)
    x, q, i, v_h, v_p, v_t = range(K.N_OUT)
    assert err[x] <= 1e-12 * scale[x] and err[q] <= 1e-12 * scale[q]
    assert err[v_h] <= 1e-10 * scale[v_h] and err[v_p] <= 1e-10 * scale[v_p] and err[v_t] <= 1e-10 * scale[v_t]
    assert err[i] <= 1e-9 * scale[i]
    keep = np.ones(a.st.size, bool)
    o_x, n_m = int(a.m[K.OS_XM]), int(a.m[K.N_M])
    keep[o_x + n_m:o_x + 2 * n_m] = False
    keep[[K.S_PL, K.S_PU, K.S_Y1]] = False
    np.testing.assert_allclose(a.st[keep], b.st[keep], rtol=1e-9, atol=1e-12 * scale[q])
    return v, ref


@pytest.mark.parametrize("plant_file", PLANTS)
@pytest.mark.parametrize("dt_s", [1e-6, 1e-5, 1e-4, 1e-3])
def test_the_fast_step_is_the_reference_step(root, rng, plant_file, dt_s):
    pz = load_plant(root / "plants" / plant_file).pzt
    _, ref = _fast_against_reference(pz, dt_s, rng)
    _, _, i, _, _, v_t = range(K.N_OUT)
    # the drive reached the branches: the fall from rest to the lower limit at the sink limit (where a
    # step is shorter than the slew) and, over the 20 s at 1 ms, the stack from one voltage limit to the other
    if dt_s <= 1e-4:
        assert ref[:, i].min() <= -0.98 * pz.current_limit_sink_a
    else:
        assert np.ptp(ref[:, v_t]) > 0.9 * (pz.voltage_max_v - pz.voltage_min_v)


@pytest.mark.parametrize("plant_file", PLANTS)
@pytest.mark.parametrize("dt_s", [1e-6, 1e-5, 1e-4, 1e-3])
def test_the_fast_quasi_static_step_is_the_reference_step_through_the_limit(root, rng, plant_file, dt_s):
    """``pzt_step`` (Q = G^-1 read from G's plays) against ``pzt_step_reference`` (G alone: the limit's charge tried,
    else bisection) with R out, every plant file, sub-steps 1 us-1 ms: outputs and states (plays, creep, modes) to
    the tolerances of the dynamic form's test; the drive slews at the limit (at the finer steps) and holds."""
    pz = load_plant(root / "plants" / plant_file).pzt.with_resistance(0.0)
    _, ref = _fast_against_reference(pz, dt_s, rng)
    _, _, i, _, _, _ = range(K.N_OUT)
    # the limit bound: both peaks at the limits where a level's step slews (all but the coarsest step)
    assert ref[:, i].max() <= pz.current_limit_source_a * (1 + 1e-9)
    assert ref[:, i].min() >= -pz.current_limit_sink_a * (1 + 1e-9)
    if dt_s <= 1e-4:
        assert ref[:, i].max() >= pz.current_limit_source_a * (1 - 1e-9)
        assert ref[:, i].min() <= -pz.current_limit_sink_a * (1 - 1e-9)


@pytest.mark.parametrize("plant_file", PLANTS)
@pytest.mark.parametrize("dt_s", [1e-5, 1e-3])
def test_without_an_amplifier_the_fast_step_is_the_reference_and_the_terminal_is_the_command(root, rng, plant_file,
                                                                                             dt_s):
    """``PZTParams.terminal_driven()`` (R = 0, both limits infinite: the calibration's replay of a recorded terminal
    voltage): the fast step against its Python twin, finite (the review of s37_rlimit, B2: the twin bracketed the
    limit's charge at +-inf and returned NaN), and the terminal at the command, clipped to the range, at every step."""
    pz = load_plant(root / "plants" / plant_file).pzt.terminal_driven()
    v, ref = _fast_against_reference(pz, dt_s, rng)
    assert np.all(np.isfinite(ref))
    *_, v_t = range(K.N_OUT)
    clipped = np.clip(v, pz.voltage_min_v, pz.voltage_max_v)
    np.testing.assert_allclose(ref[:, v_t], clipped, rtol=1e-12, atol=1e-12 * np.max(np.abs(clipped)))


def test_the_two_steps_can_share_a_state(sn637_creep, rng):
    # the reference keeps the capacitance segment entries current: alternating the two on one state
    # stays on the fast step's trajectory
    pz = sn637_creep.pzt
    v, f = _drive(rng, 4000, pz)
    a, b = PZTSimulator(pz, 1e-5), PZTSimulator(pz, 1e-5)
    fast = run_steps(K.pzt_step, a.m, a.st, v, f)
    mixed = np.vstack([run_steps(K.pzt_step_reference if k % 2 else K.pzt_step, b.m, b.st, v[k:k + 500], f[k:k + 500])
                       for k in range(0, 4000, 500)])
    assert np.max(np.abs(mixed[:, 0] - fast[:, 0])) <= 1e-12 * np.max(np.abs(fast[:, 0]))


def test_the_quasi_static_steps_can_share_a_state_and_pass_it_to_the_dynamic_form(sn637_creep, rng):
    """G's plays are the state of both forms now: alternating the fast and the reference quasi-static steps on one
    state stays on the fast step's trajectory; and a state the quasi-static form leaves at rest at a level, handed
    to the dynamic form (R in), holds that level (no charge moves: the terminal already at the command)."""
    pz = sn637_creep.pzt.with_resistance(0.0)
    v, f = _drive(rng, 4000, pz)
    a, b = PZTSimulator(pz, 1e-5), PZTSimulator(pz, 1e-5)
    fast = run_steps(K.pzt_step, a.m, a.st, v, f)
    mixed = np.vstack([run_steps(K.pzt_step_reference if k % 2 else K.pzt_step, b.m, b.st, v[k:k + 500],
                                 f[k:k + 500]) for k in range(0, 4000, 500)])
    assert np.max(np.abs(mixed[:, 0] - fast[:, 0])) <= 1e-12 * np.max(np.abs(fast[:, 0]))
    pz0 = dataclasses.replace(pz, creep=None, modes=())
    qs = PZTSimulator(pz0, 1e-5)
    tr = qs.run(np.full(60_000, 70.0))
    assert tr.v_t_v[-1] == pytest.approx(70.0, abs=1e-12)
    dyn = PZTSimulator(pz0.with_resistance(80.0), 1e-5)
    dyn.st[:] = qs.st
    tr2 = dyn.run(np.full(1000, 70.0))
    np.testing.assert_allclose(tr2.q_c, tr.q_c[-1], rtol=0, atol=1e-12 * abs(tr.q_c[-1]))
    # and on: R in to R out and back, each leg on a new level, the fast step against the reference on the state
    # handed over (the reference forms its RC step afresh; the fast one's RC factors, cached in the state, must be
    # re-formed for each model's R: a stale R = 0 factor relaxes the whole gap in one step)
    legs = ((80.0, 40.0), (0.0, 90.0), (80.0, 90.05), (0.0, 60.0), (80.0, 59.9), (80.0, 75.0))   # 50 mV < R I
    ref_st = dyn.st.copy()
    traj = []
    for r, level in legs:
        sim = PZTSimulator(pz0.with_resistance(r), 1e-5)
        sim.st[:] = dyn.st
        st_ref = dyn.st.copy()
        v = np.full(40_000, level)
        traj.append(sim.run(v))
        ref = run_steps(K.pzt_step_reference, sim.m, st_ref, v, np.zeros_like(v))
        assert np.max(np.abs(traj[-1].v_t_v - ref[:, 5])) <= 1e-10 * 100.0, r
        dyn.st[:] = sim.st
    # the dynamic legs settle on their level through 80 ohm (R C ~ 1 ms) and the static legs slew to theirs
    for (r, level), tr_leg in zip(legs, traj):
        assert abs(tr_leg.v_t_v[-1] - level) <= (1e-9 if r else 1e-12) * 100.0, (r, level, tr_leg.v_t_v[-1])
    # each dynamic leg's charge at rest is where the quasi-static form puts the same history (the static operator)
    v_hist = np.r_[pz0.terminal_operator().output_at_rest(), 70.0, [lv for _, lv in legs]]
    q_static = pz0.terminal_operator().inverse()(v_hist)[2:]
    got = np.array([tr_leg.q_c[-1] for tr_leg in traj])
    np.testing.assert_allclose(got, q_static, rtol=0, atol=1e-9 * np.max(np.abs(q_static)))
    assert not np.array_equal(ref_st, dyn.st)


def test_the_coupled_kernels_segment_entries_are_its_plays_slopes(root, rng):
    # after a drive through the current limit, each stack's cached capacitances are 1 / its plays' slopes
    # now, and the cached RC factors those capacitances' C (1 - exp(-h / (R C)))
    m = load_mirror(root / "plants" / "fsm_p888_51.toml")
    sim = m.simulator(1e-4, 2)
    n = 3000
    v = np.clip(rng.normal(0.0, 40.0, size=(n // 100, 3)).repeat(100, axis=0), -20.0, 120.0)
    mirror_run(sim, v)
    for j in range(3):
        o0, o1 = sim.g_off[j], sim.g_off[j + 1]
        z, r, w = sim.zg[o0:o1], sim.g_r[o0:o1], sim.g_w[o0:o1]
        qh = sim.es[j, E_QH]
        for cap, fac, direction in ((E_GUP, E_FUP, 1), (E_GDN, E_FDN, -1)):
            c = 1.0 / pi_slope(z, r, w, qh, direction)
            assert sim.es[j, cap] == c
            assert sim.es[j, fac] == K.rc_factor(c, sim.h_s, sim.sc[j, C_R])


def test_a_state_copied_into_a_model_with_another_step_is_stepped_as_the_reference(sn637_creep, rng):
    # the describing functions settle at a bias with 100 us steps and copy that state into simulators
    # with other steps: the RC factors the state carries are re-formed for the new dt, not reused
    pz = sn637_creep.pzt
    settle = PZTSimulator(pz, 1e-4)
    settle.run(np.full(5000, 50.0))
    v = 50.0 + 0.1 * np.sin(2 * np.pi * np.arange(4000) / 400)
    f = np.zeros_like(v)
    a, b = PZTSimulator(pz, 2.5e-6), PZTSimulator(pz, 2.5e-6)
    a.st[:] = settle.st
    b.st[:] = settle.st
    fast = run_steps(K.pzt_step, a.m, a.st, v, f)
    ref = run_steps(K.pzt_step_reference, b.m, b.st, v, f)
    assert np.max(np.abs(fast[:, 0] - ref[:, 0])) <= 1e-12 * np.max(np.abs(ref[:, 0]))


def test_a_coupled_state_copied_into_a_simulator_with_another_step_reforms_its_rc_factors(root):
    # a settled state whose RC factors were formed for another sub-step (as a copy from a simulator with
    # n_sub = 1 into one with n_sub = 2 carries them): the run re-forms them, so a small signal about the
    # bias (where the unlimited RC step uses them) gives the same trajectory as the intact state
    import copy
    m = load_mirror(root / "plants" / "fsm_p888_51.toml")
    sim = m.simulator(1e-4, 2)
    mirror_run(sim, np.full((8000, 3), 30.0))                # the 2 mA source slews 30 V in ~0.45 s
    intact, copied = copy.deepcopy(sim), copy.deepcopy(sim)
    h_other = 1e-4
    for j in range(3):
        r = copied.sc[j, C_R]
        copied.es[j, E_FUP] = K.rc_factor(copied.es[j, E_GUP], h_other, r)
        copied.es[j, E_FDN] = K.rc_factor(copied.es[j, E_GDN], h_other, r)
        copied.es[j, E_FDT] = h_other
    v = 30.0 + 0.05 * np.sin(2 * np.pi * np.arange(400)[:, None] / 40 + np.arange(3))
    a, b = mirror_run(intact, v), mirror_run(copied, v)
    np.testing.assert_array_equal(a.coupled.x_m, b.coupled.x_m)


@njit
def _through_borrowed(a):
    v = K._borrowed(a)
    v[0] = 7.0
    total = 0.0
    for i in range(v.shape[0]):
        total += v[i]
    return total, v.shape[0]


def test_a_borrowed_view_is_the_array_without_a_reference_count():
    # the compiled loops take borrowed views of their arrays (no atomic count per step): the view writes
    # through to the caller's array and has its shape; holding it neither keeps nor frees the array (the
    # caller's reference count is what it was); interpreted, borrowed is the array itself.
    # What the view is for, no reference count or atomic inside the loops of pzt_run and closed_loop._loop, is
    # asserted on their compiled code below and in tests/test_bench_closed_loop.py; with the view replaced by a
    # plain one (arr[:]) the check fails (test_a_plain_view_in_pzt_run_would_count_every_step).
    import sys
    a = np.arange(5.0)
    before = sys.getrefcount(a)
    for _ in range(3):
        total, n = _through_borrowed(a)
    assert a[0] == 7.0 and total == 17.0 and n == 5
    assert sys.getrefcount(a) == before
    assert K._borrowed(a) is a


@njit
def _array_per_iteration(a, n):
    t = 0.0
    for i in range(n):
        b = np.empty(2)                 # allocated and freed (NRT_decref) every iteration
        b[0], b[1] = a[i % a.size], t
        t += b[0] * b[1] + 1.0
    return t


@njit
def _reference_per_iteration(a, n):
    held = []
    for _ in range(n):
        held.append(a)                  # one more reference to a (NRT_incref) every iteration
    return len(held)


@pytest.mark.parametrize("func", [_array_per_iteration, _reference_per_iteration])
def test_the_loop_check_finds_a_reference_count_taken_every_iteration(func):
    # the control for the check below: a loop that does take a count per iteration is found
    func(np.ones(3), 4)
    ir = fresh_llvm(func, func.signatures[0])
    n_blocks, n_cyclic, hits = refcounts_in_loops(ir, func.__name__)
    assert 0 < n_cyclic < n_blocks and hits


def test_pzt_run_takes_no_reference_count_or_atomic_inside_its_loops(sn637_creep):
    # a locked increment is a full barrier: one per step would serialize the steps (README, the breakdown)
    sim = PZTSimulator(sn637_creep.pzt, 1e-6)
    sim.run(np.full(10, 1.0))
    ir = fresh_llvm(K.pzt_run, K.pzt_run.signatures[0], error_model="numpy")
    n_blocks, n_cyclic, hits = refcounts_in_loops(ir, "7pzt_runB")
    assert n_cyclic > 10 and hits == []


@pytest.mark.parametrize("plant_file", ["p888_51_sn637_creep.toml", "p888_51_sn629.toml"])
def test_the_shared_step_runner_is_pzt_run_step_for_step(root, plant_file, rng):
    # tests/plant/step_runs.run_steps (the plant tests' one runner) drives pzt_step as pzt_run drives
    # pzt_advance: with one sub-step the two give the same rows bit for bit over a drive past both limits
    pz = load_plant(root / "plants" / plant_file).pzt
    dt = 10 ** rng.uniform(-6, -3)
    v, f = _drive(rng, 3000, pz)
    a, b = PZTSimulator(pz, dt), PZTSimulator(pz, dt)
    rows = run_steps(K.pzt_step, a.m, a.st, v, f)
    tr = b.run(v, f)
    for col, got in zip(K.OUT_NAMES, (tr.x_m, tr.q_c, tr.i_a, tr.v_h_v, tr.v_p_v, tr.v_t_v)):
        np.testing.assert_array_equal(rows[:, K.OUT_NAMES.index(col)], got, err_msg=col)
    np.testing.assert_array_equal(a.st, b.st)


@njit(inline="always")
def _plain_view(arr):
    return arr[:]


def test_a_plain_view_in_pzt_run_would_count_every_step(sn637_creep):
    # the check above can fail on pzt_run itself: with _borrowed replaced by a plain view (arr[:]: a new reference
    # to the same data) numba counts a reference at every inlined step (NRT_incref/decref inside the loops)
    PZTSimulator(sn637_creep.pzt, 1e-6).run(np.full(10, 1.0))
    ir = fresh_llvm(K.pzt_run, K.pzt_run.signatures[0], {"_borrowed": _plain_view}, error_model="numpy")
    n_blocks, n_cyclic, hits = refcounts_in_loops(ir, "7pzt_runB")
    assert any("@NRT_incref" in h for h in hits) and any("@NRT_decref" in h for h in hits)
