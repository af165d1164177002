"""The plant family, its nominal and the W_m cover (reduced grid; the CLI runs the full one)."""

import numpy as np
import pytest

from workbench.linearize.uncertainty import FamilySpec, plant_family, uncertainty_bound
from workbench.plant import load_plant

SPEC = FamilySpec(amplitudes_v=(0.1, 3.0, 30.0), freq_hz=tuple(np.geomspace(0.5, 3000.0, 9)),
                  small_signal_biases_v=(50.0,))


@pytest.fixture(scope="module")
def bound(root):
    plants = [load_plant(root / "plants" / f"p888_51_{s}.toml") for s in ("sn637", "sn618")]
    fam = plant_family(plants, SPEC)
    return plants, fam, uncertainty_bound(fam, plants[0])


def test_every_member_lies_inside_the_cover(bound):
    _, fam, ub = bound
    w = np.abs(np.array([complex(np.squeeze(ub.fit.weight(2j * np.pi * f))) for f in fam.freq_hz]))
    for name, d in ub.deltas.items():
        assert np.all(np.abs(d) <= w * (1 + 1e-9)), name
    assert ub.coverage.covered and ub.coverage.margin_db == pytest.approx(0.5, abs=1e-6)
    assert ub.coverage.member in ub.deltas
    # the member that sets the margin touches the weight (less the 0.5 dB guard) where reported
    k = int(np.argmin(np.abs(fam.freq_hz - ub.coverage.freq_hz)))
    assert abs(ub.deltas[ub.coverage.member][k]) * 10 ** (0.5 / 20) == pytest.approx(w[k], rel=1e-6)


def test_weight_is_stable_minimum_phase_and_low_order(bound):
    _, _, ub = bound
    assert ub.fit.order <= 3
    assert np.all(ub.fit.weight.poles().real < 0) and np.all(ub.fit.weight.zeros().real < 0)


def test_family_spans_serials_tolerances_and_leaves_slewing_out(bound):
    plants, fam, ub = bound
    # 2 serials x 3 C_p corners x (3 amplitudes + 4 branches) x 2 gauge extremes
    assert len(fam.members) == 2 * 3 * (3 + 4) * 2
    assert fam.excluded_points > 0                           # 30 V slews above ~1 Hz
    big = [d for n, d in ub.deltas.items() if "DF A=30 V" in n]
    assert all(d[-1] == 0 for d in big)                      # not in the family at 3 kHz
    # the gauge gains differ by serial (each serial's calibration) and barely with x0 and imbalance
    k637, k618 = fam.gauge_gains["SN637"], fam.gauge_gains["SN618"]
    cal = plants[1].gauge.calibration_m_per_v / plants[0].gauge.calibration_m_per_v     # 3.246 / 3.077 um/V
    assert k637[0] / k618[0] == pytest.approx(cal, rel=1e-3)
    assert 0 < (k637[2] - k637[1]) / k637[0] < 1e-2
    # the nominal sits between the reversal and the all-plays slope and is not an end point
    w = plants[0].pzt.hysteresis.weights
    assert w[0] * 1.05 < ub.nominal_capacitance_f < w.sum() * 0.95


def test_nominal_minimizes_the_worst_deviation(bound, root):
    plants, fam, ub = bound
    worst = np.max(ub.envelope)
    for factor in (0.8, 1.25):
        from workbench.linearize.small_signal import small_signal_model
        p = small_signal_model(plants[0].pzt, ub.nominal_capacitance_f * factor)
        g = ub.nominal_gauge_v_per_m * np.array([complex(p(2j * np.pi * f)[0, 0]) for f in fam.freq_hz])
        resp = np.array(list(fam.members.values()))
        other = np.nanmax(np.abs(resp / g - 1))
        assert other > worst


def test_family_on_two_processes_is_the_family_in_one(sn637_creep):
    """The parallel family (one process per serial x C_p case) gives the serial computation's members exactly;
    each member comes back as a python-control FRD on the frequencies where it is in."""
    import control
    from workbench.linearize.uncertainty import FamilySpec, plant_family
    spec = FamilySpec(amplitudes_v=(0.3, 50.0), freq_hz=tuple(np.geomspace(0.1, 3000.0, 7)),
                      small_signal_biases_v=(50.0,))
    one = plant_family([sn637_creep], spec, workers=1)
    two = plant_family([sn637_creep], spec, workers=2)
    assert list(one.members) == list(two.members)
    for name, g in one.members.items():
        np.testing.assert_array_equal(g, two.members[name])
    name = "SN637 C_p x1.00, DF A=50 V, K_g max"
    g = one.members[name]
    assert np.isnan(g).any() and np.isfinite(g).any()            # 50 V slews at the higher frequencies
    frd = one.frd(name)
    assert isinstance(frd, control.FRD)
    np.testing.assert_allclose(frd.omega, 2 * np.pi * one.freq_hz[np.isfinite(g)])
    np.testing.assert_allclose(np.squeeze(frd.frdata), g[np.isfinite(g)])


def test_family_cache_key_follows_files_overrides_and_grid(tmp_path, root):
    from workbench.linearize.uncertainty import FamilySpec
    from workbench.study.cache import cached_family, family_key
    src = (root / "plants" / "p888_51_sn637_creep.toml").read_text()
    plant = tmp_path / "p.toml"
    plant.write_text(src)
    spec = FamilySpec()
    k0 = family_key([plant], {}, spec)
    assert family_key([plant], {}, spec) == k0
    assert family_key([plant], {"electrical.current_limit_source_a": 0.02}, spec) != k0
    assert family_key([plant], {}, FamilySpec(bias_v=40.0)) != k0
    plant.write_text(src.replace("current_limit_sink_a = 14.0e-3", "current_limit_sink_a = 20.0e-3"))
    assert family_key([plant], {}, spec) != k0
    calls = []
    first = cached_family(k0, tmp_path / "c", lambda: calls.append(1) or {"x": np.arange(3)})
    second = cached_family(k0, tmp_path / "c", lambda: calls.append(1) or {"x": None})
    assert calls == [1] and first[2] is False and second[2] is True
    np.testing.assert_array_equal(second[0]["x"], np.arange(3))
    first[1].write_bytes(b"not a pickle")                           # a corrupt entry is recomputed
    third = cached_family(k0, tmp_path / "c", lambda: calls.append(1) or {"x": 7})
    assert third[0] == {"x": 7} and calls == [1, 1]
