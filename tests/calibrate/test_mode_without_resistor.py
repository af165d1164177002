"""A mode on a record with no series resistor (session 35, s35_rout; the review of s34_hold, B1).

Without the resistor the stack's terminal is the logged voltage itself: nothing between the amplifier and the stack
filters the drive, so a mode far above the record's Nyquist frequency rings in the samples at its alias, and what
tells it from its images is how the drive moved between samples. The record does not say how: a sampled smooth
voltage (a straight line between samples, the first-order hold), a command held from sample to sample (a step at
each sample), or a slew over part of the sample. Before session 35 such a record had no alias-family test: 8 of 30
modes drawn 30-700 Hz at 100 Hz were named at an alias and written (89.2 Hz at 11.62 Hz, gain 0.51). Now every
mode named there is tested in its family through every path from the step to the straight line
(:func:`~workbench.calibrate.tracing.direct_drives`, :meth:`~workbench.calibrate.effects.HeldDrive.direct`) and
written only where the record places it.

The records are simulated by the simulator's own means, independently of the paths: the straight line by
``simulate_record(upsample=8)`` (the command interpolated onto 8 points a sample), the held command by
``upsample=1`` (the simulator's ramp over the first of its ``N_SUB`` sub-steps a sample, where the amplifier's
current limit moves the step within it; since session 37 a larger step slews at the limit, as the amplifier does).
"""

import dataclasses

import numpy as np
import pytest
from scipy import signal

from tests.conftest import load_benchmark, reduced_draws
from workbench.calibrate.effects import HeldDrive, _foh_mode, held_mode_column


@pytest.mark.parametrize("f_hz, zeta", [(41.5, 0.01), (69.5, 0.007), (358.9, 0.018)])
def test_the_direct_paths_are_the_first_and_zero_order_holds(f_hz, zeta):
    """``HeldDrive.direct``: the mode driven along the straight line over the whole sample (``ramp_fraction`` 1) is
    the first-order hold's discretization (the search's own column, ``_foh_mode``); along the step (0), scipy's
    zero-order-hold discretization of ``w^2 / (s^2 + 2 zeta w s + w^2)`` driven by each sample's value held over the
    interval ending at it. Both to 1e-10 of the column, below and above Nyquist (100 Hz sampling)."""
    dt, n = 0.01, 2000
    u = np.cumsum(np.random.default_rng(3521).standard_normal(n))
    u -= u[0]
    lin = held_mode_column(u, HeldDrive.direct(n, dt, 1.0), f_hz, zeta)
    b, a = _foh_mode(f_hz, zeta, dt)
    ref = signal.lfilter(b, a, u) - u
    assert np.max(np.abs(lin - ref)) < 1e-10 * np.max(np.abs(ref))
    stp = held_mode_column(u, HeldDrive.direct(n, dt, 0.0), f_hz, zeta)
    w = 2 * np.pi * f_hz
    bz, az, _ = signal.cont2discrete(([w * w], [1.0, 2 * zeta * w, w * w]), dt, method="zoh")
    # (interval k holds u_k: the standard zero-order hold's input, which holds u_k over the interval after k, led a
    # sample)
    ref = signal.lfilter(np.ravel(bz), az, np.r_[u[1:], u[-1]]) - u
    assert np.max(np.abs(stp - ref)) < 1e-10 * np.max(np.abs(ref))
    for bad in (-0.1, 1.5):
        with pytest.raises(ValueError):
            HeldDrive.direct(n, dt, bad)


