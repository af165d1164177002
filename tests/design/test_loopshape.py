"""Structured loop shaping against a (reduced) family: targets met on every member, trade-offs, errors."""

import control
import numpy as np
import pytest

from workbench.design.loopshape import LoopShapeSpec, family_loops, structured_controller, tune_loop_shape
from workbench.design.margins import family_margins
from workbench.errors import DesignError
from workbench.linearize.uncertainty import FamilySpec, plant_family, uncertainty_bound

SPEC = FamilySpec(amplitudes_v=(0.1, 3.0), freq_hz=tuple(np.geomspace(1.0, 4990.0, 40)),
                  small_signal_biases_v=(50.0,))
SHAPES = dict(integral_ratios=(8.0,), lead_ratios=(1.0, 3.0), rolloff_ratios=(8.0,), fc_points=12)


@pytest.fixture(scope="module")
def family(sn637):
    fam = plant_family([sn637], SPEC)
    return fam, uncertainty_bound(fam, sn637)


def test_design_meets_the_targets_on_every_member(family):
    fam, ub = family
    r = tune_loop_shape(fam.freq_hz, fam.members, ub.nominal, LoopShapeSpec(**SHAPES))
    rows, worst = family_margins(fam.freq_hz, family_loops(r.controller_d, fam.freq_hz,
                                                           {n: g for n, g in fam.members.items()
                                                            if np.any(np.isfinite(g))}))
    assert all(abs(row["phase_margin_deg"]) >= 45 and abs(row["gain_margin_db"]) >= 6 for row in rows)
    assert worst["crossover_hz_min"]["value"] >= 100                   # the floor
    assert r.crossover_hz == pytest.approx(worst["crossover_hz_min"]["value"])
    # the integrator: infinite gain at DC (a pole at z = 1)
    assert np.min(np.abs(r.controller_d.poles() - 1)) < 1e-9


def test_stricter_margins_cost_crossover(family):
    fam, ub = family
    loose = tune_loop_shape(fam.freq_hz, fam.members, ub.nominal, LoopShapeSpec(**SHAPES))
    strict = tune_loop_shape(fam.freq_hz, fam.members, ub.nominal,
                             LoopShapeSpec(phase_margin_deg=75.0, **SHAPES))
    assert strict.params["fc_hz"] < loose.params["fc_hz"]
    assert strict.worst["phase_margin_deg"]["value"] >= 75 and strict.worst["gain_margin_db"]["value"] >= 6


def test_impossible_crossover_range_is_an_error(family):
    fam, ub = family
    with pytest.raises(DesignError, match="lower the range"):
        tune_loop_shape(fam.freq_hz, fam.members, ub.nominal,
                        LoopShapeSpec(fc_range_hz=(2500.0, 4000.0), **{**SHAPES, "fc_points": 3}))


def test_structured_controller_shape():
    c = structured_controller(2.0, 300.0, 5.0, 4.0, 6.0, 0.6)
    w = 2 * np.pi * 300.0
    # the lead is centred on f_c: the phase there is the lead's maximum, atan((a - 1) / (2 sqrt a)) = 36.9 deg,
    # less the PI's atan(1/5) and the roll-off's small lag
    ph = np.degrees(np.angle(complex(np.squeeze(c(1j * w)))))
    lead = np.degrees(np.arctan(3 / 4))
    pi = np.degrees(np.arctan(1 / 5))
    roll = np.degrees(np.arctan2(2 * 0.6 / 6, 1 - 1 / 36))
    assert ph == pytest.approx(lead - pi - roll, abs=1e-6)
    notch = structured_controller(2.0, 300.0, 5.0, 1.0, 6.0, 0.6, notch=(1000.0, 20.0, 0.5))
    n_at = abs(complex(np.squeeze(notch(2j * np.pi * 1000.0))))
    plain = abs(complex(np.squeeze(structured_controller(2.0, 300.0, 5.0, 1.0, 6.0, 0.6)(2j * np.pi * 1000.0))))
    assert 20 * np.log10(plain / n_at) == pytest.approx(20.0, abs=1e-6)


def test_noise_on_the_command_closed_form():
    # a static controller d on a zero plant: the command steps are d times the difference of
    # white noise, RMS sqrt(2) d sigma
    import control
    from workbench.design.loopshape import noise_command_rms_v
    k = control.ss([], [], [], [[3.0]], 1e-4)
    zero = control.ss([], [], [], [[0.0]])
    assert noise_command_rms_v(k, zero, 0.01) == pytest.approx(np.sqrt(2) * 3.0 * 0.01, rel=1e-3)


