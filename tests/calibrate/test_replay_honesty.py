"""s22_outsider C1/C2: the updated plant file carries a stage only where its written form replays the development
rows closer, a bow is written about rest (the file's reference), the file's replay above the error before is a
top-level warning, and the named effect's folds are counted per channel.

Constructed results and stages (no record) but for the FULL-only record test at the end.
"""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tests.conftest import FULL
from workbench.calibrate import plant_update
from workbench.calibrate.plant_update import (bow_about_rest, carried_stages, declared_core, plant_file_gaps,
                                              replay_above_before_warning, updated_plant_text)
from workbench.calibrate.run import agreement_counts
from workbench.plant import load_plant
from workbench.plant.additions import gauge_bow

PLANTS = Path(__file__).resolve().parents[2] / "plants"
SN637 = PLANTS / "p888_51_sn637.toml"


def _base(x, offset=0.0, gauge=False):
    """A base fit's stand-in: a displacement channel recorded as ``x + offset`` (m), every row valid."""
    n = x.size
    ch = {"displacement": SimpleNamespace(y=x + offset, valid=np.ones(n, bool), offset=offset, units="m")}
    if gauge:
        ch["gauge"] = SimpleNamespace(y=np.zeros(n), valid=np.ones(n, bool), offset=0.0, units="V")
    return SimpleNamespace(channels=ch, t=np.arange(n) * 1e-3, v_drive=np.linspace(0.0, 100.0, n),
                           starts_from_rest=True, input_kind="terminal", train=np.arange(n) % 2 == 0)


def _result(stages):
    err = {"rms": 1e-8, "max": 3e-8, "units": "m"}
    return {"effect": stages[0]["effect"], "channel": stages[0]["channel"], "parameters": stages[0]["parameters"],
            "error_before": err, "error_after": err, "stages": stages, "core_fit": None}


def _written_bow(text):
    lines = [ln for ln in text.splitlines() if ln.startswith("coefficient_per_m")]
    return float(lines[0].split("=")[1].split("#")[0]) if lines else None


def test_a_bow_is_written_about_rest_the_file_reading_the_gauge_the_tracing_fitted(tmp_path):
    """The tracing fits ``d / (1 + b' d)`` about the record's mean displacement ``x_ref`` (the gain in the refitted
    gauge line); the file's bow is ``x / (1 + b x)`` about rest (``additions.gauge_bow``, as the simulator reads it).
    The coefficient written must make the file's map the tracing's up to a gain and an offset (what the gauge's
    line carries): an exact identity for ``b = b' / (1 - b' x0)``, ``x0`` the reference from rest (``x_ref`` less
    the displacement's zero). On main ``b'`` itself was written: the maps differ by a share of the bow's curvature
    (7.6 % of it), far above the rounding asserted."""
    x = np.linspace(0.0, 8e-6, 801)
    offset = 1.5e-6                                    # the displacement sensor's zero: x_ref is in its units
    x0 = 3e-6
    bp = -2.0e4
    p = {"coefficient_per_m": bp, "x_ref": x0 + offset, "c0": 0.0, "c1": 0.0, "c2": 1.0}
    base = _base(x, offset)
    plant = load_plant(SN637)
    text = updated_plant_text(SN637, plant, base, _result([{"effect": "gauge_nonlinearity", "channel": "gauge",
                                                            "parameters": p}]), tmp_path / "r.csv",
                              core=declared_core("test"))
    b = _written_bow(text)
    assert b is not None
    d = x - x0
    tracing = d / (1.0 + bp * d)
    file_map = gauge_bow(x, b, x_ref_m=0.0)
    A = np.column_stack([tracing, np.ones_like(x)])
    coef, *_ = np.linalg.lstsq(A, file_map, rcond=None)
    left = file_map - A @ coef
    # the bow's own curvature over the motion: what a wrong coefficient leaves is a share of it
    bow = tracing - np.polyval(np.polyfit(x, tracing, 1), x)
    assert float(np.max(np.abs(left))) < 1e-6 * float(np.max(np.abs(bow))), (b, float(np.max(np.abs(left))))
    assert b == pytest.approx(bp / (1.0 - bp * x0), rel=1e-12)