@pytest.mark.parametrize("f_hz, zeta", [(41.5, 0.01), (124.0, 0.0075)])
def test_a_ramp_over_the_first_sub_step_is_the_simulator_s_held_command_without_a_resistor(sn637, f_hz, zeta):
    """The simulator's record of a held command with no series resistor (``upsample=1``, ``N_SUB`` sub-steps a
    sample, its input linear over each sub-step) moves the stack along a ramp over the first ``1 / N_SUB`` of each
    sample where the amplifier's current limit moves each step within that sub-step: the mode's motion (the record
    with the mode less the same record without it, noise-free) is ``held_mode_column`` along
    ``HeldDrive.direct(..., 1 / N_SUB)`` of the motion without it, to 1e-6 of its size; the step's and the straight
    line's are off by more than a tenth. The benchmark's steps protocol scaled so its largest step takes 0.9 of
    the charge the limit moves in a sub-step (``C_max |dv| <= 0.9 I h``, C_max the terminal's largest capacitance).
    At full size its steps slew at the limit over several sub-steps (session 37: the simulator applies the limit
    with R out), and the first sub-step's ramp is off by more than a tenth too."""
    from workbench.calibrate.synthetic import N_SUB, SensorNoise, benchmark_protocol, simulate_record
    from workbench.plant.additions import Additions
    from workbench.plant.pzt import Mode
    rate = 100.0
    t, v_full = benchmark_protocol("steps", rate, 1500)
    pz = dataclasses.replace(sn637.pzt, creep=None, modes=(Mode(f_hz, zeta),), series_resistance_ohm=0.0)
    h = 1.0 / rate / N_SUB
    c_max = 1.0 / np.cumsum(pz.terminal_operator().weights).min()
    dv = np.diff(v_full)
    scale = 0.9 * min(pz.current_limit_source_a * h / (c_max * dv.max()),
                      pz.current_limit_sink_a * h / (c_max * -dv.min()))
    quiet = dict(noise=SensorNoise(0.0, 0.0, 0.0), gauge=False)
    for v, within in ((v_full * scale, True), (v_full, False)):
        x = simulate_record(dataclasses.replace(sn637, pzt=pz, additions=Additions()), t, v, **quiet)["x_true_m"]
        x0 = simulate_record(dataclasses.replace(sn637, pzt=dataclasses.replace(pz, modes=()), additions=Additions()),
                             t, v, **quiet)["x_true_m"]
        err = {}
        for a in (1.0 / N_SUB, 0.0, 1.0):
            col = held_mode_column(x0, HeldDrive.direct(t.size, 1.0 / rate, a), f_hz, zeta)
            err[a] = np.max(np.abs(x - x0 - col)) / np.max(np.abs(x - x0))
        if within:
            assert err[1.0 / N_SUB] < 1e-6, err
        else:
            assert err[1.0 / N_SUB] > 0.1, err
        assert err[0.0] > 0.1 and err[1.0] > 0.1, err


def _r_out_trace(plant0, protocol, f_hz, zeta, seed, hold):
    """A 100 Hz record of the benchmark's protocol, one mode, no series resistor; the command between samples a
    straight line (``hold="linear"``), held (``"held"``, the simulator's own: a slew over the first quarter of the
    sample) or slewing over a third of it (``"slew3"``, a path between :data:`DIRECT_RAMP_FRACTIONS`' 1/4 and 3/8).
    The tracing's result."""
    from workbench.calibrate.base_fit import fit_base
    from workbench.calibrate.splits import make_split
    from workbench.calibrate.synthetic import benchmark_protocol, simulate_record
    from workbench.calibrate.tracing import trace_effect
    from workbench.plant.additions import Additions
    from workbench.plant.pzt import Mode
    cc = load_benchmark("calibrate_confusion")
    rate = 100.0
    t, v = benchmark_protocol(protocol, rate, cc.ROWS[rate])
    pz = dataclasses.replace(plant0.pzt, creep=None, modes=(Mode(f_hz, zeta),), series_resistance_ohm=0.0)
    plant = dataclasses.replace(plant0, pzt=pz, additions=Additions())
    kw = {"n_sub": 3} if hold == "slew3" else {}          # a slew over a third of the sample: off the path grid
    if hold == "limit":
        # the amplifier at its declared current limit: the command slewed at most I_max / C_min a sample, each step a
        # ramp at that slew, then held (written before session 37, when the simulator did not apply the limit with R
        # out; it does now, so where the terminal's capacitance exceeds C_min the stack lags this path at I / C)
        slew = (pz.current_limit_source_a / pz.min_capacitance_f, pz.current_limit_sink_a / pz.min_capacitance_f)
        dt = 1.0 / rate
        lim = np.empty_like(v)
        lim[0] = v[0]
        for k in range(1, v.size):
            lim[k] = lim[k - 1] + np.clip(v[k] - lim[k - 1], -slew[1] * dt, slew[0] * dt)
        v = lim
        kw = {"held": _LimitPath(v, dt, slew), "upsample": 32}
    r = simulate_record(plant, t, v, seed=seed, **({"upsample": 8 if hold == "linear" else 1} | kw))
    sp = make_split(t, r["voltage_v"], "blocks")
    base = fit_base(cc._record(r, 1.0 / rate), 0.0, train=sp.train, test=sp.test, pzt=plant.pzt,
                    dac_range_v=plant.gauge.dac_range_v)
    return trace_effect(base, split=sp)


