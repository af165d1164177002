"""The amplifier's current limit with the series resistor out (R = 0, the quasi-static form; session 37).

Seed 000's amplifier saturates on its current whether or not R sits between it and the stack: without R the
terminal charge moves at most ``I_src dt`` (rising) or ``I_snk dt`` (falling) a step, so the terminal voltage slews
at ``I / C`` until it reaches the command. Before session 37 the quasi-static step set ``V_t = v`` at every sub-step
(no limit at all): a resistor-out record stepped 30-270x faster than the declared amplifier can (session 36).

Checked here: the closed form on a linear capacitance (slew at ``I / C``, arrival after ``C |dV| / I``, both
directions), the charge of a real plant's slew (``I k dt`` a step until the static charge of the command), the
limit ``R -> 0`` of the dynamic form (bounds derived from ``R C / dt``), Kirchhoff's current law with creep branches
relaxing during a slew, and a drive the limit never binds on (the static operator's answer to rounding). The fast
step against its reference twin through the limit: tests/plant/test_kernel_arithmetic.py.
"""

import dataclasses

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from workbench.plant import PZTSimulator, load_plant
from workbench.plant import kernels as K
from workbench.plant.hysteresis import PrandtlIshlinskii
from workbench.plant.pzt import PZTParams

from tests.plant.step_runs import run_steps_with_creep_charge

PLANTS = ("p888_51_sn637.toml", "p888_51_sn637_creep.toml", "p888_51_sn618.toml", "p888_51_sn629.toml",
          "p888_51_sn637_on_flexure.toml")


def _linear(c_h, c_p, t_em, k_p, i_src, i_snk, r=0.0):
    """A stack whose C_h is linear (one play, threshold 0): the terminal sees C = 1 / (1 / C_h + 1 / C_pp)."""
    return PZTParams(series_resistance_ohm=r, current_limit_source_a=i_src, current_limit_sink_a=i_snk,
                     voltage_min_v=-1e3, voltage_max_v=1e3, working_capacitance_f=c_p,
                     transducer_constant_n_per_v=t_em, stiffness_n_per_m=k_p,
                     hysteresis=PrandtlIshlinskii(np.array([0.0]), np.array([c_h]), np.array([0.0])))


_log = lambda lo, hi: st.floats(np.log(lo), np.log(hi)).map(np.exp)     # noqa: E731 (log-uniform floats)


@given(c_h=_log(1e-9, 1e-4), c_p=_log(1e-9, 1e-4), t_em=_log(0.1, 100.0), k_p=_log(1e5, 1e9),
       i_src=_log(1e-5, 1.0), v1=st.floats(0.5, 900.0), v2=st.floats(-900.0, 0.0),
       n1=st.floats(1.5, 800.0), n2=st.floats(1.5, 800.0))