def test_a_bow_whose_pole_lies_within_the_motion_is_not_written_and_the_gap_says_why(tmp_path):
    """A bow ``x / (1 + b x)`` whose pole ``x = -1/b`` lies within the record's motion is no gauge map (it folds
    over there): the tracing's quadratic is then no bow the file holds. -8e4 /m about a 3 um mean is -6.45e4 /m
    about rest, within the loader's +-1e5 /m (main wrote it), with its pole at 15.5 um inside the 18 um motion."""
    x = np.linspace(0.0, 18e-6, 181)
    p = {"coefficient_per_m": -8.0e4, "x_ref": 3e-6, "c0": 0.0, "c1": 0.0, "c2": 1.0}
    base = _base(x)
    b, why = bow_about_rest(p, base)
    assert b == pytest.approx(-8.0e4 / (1 + 8.0e4 * 3e-6), rel=1e-12)
    assert why is not None and "pole" in why
    plant = load_plant(SN637)
    stages = [{"effect": "gauge_nonlinearity", "channel": "gauge", "parameters": p}]
    text = updated_plant_text(SN637, plant, base, _result(stages), tmp_path / "r.csv", core=declared_core("test"))
    assert "[gauge_nonlinearity]" not in text
    gaps = plant_file_gaps(stages, base, plant)
    assert any("gauge bow" in g and "pole" in g for g in gaps), gaps
    # the same bow over a motion that stays short of the pole is written
    short = _base(np.linspace(0.0, 12e-6, 121))
    assert bow_about_rest(p, short)[1] is None


@pytest.mark.parametrize("helps", [True, False])
def test_a_stage_is_written_only_where_its_form_replays_the_development_rows_closer(tmp_path, monkeypatch, helps):
    """``carried_stages`` replays the file with and without each stage on the development rows: a mode whose file
    form makes the replay worse there (s22_outsider A1: a triangle's 'mode', the file 36x the error before) is
    left out and the file's header says so; one that makes it closer is kept. The replay is stood in for by the
    record plus a misfit that the written mode removes (``helps``) or adds."""
    n = 400
    x = np.sin(np.linspace(0.0, 6.0, n)) * 1e-6
    base = _base(x)
    p = {"f_n_hz": 5.29, "zeta": 0.04, "gain": 0.016}
    result = _result([{"effect": "resonance", "channel": "displacement", "parameters": p}])
    misfit = 1e-8 * np.cos(np.linspace(0.0, 40.0, n))

    def fake_replay(plant, base_, channel):
        has = any(abs(float(m.freq_hz) - 5.29) < 1e-6 for m in plant.pzt.modes)
        return base_.channels[channel].y + (misfit if has != helps else 0.0)
    monkeypatch.setattr(plant_update, "_replay", fake_replay)
    plant = load_plant(SN637)
    core = declared_core("test")
    omit, carried = carried_stages(SN637, plant, base, result, tmp_path / "r.csv", core, base.train)
    assert [c["written"] for c in carried] == [helps]
    dev = carried[0]["development_rms"]
    assert (dev["with"] < dev["without"]) == helps
    text = updated_plant_text(SN637, plant, base, result, tmp_path / "r.csv", core=core, omit=omit)
    assert ("freq_hz = 5.29" in text) == helps
    if not helps:
        assert ("resonance", "displacement") in omit
        assert "# The resonance found on the displacement is not written" in text