class _LimitPath:
    """The path of a voltage slewed at the current limit: each sample's step a ramp at the limit's slew, then held
    (the ``held=`` path of :func:`~workbench.calibrate.synthetic.simulate_record`; the second review of s36_rout)."""

    def __init__(self, v, dt, slew):
        dv = np.diff(np.asarray(v, float), prepend=v[0])
        self.a = np.clip(np.abs(dv) / (np.where(dv > 0, slew[0], slew[1]) * dt), 1e-9, 1.0)
        self.dt = dt

    def path(self, s, rows=slice(None)):
        return np.clip(np.asarray(s, float)[None, :] / (self.a[rows][:, None] * self.dt), 0.0, 1.0)


# single modes 30-700 Hz log-uniform (the review's range: below and far above the 50 Hz Nyquist frequency), the
# benchmark's damping range, the three protocols in turn, the straight line and the held command alternately;
# default_rng(3522), drawn before the rule was run on any. Measured (2026-11-28, s35_rout): none written at a
# wrong frequency; the second (124.0 Hz, held command) was written at 23.85 Hz by a rule tried and withdrawn (only
# the step and the straight line tested, and a member whose straight-line column needed a gain of 4.85 dropped as
# no stack mode's: the held command's path is neither). make test runs that one (~4.5 s), WORKBENCH_FULL=1 all
# twelve
_RNG = np.random.default_rng(3522)
_DRAWS = [(("sine", "calibration", "steps")[k % 3], float(np.exp(_RNG.uniform(np.log(30.0), np.log(700.0)))),
           float(_RNG.uniform(0.005, 0.02)), int(_RNG.integers(1 << 30)), ("linear", "held")[k % 2]) for k in range(12)]
# and four more on a slew over a third of the sample, a path the grid does not hold (review of s35_rout, S2),
# default_rng(3524), drawn before run: full form only (measured: none written at a wrong frequency)
_RNG3 = np.random.default_rng(3524)
_DRAWS += [(("sine", "calibration", "steps")[k % 3], float(np.exp(_RNG3.uniform(np.log(30.0), np.log(700.0)))),
            float(_RNG3.uniform(0.005, 0.02)), int(_RNG3.integers(1 << 30)), "slew3") for k in range(4)]
DRAWS = reduced_draws(_DRAWS, keep=(1,))


@pytest.mark.slow
@pytest.mark.parametrize("protocol, f_hz, zeta, seed, hold", DRAWS)
def test_a_mode_on_a_record_without_a_resistor_is_written_at_its_frequency_or_not_at_all(sn637, protocol, f_hz, zeta,
                                                                                         seed, hold):
    """Whatever a 100 Hz record without a series resistor names, the mode the plant file carries (``unplaced_modes``
    leaves out what the folds do not place) is the drawn one, within a quarter of its half-power bandwidth ``2 zeta
    f``; every mode named carries its alias family, and one left out says why in its note. The truth is the draw's."""
    from workbench.calibrate.plant_update import unplaced_modes
    res = _r_out_trace(sn637, protocol, f_hz, zeta, seed, hold)
    un = unplaced_modes(res["stages"])
    for st in res["stages"]:
        if st["effect"] != "resonance":
            continue
        assert st.get("alias_family") is not None, st
        if (st["effect"], st["channel"]) in un:
            assert "not placed" in st["note"] and st["note"] == st["alias_family"]["note"]
        else:
            assert abs(st["parameters"]["f_n_hz"] - f_hz) < 0.25 * 2 * zeta * f_hz, (st["parameters"], f_hz)