@settings(max_examples=120, deadline=None)
def test_a_linear_capacitance_slews_at_the_limit_and_arrives_after_c_dv_over_i(c_h, c_p, t_em, k_p, i_src, v1, v2,
                                                                              n1, n2):
    """From rest to ``v1`` at the source limit, then to ``v2 < v1`` at the sink limit: the charge moves ``I dt`` a
    step, ``V_t = V_0 +/- I t / C``, until it reaches the command after ``C |dV| / I`` steps (``n1``, ``n2``, not
    whole numbers: they set dt and the sink limit), then stays there. Capacitances, the source limit (the sink's
    follows, 1e-5..1e3 A), voltages and the step counts drawn over decades."""
    pz0 = _linear(c_h, c_p, t_em, k_p, i_src, 1.0)
    c = 1.0 / (1.0 / c_h + 1.0 / pz0.c_pp_f)
    dt = c * v1 / (i_src * n1)                    # the rise takes n1 steps at the source limit
    i_snk = c * (v1 - v2) / (n2 * dt)             # the fall n2 at the sink limit
    pz = dataclasses.replace(pz0, current_limit_sink_a=i_snk)
    n2_dt = c * (v1 - v2) / (i_snk * dt)          # n2, as the simulator's arithmetic sees it
    assume(abs(n1 - round(n1)) > 1e-6 and abs(n2_dt - round(n2_dt)) > 1e-6)
    k1, k2 = int(np.ceil(n1)) + 3, int(np.ceil(n2_dt)) + 3
    tr = PZTSimulator(pz, dt).run(np.r_[np.full(k1, v1), np.full(k2, v2)])
    k = np.arange(1, k1 + k2 + 1)
    q_up = np.minimum(i_src * dt * k[:k1], c * v1)
    q_dn = np.maximum(c * v1 - i_snk * dt * (k[k1:] - k1), c * v2)
    q_ref = np.r_[q_up, q_dn]
    scale = c * max(v1, -v2, v1 - v2)
    np.testing.assert_allclose(tr.q_c, q_ref, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(tr.v_t_v, q_ref / c, rtol=0, atol=1e-12 * max(v1, -v2))
    # the arrivals: the first step at the command is ceil(C |dV| / (I dt)), before it the terminal is short of it
    at1 = np.flatnonzero(np.abs(tr.v_t_v[:k1] - v1) <= 1e-12 * v1)
    at2 = np.flatnonzero(np.abs(tr.v_t_v[k1:] - v2) <= 1e-12 * (v1 - v2))
    assert at1[0] + 1 == int(np.ceil(n1)) and at2[0] + 1 == int(np.ceil(n2_dt))
    assert np.all(tr.v_t_v[:k1] <= v1 * (1 + 1e-12)) and np.all(tr.v_t_v[k1:] >= v2 - 1e-12 * (v1 - v2))
    # the peak currents: the limits themselves
    assert tr.peak_current_a[0] == pytest.approx(i_src, rel=1e-9)
    assert tr.peak_current_a[1] == pytest.approx(-i_snk, rel=1e-9)


@pytest.mark.parametrize("plant_file", PLANTS)
def test_a_real_stack_s_charge_slews_at_the_limit_to_the_static_charge_of_the_command(root, rng, plant_file):
    """Every plant file (creep left out: its branches move charge inside the stack during a slew), steps from rest up
    to a drawn level and down to another: the terminal charge moves ``I dt`` a step (source rising, sink falling)
    until it is the charge the static operator ``G^-1`` gives the command along that path (the hysteresis' own
    closed form, :meth:`PrandtlIshlinskii.inverse`), then holds it. The steps to arrive are ``ceil(dq / (I dt))``."""
    pz = dataclasses.replace(load_plant(root / "plants" / plant_file).pzt.with_resistance(0.0), creep=None)
    g = pz.terminal_operator()
    v1 = rng.uniform(0.3, 1.0) * pz.voltage_max_v
    v2 = pz.voltage_min_v + rng.uniform(0.0, 0.7) * (v1 - pz.voltage_min_v)
    q_static = g.inverse()(np.array([g.output_at_rest(), v1, v2]))        # q_h at rest, at v1, then at v2
    dt = rng.uniform(0.5, 2.0) * 1e-5
    n1 = (q_static[1] - q_static[0]) / (pz.current_limit_source_a * dt)
    n2 = (q_static[1] - q_static[2]) / (pz.current_limit_sink_a * dt)
    assert n1 > 20 and n2 > 5                          # both steps slew
    k1, k2 = int(np.ceil(n1)) + 50, int(np.ceil(n2)) + 50
    tr = PZTSimulator(pz, dt).run(np.r_[np.full(k1, v1), np.full(k2, v2)])
    k = np.arange(1, k1 + k2 + 1)
    q_ref = np.r_[np.minimum(q_static[0] + pz.current_limit_source_a * dt * k[:k1], q_static[1]),
                  np.maximum(q_static[1] - pz.current_limit_sink_a * dt * (k[k1:] - k1), q_static[2])]
    np.testing.assert_allclose(tr.q_c, q_ref, rtol=0, atol=1e-12 * np.max(np.abs(q_static)))
    assert abs(tr.v_t_v[k1 - 1] - v1) <= 1e-12 * pz.voltage_max_v and abs(tr.v_t_v[-1] - v2) <= 1e-12 * pz.voltage_max_v
    # short of the command until the arrival: V_t never passes it
    assert np.all(tr.v_t_v[:k1] <= v1 + 1e-12 * pz.voltage_max_v)
    assert np.all(tr.v_t_v[k1:] >= v2 - 1e-12 * pz.voltage_max_v)
    # the slew in volts lies between I / C_max and I / C_min (C along a continuing move grows from the reversal's)
    slew = np.diff(tr.v_t_v[:int(n1) - 1]) / dt
    c_max = 1.0 / (np.cumsum(g.weights).min())
    assert np.all(slew <= pz.current_limit_source_a / pz.min_capacitance_f * (1 + 1e-9))
    assert np.all(slew >= pz.current_limit_source_a / c_max * (1 - 1e-9))


@given(c_h=_log(1e-8, 1e-4), c_p=_log(1e-8, 1e-4), i_src=_log(1e-4, 0.1), i_snk=_log(1e-4, 0.1),
       rc_over_dt=_log(1e-6, 1e-3), levels=st.lists(st.floats(-100.0, 100.0), min_size=3, max_size=6),
       hold=st.integers(1, 400))
@settings(max_examples=60, deadline=None)
def test_the_dynamic_form_tends_to_the_quasi_static_one_as_r_goes_to_zero(c_h, c_p, i_src, i_snk, rc_over_dt,
                                                                           levels, hold):
    """A linear stack, R with ``R C = rc_over_dt dt`` (1e-6..1e-3): the dynamic form's terminal charge differs from
    the quasi-static form's by the charge the drop across R holds back, at most ``C R I_max``, and by the RC
    relaxation's tail ``C |dV| exp(-dt / (R C))`` (0 here), at every step, slewing or settled. dt such that a step of
    100 V slews for ``hold / 4`` steps at the source limit (every level draws its own mix of slews and holds)."""
    pz0 = _linear(c_h, c_p, 10.0, 1e7, i_src, i_snk)
    c = 1.0 / (1.0 / c_h + 1.0 / pz0.c_pp_f)
    dt = c * 100.0 / (i_src * max(hold / 4.0, 0.3))
    r = rc_over_dt * dt / c
    v = np.repeat(np.asarray(levels, float), hold)
    qs = PZTSimulator(pz0, dt).run(v)
    dyn = PZTSimulator(dataclasses.replace(pz0, series_resistance_ohm=r), dt).run(v)
    i_max = max(i_src, i_snk)
    bound = c * r * i_max + 1e-12 * c * 100.0
    assert np.max(np.abs(dyn.q_c - qs.q_c)) <= bound
    assert np.max(np.abs(dyn.v_t_v - qs.v_t_v)) <= bound / c


@pytest.mark.parametrize("plant_file", ("p888_51_sn637.toml", "p888_51_sn618.toml", "p888_51_sn629.toml"))
def test_a_real_stack_s_dynamic_form_at_a_milliohm_settles_where_the_quasi_static_one_does(root, rng, plant_file):
    """The hysteretic stacks at R = 1 mOhm (R C ~ 1e-8 s against dt = 10 us) and R = 0 on one drive of held levels
    from both voltage limits: both slew at the limit (the same ``I dt`` a step), and where the command has been
    held 20 steps past the later one's arrival the terminal charges agree within ``C_max R I_max`` (the drop across
    R) plus rounding. Between, the dynamic form's step on G's slope at the step's start lags the exact inverse while
    plays engage, by less than the step's charge: ``I_max dt`` bounds it everywhere."""
    pz = dataclasses.replace(load_plant(root / "plants" / plant_file).pzt.with_resistance(0.0), creep=None, modes=())
    dt, hold = 1e-5, 100_000                      # 1 s a level: the full range slews in ~0.85 s at 2 mA
    levels = np.r_[pz.voltage_max_v, pz.voltage_min_v, rng.uniform(pz.voltage_min_v, pz.voltage_max_v, 6)]
    v = np.repeat(levels, hold)
    qs = PZTSimulator(pz, dt).run(v)
    dyn = PZTSimulator(pz.with_resistance(1e-3), dt).run(v)
    i_max = max(pz.current_limit_source_a, pz.current_limit_sink_a)
    c_max = 1.0 / np.cumsum(pz.terminal_operator().weights).min()
    d = np.abs(dyn.q_c - qs.q_c)
    assert np.max(d) <= i_max * dt + c_max * 1e-3 * i_max
    settled = np.zeros(v.size, bool)
    for j in range(levels.size):
        seg = slice(j * hold, (j + 1) * hold)
        arrive = [np.flatnonzero(np.abs(tr.v_t_v[seg] - min(max(levels[j], pz.voltage_min_v), pz.voltage_max_v))
                                 <= 1e-3 * i_max + 1e-9) for tr in (qs, dyn)]
        assert arrive[0].size and arrive[1].size             # every level reached within its hold
        settled[j * hold + max(arrive[0][0], arrive[1][0]) + 20:(j + 1) * hold] = True
    assert settled.sum() > 0.3 * v.size
    assert np.max(d[settled]) <= c_max * 1e-3 * i_max + 1e-12 * np.max(np.abs(qs.q_c))


def test_the_amplifier_moves_the_terminal_charge_only_while_creep_branches_relax_during_a_slew(sn637_creep):
    """Kirchhoff's current law at the terminal with the creep plant, R out: during a slew the terminal charge
    ``q = q_h + Q_c`` moves exactly ``I dt`` a step although the branches take charge every step (from C_h's node,
    not from the amplifier); over the whole run the amplifier's current integrates to the terminal charge's change
    and never passes either limit; after the arrival the amplifier holds ``V_t = v`` and supplies the branches."""
    pz = sn637_creep.pzt.with_resistance(0.0)
    dt = 1e-5
    v = np.r_[np.full(80_000, 100.0), np.full(20_000, 10.0), np.full(60_000, 60.0)]
    sim = PZTSimulator(pz, dt)
    rec = run_steps_with_creep_charge(K.pzt_step, sim.m, sim.st, v, np.zeros_like(v))
    q, v_t, qc = rec[:, 1], rec[:, 5], rec[:, K.N_OUT]
    dq = np.diff(np.r_[sim_rest_charge(pz), q])
    dqc = np.diff(np.r_[0.0, qc])
    tol = 1e-12 * np.max(np.abs(q))
    assert np.all(dq <= pz.current_limit_source_a * dt + tol) and np.all(dq >= -pz.current_limit_sink_a * dt - tol)
    slewing = np.abs(v_t - v) > 1e-9
    rising = slewing & (v > v_t)
    falling = slewing & (v < v_t)
    assert rising.sum() > 1000 and falling.sum() > 50
    np.testing.assert_allclose(dq[rising], pz.current_limit_source_a * dt, rtol=0, atol=tol)
    np.testing.assert_allclose(dq[falling], -pz.current_limit_sink_a * dt, rtol=0, atol=tol)
    assert np.sum(dqc[rising]) > 1e-3 * np.sum(dq[rising])   # the branches take a share meanwhile (from C_h)
    # each level is reached and then held: V_t = v from the arrival to the level's end, the amplifier feeding the
    # branches (the terminal charge still moves)
    for a, b in ((0, 80_000), (80_000, 100_000), (100_000, 160_000)):
        at = np.flatnonzero(~slewing[a:b])
        assert at.size and np.all(~slewing[a + at[0]:b])
        assert np.all(np.abs(dq[a + at[0] + 1:b]) > 0.0)


def sim_rest_charge(pz):
    """The terminal charge of a stack at rest (its plays' initial states), C."""
    return float(pz.hysteresis.output_at_rest())


@given(amp=st.floats(1.0, 60.0), margin=st.floats(0.02, 0.9), per=st.integers(50, 2000), cycles=st.integers(1, 3))
@settings(max_examples=40, deadline=None)
def test_where_the_limit_never_binds_the_terminal_follows_the_command_as_the_static_operator_says(sn637, amp, margin,
                                                                                                 per, cycles):
    """A sine from rest whose peak current ``2 pi f A C_max`` is ``margin`` of the source limit (2 %-90 %), sampled
    ``per`` times a period: the limit never binds, so ``V_t = v`` at every step and the stroke is the static
    operator's (:meth:`PZTParams.quasi_static_x_m`, the quasi-static form before the limit) to 1e-12 of it."""
    pz = dataclasses.replace(sn637.pzt.with_resistance(0.0), modes=(), creep=None)
    c_max = 1.0 / np.cumsum(pz.terminal_operator().weights).min()
    f = margin * pz.current_limit_source_a / (2 * np.pi * amp * c_max)
    n = per * cycles
    t = np.arange(1, n + 1) / (f * per)
    v = amp * (1 - np.cos(2 * np.pi * f * t))
    tr = PZTSimulator(pz, 1.0 / (f * per)).run(v)
    assert tr.peak_current_a[0] < pz.current_limit_source_a and -tr.peak_current_a[1] < pz.current_limit_sink_a
    np.testing.assert_allclose(tr.v_t_v, v, rtol=0, atol=1e-12 * amp)
    x_ref = pz.quasi_static_x_m(np.r_[0.0, v])[1:]
    np.testing.assert_allclose(tr.x_m, x_ref, rtol=0, atol=1e-12 * np.max(np.abs(x_ref)))


@given(r1=st.floats(0.2, 5.0), r2=st.floats(0.2, 5.0), r3=st.floats(0.2, 5.0), w0=_log(1e-7, 1e-5),
       w_neg=st.floats(0.3, 0.9), w_pos=st.floats(0.0, 0.3), levels=st.lists(st.floats(0.0, 110.0), min_size=3,
                                                                            max_size=6),
       back=st.floats(0.3, 3.0))
@settings(max_examples=80, deadline=None)
def test_the_charge_a_step_moves_never_passes_the_limit_with_a_negative_weight_in_c_h(sn637, r1, r2, r3, w0, w_neg,
                                                                                     w_pos, levels, back):
    """A C_h whose PI has a negative weight (allowed: its partial sums stay positive) gives Q = G^-1 a negative one
    too, so Q's largest slope is its largest partial sum of weights (here the reversal's), not their sum: the
    quasi-static step's bound on the charge a step can take must use the former, or a step it thinks cannot bind
    moves more than ``I dt``. Held levels from rest (each a slew at the limit), each followed by a small step back
    of ``back`` times what the sink's limit moves in a step on the reversal's capacitance (0.3-3: the limit binds
    and does not): every step's terminal charge within ``[-I_snk dt, I_src dt]``, each level reached."""
    thr = np.cumsum([0.0, r1, r2, r3])
    w = np.array([w0, -w_neg * w0, w_pos * w_neg * w0, 0.5 * w_pos * w_neg * w0])   # partial sums > 0
    h = PrandtlIshlinskii(thr, w, np.zeros(4))
    pz = dataclasses.replace(sn637.pzt.with_resistance(0.0), hysteresis=h, modes=(), creep=None)
    g = pz.terminal_operator()
    c_rev = 1.0 / g.weights[0]
    c_big = 1.0 / np.cumsum(g.weights).min()
    dt = c_big * 100.0 / (pz.current_limit_source_a * 300.0)       # 100 V in ~300 steps at the source limit
    delta = back * pz.current_limit_sink_a * dt / c_rev
    v = np.concatenate([np.r_[np.full(1500, lv), np.full(50, lv - delta)] for lv in levels])
    tr = PZTSimulator(pz, dt).run(v)
    dq = np.diff(np.r_[pz.hysteresis.output_at_rest(), tr.q_c])
    tol = 1e-12 * np.max(np.abs(tr.q_c)) + 1e-30
    assert np.all(dq <= pz.current_limit_source_a * dt + tol), (dq.max(), pz.current_limit_source_a * dt)
    assert np.all(dq >= -pz.current_limit_sink_a * dt - tol), (dq.min(), -pz.current_limit_sink_a * dt)
    ends = tr.v_t_v[1499::1550]
    np.testing.assert_allclose(ends, np.clip(levels, pz.voltage_min_v, pz.voltage_max_v), rtol=0, atol=1e-9 * 100.0)