def test_noise_budget_lowers_the_crossover(family):
    fam, ub = family
    free = tune_loop_shape(fam.freq_hz, fam.members, ub.nominal, LoopShapeSpec(**SHAPES))
    from workbench.design.loopshape import noise_command_rms_v
    budget = 0.5 * noise_command_rms_v(free.controller_d, ub.nominal, 7e-3)
    tight = tune_loop_shape(fam.freq_hz, fam.members, ub.nominal,
                            LoopShapeSpec(max_noise_command_v=budget, noise_reading_v=7e-3, **SHAPES))
    assert noise_command_rms_v(tight.controller_d, ub.nominal, 7e-3) <= budget
    assert tight.params["fc_hz"] < free.params["fc_hz"]


@pytest.mark.parametrize("fc_hz, ri, al, rr, dt_s, notch", [(120.0, 0.25, 3.0, 8.0, 1e-4, None),
                                                             (900.0, 8.0, 1.0, 4.0, 1e-4, None),
                                                             (40.0, 1.0, 6.0, 4.0, 2.5e-4, None),
                                                             (250.0, 1.0, 3.0, 6.0, 1e-4, (1070.0, 20.0, 0.4))])
def test_search_scores_exactly_the_discretized_controller(fc_hz, ri, al, rr, dt_s, notch):
    """The search's closed-form prewarped Tustin response equals python-control's c2d of the same C."""
    from workbench.design.antiwindup import discretize
    from workbench.design.loopshape import shape_response, tustin_s
    f = np.geomspace(0.5, 0.49 / dt_s, 300)
    c = structured_controller(2.5, fc_hz, ri, al, rr, notch=notch)
    ref = np.asarray(control.frequency_response(discretize(c, dt_s, fc_hz), 2 * np.pi * f).complex).ravel()
    fast = shape_response(tustin_s(f, dt_s, fc_hz), 2.5, fc_hz, ri, al, rr, notch=notch)
    np.testing.assert_allclose(fast, ref, rtol=1e-8)


def test_binding_constraint_named_and_relaxing_it_raises_the_crossover(family):
    """The noise budget set at half the free design's noise binds; doubling it lets the crossover rise."""
    from workbench.design.loopshape import noise_command_rms_v, relaxed
    fam, ub = family
    free = tune_loop_shape(fam.freq_hz, fam.members, ub.nominal, LoopShapeSpec(**SHAPES, noise_reading_v=7e-3))
    budget = 0.5 * noise_command_rms_v(free.controller_d, ub.nominal, 7e-3)
    spec = LoopShapeSpec(**SHAPES, max_noise_command_v=budget, noise_reading_v=7e-3)
    tight = tune_loop_shape(fam.freq_hz, fam.members, ub.nominal, spec)
    b = tight.binding
    assert b["constraint"] == "noise budget" and b["value"] > b["limit"] == pytest.approx(budget)
    assert b["at_fc_hz"] > tight.params["fc_hz"]
    loose = tune_loop_shape(fam.freq_hz, fam.members, ub.nominal, relaxed(spec, "noise budget"))
    assert loose.crossover_hz > tight.crossover_hz


@pytest.mark.parametrize("seed", range(6))
def test_triangle_tracking_of_a_pure_integrator_loop_closed_form(seed):
    """L = K_v / s: the error is a square wave of +/- r'/K_v with exponential corners; over a half period H
    its mean square is (r'/K_v)^2 (1 - 2/(K_v H) + O(e^{-K_v H})). Frequencies, spans and K_v drawn wide."""
    from workbench.design.loopshape import tracking_rms, triangle_harmonics
    rng = np.random.default_rng(seed)
    f0 = 10 ** rng.uniform(-2, 1)
    span = rng.uniform(0.1, 1.0)
    half = 0.5 / f0
    kv = 10 ** rng.uniform(np.log10(30 / half), np.log10(2000 / half))
    f, a = triangle_harmonics(f0, span)
    rate = span / half                                     # p-p span in half a period
    expected = rate / kv * np.sqrt(1 - 2 / (kv * half))
    assert tracking_rms(kv / (2j * np.pi * f), a) == pytest.approx(expected, rel=2e-3)
    # the harmonics themselves: a triangle of p-p ``span`` (Parseval: RMS^2 = span^2 / 12)
    assert np.sqrt(0.5 * np.sum(a ** 2)) == pytest.approx(span / np.sqrt(12), rel=1e-6)