def test_a_ramp_excites_a_mode_by_the_sinc_of_its_length():
    """``direct_image_reach``'s premise: a drive step moved along a ramp over ``a dt`` rings a mode at ``f`` by
    ``|sinc(pi f a dt)|`` of what a step rings (the exact held column of one step, 100 Hz sampling, modes below and
    far above Nyquist, ramps on and off the path grid); so at the reach a mode whose share is the band's top rings
    at the alias with the band's floor, and a step (``a = 0``) reaches every frequency."""
    from workbench.calibrate.tracing import MODE_GAIN_BAND, direct_image_reach
    dt, n = 0.01, 400
    u = np.zeros(n)
    u[50:] = 1.0

    def ring(f, a):
        col = held_mode_column(u, HeldDrive.direct(n, dt, a), f, 1e-6)[60:]   # after the ramp: the free ring
        tk = dt * np.arange(col.size)
        w = 2 * np.pi * f * np.sqrt(1 - 1e-12)
        basis = np.exp(-1e-6 * 2 * np.pi * f * tk)[:, None] * np.c_[np.cos(w * tk), np.sin(w * tk)]
        return np.hypot(*np.linalg.lstsq(basis, col, rcond=None)[0])             # its amplitude
    for f in (23.0, 130.0, 635.9):
        for a in (1.0 / 16, 1.0 / 3, 0.5, 1.0):
            assert ring(f, a) / ring(f, 0.0) == pytest.approx(abs(np.sinc(f * a * dt)), abs=1e-5), (f, a)
    band = (MODE_GAIN_BAND[0], 1.0)
    assert direct_image_reach(36.1, 0.0, dt, band) == np.inf
    for f0, a in ((36.1, 1.0 / 8), (12.0, 1.0), (45.0, 0.25)):
        f = direct_image_reach(f0, a, dt, band)
        envelope = 1.0 / (np.pi * f * a * dt)                     # |sinc| at its lobes' peaks
        assert band[1] * envelope / abs(np.sinc(f0 * a * dt)) == pytest.approx(band[0], rel=1e-9)



def test_the_current_limit_bounds_how_far_a_record_s_steps_ring_an_image():
    """``direct_slew_reach``: a step ``dv`` the amplifier moves at most ``slew`` V/s takes at least
    ``a = dv / (slew dt)`` of its sample, so (the sinc premise above) a record of such steps rings a mode at ``f``
    by at most ``1 / (pi f a dt)``: its reach is the ramp's own (:func:`direct_image_reach`, a record of one step
    size, sinks and sources alike); a record with a step the limit cannot move in a sample is not bounded by it (the
    declared limit does not describe the record), nor is one whose plant declares no limit."""
    from workbench.calibrate.tracing import MODE_GAIN_BAND, direct_image_reach, direct_slew_reach
    rng = np.random.default_rng(3661)
    dt, band = 1e-3, (MODE_GAIN_BAND[0], 1.0)
    slew = (333.3, 2333.3)                                        # V/s: 2 mA up, 14 mA down over 6 uF
    for a in (0.1, 0.5, 1.0):
        signs = rng.choice([-1.0, 1.0], 500)
        dv = np.where(signs > 0, slew[0], slew[1]) * a * dt * signs
        v = np.r_[0.0, np.cumsum(dv)]
        for f0 in (37.0, 210.0, 480.0):
            got = direct_slew_reach(f0, dt, band, v, slew, (a,))
            assert got["steps_over"] == 0
            want = direct_image_reach(f0, a, dt, band)
            assert got["reach_hz"] == pytest.approx(max(want, 0.5 / dt), rel=1e-6), (a, f0)
    v = np.r_[0.0, np.cumsum(np.full(200, 0.2))]
    v[120:] += 5.0                                                # 5 V in a sample: 15 ms at 333 V/s
    got = direct_slew_reach(100.0, dt, band, v, slew)
    assert got["steps_over"] == 1 and got["reach_hz"] == np.inf
    assert direct_slew_reach(100.0, dt, band, v[:100], None)["reach_hz"] == np.inf
    # a long record slewing at the limit with white noise on its logged voltage is the amplifier's (noise alone does
    # not exceed it); a step 0.1 V over the limit, ten times the noise, is not
    ramp = np.r_[np.linspace(0.0, 100.0, 301), np.linspace(100.0, 0.0, 44)[1:]]     # at the limit up and down
    clean = np.tile(np.r_[ramp, np.zeros(100)], 25)
    assert np.abs(np.diff(clean)).max() == pytest.approx(slew[1] * dt, rel=1e-2)
    for seed in range(3):
        noisy = clean + np.random.default_rng(seed).normal(0.0, 0.01, clean.size)
        assert direct_slew_reach(100.0, dt, band, noisy, slew)["steps_over"] == 0
        bad = noisy.copy()
        bad[10 * 444 + 150:] += 0.1                                # inside a rise at the limit
        assert direct_slew_reach(100.0, dt, band, bad, slew)["steps_over"] >= 1