def test_overlapping_stages_keep_the_named_effect_the_later_one_judged_first(tmp_path, monkeypatch):
    """Two written forms that take the same misfit (review of s23_replay): the mode alone leaves 1 % of it, the
    delay alone 5 %, both together 6 %, neither 100 %. Judged first to last the mode (the named effect) was dropped
    against the file holding the delay (6 % against 5 %) and the file kept the delay; judged last to first the
    delay goes (6 % against the mode alone's 1 %) and the mode stays (1 % against 100 %)."""
    n = 400
    x = np.sin(np.linspace(0.0, 6.0, n)) * 1e-6
    base = _base(x)
    mode = {"effect": "resonance", "channel": "displacement", "parameters": {"f_n_hz": 5.29, "zeta": 0.04, "gain": 0.016}}
    delay = {"effect": "delay", "channel": "displacement", "parameters": {"delay_s": 2e-4}}
    result = _result([mode, delay])
    misfit = 1e-8 * np.cos(np.linspace(0.0, 40.0, n))
    left = {(True, True): 0.06, (True, False): 0.01, (False, True): 0.05, (False, False): 1.0}

    def fake_replay(plant, base_, channel):
        has_mode = any(abs(float(m.freq_hz) - 5.29) < 1e-6 for m in plant.pzt.modes)
        has_delay = bool(getattr(plant.additions, "sensor_delay_s", 0))
        return base_.channels[channel].y + left[(has_mode, has_delay)] * misfit
    monkeypatch.setattr(plant_update, "_replay", fake_replay)
    plant = load_plant(SN637)
    omit, carried = carried_stages(SN637, plant, base, result, tmp_path / "r.csv", declared_core("test"), base.train)
    assert {c["effect"]: c["written"] for c in carried} == {"resonance": True, "delay": False}, carried
    assert set(omit) == {("delay", "displacement")}


def test_the_replay_above_the_error_before_is_a_top_level_warning():
    """The file's replay (``error_after``, source "updated plant") above ``error_before``: a warning naming both
    figures, what the file carries and what it does not; none at or below. With no file replayed the reported
    ``error_after`` is the tracing model's: above ``error_before`` it is said with the reason no file was replayed
    (s22_outsider A4: a generic stack's drift over the predicted cycles, 654x)."""
    eb = {"rms": 1.0e-8, "max": 3e-8, "units": "m"}
    carried = [{"effect": "creep", "channel": "gauge", "written": False, "reason": "no plant-file form"}]
    w = replay_above_before_warning(eb, {"rms": 2.15e-8, "max": 5e-8, "units": "m"}, "updated plant", carried)
    assert w is not None and "2.15x" in w and "creep on the gauge (no plant-file form)" in w
    assert replay_above_before_warning(eb, {"rms": 0.9e-8, "max": 3e-8, "units": "m"}, "updated plant", carried) is None
    # no file replayed (a generic stack, an amplifier command): the tracing model's error_after above is said too
    w = replay_above_before_warning(eb, {"rms": 6.54e-6, "max": 3e-5, "units": "m"}, "tracing model", (),
                                    no_replay="a generic stack's plant file has no simulator: no replay")
    assert w is not None and "654.00x" in w and "the tracing model's (no plant file replayed: a generic stack" in w
    assert replay_above_before_warning(eb, {"rms": 0.5e-8, "max": 3e-8, "units": "m"}, "tracing model", ()) is None


def test_the_agreement_is_counted_per_channel():
    """s22_outsider C2: creep named on the gauge with 1 fold of its own and 3 on the displacement's view of the same
    motion read "1 of 5"; the counts say both."""
    winners = ["creep on the gauge", "creep on the displacement", "creep on the displacement",
               "creep on the displacement", "none"]
    c = agreement_counts("creep", "gauge", winners, [{"agreement": "1 of 5", "agreement_compatible": 4}])
    assert c["named_view"] == "1 of 5" and c["any_channel"] == "4 of 5"
    assert c["by_channel"] == {"gauge": 1, "displacement": 3} and c["compatible"] == "4 of 5"
    assert agreement_counts("none", "displacement", winners, []) is None