@pytest.mark.parametrize("seed", range(4))
def test_triangle_tracking_with_the_lead_matches_the_sampled_loop_fed_r_plus_v_lead(seed):
    """tracking_rms with lead L is |S_k (1 - D_k L L_k) r_k| on the harmonics: checked against the discrete
    closed loop L(z) = K_v T / (z - 1) (1 - a) / (z - a) fed the triangle led on its planned slope
    (verify's planned_slope_lead), steady state over the last period. Without a lead the same formula is the
    old |S_k r_k|; with L = 1/K_v only the extra pole's share is left (much below the ramp lag v/K_v).
    K_v, the pole and the triangle's frequency drawn wide."""
    from workbench.design.loopshape import tracking_rms, triangle_harmonics
    from workbench.verify.scenarios import planned_slope_lead
    rng = np.random.default_rng(seed)
    dt = 1e-3
    f0 = float(rng.choice([0.5, 1.0, 2.0]))
    kv = 10 ** rng.uniform(1.3, 2.0)                       # 20-100 1/s: ramp lag well resolved
    a = rng.uniform(0.3, 0.8)                              # the extra pole, z = a
    z = control.TransferFunction([1, 0], [1], dt)
    loop = kv * dt / (z - 1) * (1 - a) / (z - a)
    cl = control.feedback(loop, 1)
    per = int(round(1 / (f0 * dt)))
    n = 6 * per
    t = np.arange(n + 1) * dt
    span = 1.0
    r_next = span * 2 * np.abs((t * f0 + 0.25) % 1.0 - 0.5)
    f, amp = triangle_harmonics(f0, span, 0.5 / dt)
    lz = np.array([complex(loop(np.exp(2j * np.pi * fk * dt))) for fk in f])
    for lead in (0.0, 1.0 / kv, 0.5 / kv):
        fed = planned_slope_lead(r_next, dt, lead)
        y = control.forced_response(cl, T=t[:-1], U=fed).outputs
        e = (r_next[:-1] - y)[-per:]
        got = float(np.sqrt(np.mean((e - 0.0) ** 2)))
        assert tracking_rms(lz, amp, f, lead, dt) == pytest.approx(got, rel=0.01), lead
    assert tracking_rms(lz, amp, f, 1.0 / kv, dt) < 0.5 * tracking_rms(lz, amp)
    assert tracking_rms(lz, amp) == tracking_rms(lz, amp, f, 0.0, dt)

def test_the_search_honours_the_tracking_limit(family):
    """With a tracking limit below what the free design reaches, the chosen design meets it, every shape ruled
    out missed it on the nominal loop, and tightening it can only cost crossover."""
    from workbench.design.loopshape import triangle_harmonics
    fam, ub = family
    shapes = dict(integral_ratios=(0.25, 1.0, 8.0), lead_ratios=(1.0, 3.0), rolloff_ratios=(8.0,), fc_points=12)
    f_tr, a_tr = triangle_harmonics(0.1, 0.8, 4500.0)
    probe = LoopShapeSpec(**shapes, tracking_freq_hz=tuple(f_tr), tracking_amplitudes=tuple(a_tr),
                          max_tracking_rms=1.0)            # never binds: measures the free design
    free = tune_loop_shape(fam.freq_hz, fam.members, ub.nominal, probe)
    assert not free.tracking["ruled_out"]
    limit = 0.7 * free.tracking["rms"]
    r = tune_loop_shape(fam.freq_hz, fam.members, ub.nominal, LoopShapeSpec(
        **shapes, tracking_freq_hz=tuple(f_tr), tracking_amplitudes=tuple(a_tr), max_tracking_rms=limit))
    assert r.tracking["rms"] <= limit
    assert r.tracking["ruled_out"] and all(m["rms"] > limit for m in r.tracking["ruled_out"])
    assert r.crossover_hz <= free.crossover_hz
    assert (r.params["integral_ratio"], r.params["lead_ratio"]) != (free.params["integral_ratio"],
                                                                   free.params["lead_ratio"])
    with pytest.raises(DesignError, match="tracks the reference"):
        tune_loop_shape(fam.freq_hz, fam.members, ub.nominal, LoopShapeSpec(
            **shapes, tracking_freq_hz=tuple(f_tr), tracking_amplitudes=tuple(a_tr), max_tracking_rms=1e-9))


def test_type_two_shape_has_a_double_integrator_and_is_scored_exactly():
    """integral_order 2: (1 + w_i/s)^2, two poles at s = 0 (z = 1 after Tustin); the search's response
    is the discretized controller's."""
    from workbench.design.antiwindup import discretize
    from workbench.design.loopshape import shape_response, tustin_s
    c = structured_controller(2.0, 300.0, 4.0, 3.0, 8.0, 0.6, integral_order=2)
    assert np.sum(np.abs(c.poles()) < 1e-6) == 2
    cd = discretize(c, 1e-4, 300.0)
    assert np.sum(np.abs(cd.poles() - 1) < 1e-6) == 2
    f = np.geomspace(0.1, 4000.0, 50)
    fast = shape_response(tustin_s(f, 1e-4, 300.0), 2.0, 300.0, 4.0, 3.0, 8.0, 0.6, None, 2)
    exact = np.asarray(control.frequency_response(cd, 2 * np.pi * f).complex).ravel()
    assert np.allclose(fast, exact, rtol=1e-6)