# modes below the Nyquist frequency on the straight-line drive (where the record tells a mode from its images: each
# image's column fits the ring only with a negative gain or one no stack mode takes), 20-45 Hz log-uniform, the
# three protocols in turn; default_rng(3523), drawn before the rule was run on any. Measured: the four calibration
# and steps draws placed at their frequency; the two under the sine protocol name no mode at all (main alike): a
# detection miss, not a placement, kept as strict xfails; the fourth (43.64 Hz) is left out by the image-reach rule
# since 2026-11-28 (measured after the rule was written: a miss, kept as a strict xfail). Full form only (4.5-7.9 s each; review of s35_rout, S3):
# make test's guard of the same code is the 124 Hz draw above (alias_family through direct_drives) and the gain
# band's test below (its top); what only these draws catch is a placed mode lost
_RNG2 = np.random.default_rng(3523)
_BELOW = [(("calibration", "steps", "sine")[k % 3], float(np.exp(_RNG2.uniform(np.log(20.0), np.log(45.0)))),
           float(_RNG2.uniform(0.005, 0.02)), int(_RNG2.integers(1 << 30))) for k in range(6)]
_SINE_NONE = pytest.mark.xfail(strict=True, reason="the 100 Hz sine record names no mode (none on 5 of 5 folds; main "
                                                   "alike): not named, so not placed")
_REACH = pytest.mark.xfail(strict=True, reason="a miss of the image-reach rule (review of s35_rout, X1): named at its "
                                               "frequency on every test, left out because its images at 243.6 / 256.4 "
                                               "Hz lie beyond the family tested (200 Hz) and within the reach its decay "
                                               "allows (265.8 Hz at zeta >= 0.002)")
# Since session 37 the simulator applies the amplifier's current limit without a resistor: the straight line
# between samples (upsample 8) is followed only where its slope is within I / C; the calibration and steps
# protocols' fast segments slew at the limit, a ramp over the whole sample while it lasts, a part of the arrival's,
# none while held, so no single path of the family fits every sample. Measured (2026-11-29, s37_rlimit): the
# 42.02 Hz calibration draw, placed at its frequency before, is named at 41.94 Hz and not placed (its family
# resolved on 0 of 5 folds); the 36.12 Hz steps draw, placed before, is named at 36.15 Hz and not placed (gain
# 1.41 +/- 0.04 outside the stack's band 0.81-1.27). Nothing is written at a wrong frequency (the draws above all
# pass); a detection miss, kept as strict xfails
_SLEWED = {0: "42.02 Hz named at 41.94 Hz, its alias family resolved on 0 of 5 folds",
           4: "36.12 Hz named at 36.15 Hz with gain 1.41 +/- 0.04, outside the stack's band 0.81-1.27"}


def _slewed(k):
    return pytest.mark.xfail(strict=True, reason=f"a miss since session 37 (the current limit slews the drive "
                                                 f"between samples, no single direct path fits): {_SLEWED[k]}; not "
                                                 f"placed, not written")


BELOW = reduced_draws([pytest.param(*d, marks=[_SINE_NONE]) if d[0] == "sine"
                       else pytest.param(*d, marks=[_REACH]) if k == 3
                       else pytest.param(*d, marks=[_slewed(k)]) if k in _SLEWED else d
                       for k, d in enumerate(_BELOW)], keep=())