@pytest.mark.skipif(not FULL, reason="a record calibrated end to end (~15 s): WORKBENCH_FULL=1 runs it")
def test_a_triangles_mode_whose_file_replays_worse_is_not_written(tmp_path):
    """s22_outsider A1 (``benchmarks/outsider/repro_triangle_resonance.py``, 2.5 kHz, 0.5 Hz, 10 s, seed 1): a clean
    triangle named a resonance; its mode in the file replayed the test rows at 36x the error before. The file
    made by the declared plant leaves the noise: with the mode left out (its form replays the development rows
    worse) the reported error_after is below error_before, and no warning is due."""
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks" / "outsider"))
    from harness import calibrate, simulate, triangle
    t, v = triangle(2.5e3, 10.0, 0.5)
    r, _ = simulate(load_plant(SN637), "none", t, v, 1, 1.0)
    res = calibrate(r, str(SN637), "tri_honesty")
    assert "error" not in res, res
    if res["effect"] in ("none", "inconclusive"):
        # with s23_triangle's declared thresholds in the base (a branch, not main) the clean triangle is answered
        # none: nothing is written and the record does not reach the rule (the constructed tests above do)
        pytest.skip(f"the record is answered {res['effect']}: no stage to carry")
    assert res["error_after_source"] == "updated plant"
    assert res["error_after"]["rms"] <= res["error_before"]["rms"], (res["error_after"], res["error_before"])
    # the file is not above the error before, so the one warning is that the named mode is not in the file
    # (the lead's fix after the review of s23_replay: said beside the answer)
    # (the base fit's own warnings are also in ``warnings`` since session 33: not counted here)
    own = [w for w in res["warnings"] if w not in (res.get("base_fit") or {}).get("warnings", ())]
    assert len(own) == 1 and "resonance named on the displacement is not in the updated plant file" \
        in own[0], res["warnings"]
    modes = [c for c in res["updated_plant_stages"] if c["effect"] == "resonance"]
    assert modes and not modes[0]["written"]


def test_the_cli_prints_the_replay_warning_at_the_top_and_the_folds_per_channel(tmp_path, capsys, monkeypatch):
    """s22_outsider C1/C2 at the CLI: the file's replay above the error before is printed as a WARNING beside the
    answer (not only among the base's warnings, after the candidates), and a named effect's folds on the other
    channel are said beside its own "1 of 5"."""
    import workbench.calibrate.run as run
    from workbench.cli import main
    eb = {"rms": 1e-8, "max": 3e-8, "units": "m"}
    ea = {"rms": 2.15e-8, "max": 5e-8, "units": "m"}
    warning = replay_above_before_warning(eb, ea, "updated plant", [
        {"effect": "creep", "channel": "gauge", "written": False, "reason": "no plant-file form"}])
    winners = ["creep on the gauge"] + ["creep on the displacement"] * 3 + ["none"]
    st = {"effect": "creep", "channel": "gauge", "agreement": "1 of 5", "error_before": eb, "error_after": eb}
    data = {"effect": "creep", "channel": "gauge", "agreement": "1 of 5", "error_before": eb, "error_after": ea,
            "error_after_model": eb, "error_after_source": "updated plant", "stages": [st], "reason": "wins",
            "agreement_counts": agreement_counts("creep", "gauge", winners, [st]), "candidates": [],
            "base_fit": {"warnings": []}, "warnings": [warning], "elapsed_s": 1.0}
    monkeypatch.setattr(run, "run_calibrate", lambda *a, **k: data)
    rec = tmp_path / "r.csv"
    rec.write_text("time[s],voltage[V],displacement[m]\n" + "".join(f"{k * 1e-3},{k % 50},{k % 50}e-7\n"
                                                                     for k in range(200)))
    assert main(["calibrate", str(rec), "--plant", str(SN637)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "1 of 5 validation folds on the gauge; the creep on the displacement won 3 more" in out[0], out[0]
    assert out[2].startswith("  WARNING: the updated plant file replays the test rows at 2.15e-08 m RMS, 2.15x"), out