@pytest.mark.slow
@pytest.mark.parametrize("protocol, f_hz, zeta, seed", BELOW)
def test_a_mode_below_nyquist_on_a_straight_line_drive_is_placed(sn637, protocol, f_hz, zeta, seed):
    """A mode below Nyquist under a sampled smooth drive without a resistor (the simulator's default noise) is
    named, placed in its alias family and written at its frequency (a quarter of its half-power bandwidth)."""
    from workbench.calibrate.plant_update import unplaced_modes
    res = _r_out_trace(sn637, protocol, f_hz, zeta, seed, "linear")
    modes = [st for st in res["stages"] if st["effect"] == "resonance"]
    assert modes, (res["effect"], res.get("fold_winners"))
    st = modes[0]
    assert (st["effect"], st["channel"]) not in unplaced_modes(res["stages"]), st.get("note")
    assert abs(st["parameters"]["f_n_hz"] - f_hz) < 0.25 * 2 * zeta * f_hz, (st["parameters"], f_hz)


def test_the_gain_band_of_a_record_without_a_resistor_is_read_at_the_tip_with_a_tolerance_above_one():
    """The sensor reads the stack's tip: a uniform rod fixed at one end, its static motion under a uniform strain
    expanded in its modes ``sin((2n - 1) pi xi / 2)`` (by quadrature, not the closed form), the first mode's share at
    the tip is ``8 / pi^2`` (``MODE_GAIN_BAND``'s floor) and the modes' shares there sum to one (its top), so the top
    of a record without a resistor's band above one (``MODE_GAIN_READ_TOP``) is a tolerance on the column's model
    error, not a share: the band's test (the folds' mean within two jackknife errors) takes it as the top."""
    from scipy.integrate import trapezoid as _trapezoid
    from workbench.calibrate.tracing import MODE_GAIN_BAND, MODE_GAIN_READ_TOP, gain_is_a_modes
    xi = np.linspace(0.0, 1.0, 40_001)
    shares = []
    for n in range(1, 201):
        phi = np.sin((2 * n - 1) * np.pi * xi / 2)
        shares.append(_trapezoid(xi * phi, xi) / _trapezoid(phi * phi, xi) * phi[-1])
    assert shares[0] == pytest.approx(MODE_GAIN_BAND[0], rel=1e-6)
    assert sum(shares) == pytest.approx(MODE_GAIN_BAND[1], abs=2e-3)     # the tail past 200 modes: ~1e-3
    assert MODE_GAIN_READ_TOP > MODE_GAIN_BAND[1]
    band = (MODE_GAIN_BAND[0], MODE_GAIN_READ_TOP)
    rng = np.random.default_rng(3662)
    assert gain_is_a_modes(rng.uniform(*band, 5), band)[0]
    assert not gain_is_a_modes(MODE_GAIN_READ_TOP + 0.05 + rng.normal(0.0, 0.001, 5), band)[0]


# modes just above two and one sample rates on a current-limited steps record at 100 Hz (the second review of
# s36_rout, G1, default_rng(3691)'s 118 and 128 Hz): their images fold from above into the band at a small positive
# gain (0.14-0.16), which the current-limit gate let skip the family test and pass as placed, written at 17.9 and
# 27.3 Hz; the gate now asks the band's floor of the named gain
# (make test runs the 128 Hz one, ~4.5 s; WORKBENCH_FULL=1 both)
@pytest.mark.parametrize("f_hz, zeta, seed", reduced_draws([(118.0, 0.005, 5), (128.0, 0.015, 6)], keep=(1,)))
def test_an_image_from_above_on_a_current_limited_record_is_not_written(sn637, f_hz, zeta, seed):
    from workbench.calibrate.plant_update import unplaced_modes
    res = _r_out_trace(sn637, "steps", f_hz, zeta, seed, "limit")
    un = unplaced_modes(res["stages"])
    for st in res["stages"]:
        if st["effect"] == "resonance" and (st["effect"], st["channel"]) not in un:
            assert abs(st["parameters"]["f_n_hz"] - f_hz) < 0.25 * 2 * zeta * f_hz, (st["parameters"], f_hz)
