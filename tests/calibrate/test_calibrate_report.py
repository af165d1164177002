"""Tests for workbench.report.calibrate_figures and workbench.report.calibrate_report.

One short synthetic record (a sensor latency drawn into SN637, the calibration protocol cut to
11.5 s) is fitted and traced once per module; every test reads those real engine objects. The
'none' case is the same base with the answer forced to ``none`` (no terms). Figures are checked
for existence and content, not for how long they take (no timed tests).
"""

from pathlib import Path

import numpy as np
import pytest

from workbench.calibrate.base_fit import fit_base
from workbench.calibrate.creep_holds import fit_holds
from workbench.calibrate.effects import Delay
from workbench.calibrate.protocol import calibration_protocol
from workbench.calibrate.record import Record
from workbench.calibrate.synthetic import plant_with_effect, simulate_record
from workbench.calibrate.tracing import trace_effect
from workbench.report import calibrate_figures
from workbench.report.calibrate_figures import (MAX_POINTS, calibration_figures, decimate, residual_models,
                                                residual_reports, si_scale)
from workbench.report.calibrate_report import _num, calibration_markdown, parameter_rows

PLANT = Path(__file__).resolve().parents[2] / "plants" / "p888_51_sn637.toml"
PNG = b"\x89PNG\r\n\x1a\n"
ALL = ["overview", "residual", "correlation", "spectrum", "candidates"]


def _with_terms(base, result):
    """The engine's answer when it has terms; else the same dict with a delay fitted by hand.

    The engine is tuned independently: these tests are about the figures and the report, so an
    effect case must exist whatever the tracing decides on this short record.
    """
    if result.get("terms") is not None and result["effect"] != "none":
        return result
    m = base.channels["displacement"]
    test = ~base.train
    eff = Delay(max_delay=50)
    p = eff.fit(base.t, m.yhat, m.residual, base.train, y_model=m.yhat)
    term = eff.term(base.t, m.yhat, p, y_model=m.yhat)
    after = m.residual - term

    def err(e):
        return {"rms": float(np.sqrt(np.mean(e[test] ** 2))), "max": float(np.max(np.abs(e[test]))), "units": "m"}

    return {**result, "effect": "delay", "channel": "displacement", "error_before": err(m.residual),
            "error_after": err(after), "parameters": p, "reason": "fitted by the test (engine said none)",
            "terms": {"channel": "displacement", "base": m.yhat, "term": term}}


@pytest.fixture(scope="module")
def traced(sn637):
    t, v = calibration_protocol(sine_cycles=2, stairs_v=(50.0, 20.0), chirp_s=1.0)
    plant, _ = plant_with_effect(sn637, "delay", 1)
    r = simulate_record(plant, t, v, seed=1)
    rec = Record(Path("x.csv"), {}, r["time_s"],
                 {k: r[k] for k in ("voltage_v", "current_a", "displacement_m", "gauge_v")}, 1e-4)
    base = fit_base(rec, 80.0, pzt=plant.pzt, dac_range_v=2.6)
    result = _with_terms(base, trace_effect(base))
    holds = fit_holds(base.t, base.v_drive, base.channels["displacement"].y, noise_rms=1e-9)
    nan = float("nan")
    holds.append({"start_s": 11.0, "duration_s": 1.2, "voltage_v": 20.0, "step_v": nan, "l0": nan, "gamma": nan,
                  "sigma_l0": nan, "sigma_gamma": nan, "chi2_reduced": nan, "n": 0,
                  "skip_reason": "no constant input before the hold: the step is unknown"})
    return base, result, holds


@pytest.fixture(scope="module")
def none_result(traced):
    _, result, _ = traced
    out = {k: v for k, v in result.items() if k != "terms"}
    out.update(effect="none", parameters={}, reason="forced by the test")
    out["error_after"] = out["error_before"] = out["channels"]["displacement"]
    return out


def _laid_out(fig):
    """``fig``'s faults of layout at its saving resolution: texts out of the canvas, or two axes' texts overlapping
    (each axes' tight box: its tick labels, axis labels, title and legend; a secondary axis is its parent's)."""
    from matplotlib.transforms import Bbox
    fig.set_dpi(120)
    fig.draw_without_rendering()
    r = fig.canvas.get_renderer()
    px = 1.0                                                      # a pixel of antialiasing
    faults = []
    whole = fig.get_tightbbox(r)                                  # inches: every artist, the suptitle too
    w, h = fig.get_size_inches()
    if whole.x0 < -px / 120 or whole.y0 < -px / 120 or whole.x1 > w + px / 120 or whole.y1 > h + px / 120:
        faults.append(f"outside the canvas {w:.2f} x {h:.2f} in: {whole.bounds}")
    boxes = [(i, a.get_tightbbox(r)) for i, a in enumerate(fig.axes)]
    for i, a in boxes:
        for j, b in boxes[i + 1:]:
            inter = Bbox.intersection(a, b)
            if inter is not None and inter.width > px and inter.height > px:
                faults.append(f"axes {i} and {j} overlap by {inter.width:.0f} x {inter.height:.0f} px")
    return faults


LAYOUT_FAULTS = {}          # (folder, figure) -> faults, filled by the ``drawn`` fixture


def _checked_save(fig, path, **kw):
    from workbench.report.output import save_figure
    LAYOUT_FAULTS[Path(path).parent.name, Path(path).name] = _laid_out(fig)
    return save_figure(fig, path, **kw)


@pytest.fixture(scope="module")
def drawn(traced, none_result, tmp_path_factory):
    """Each case's figures drawn once in the module, as ``workbench calibrate`` draws them (the effect case with
    its holds, the none case without, its residual reports given): ``{case: (paths, reports)}``. The tests only
    read the files; ``test_figures_laid_out_once_are_the_same_pngs`` compares the matplotlib-saved PNGs with these.
    Each figure's layout faults (:func:`_laid_out`) are noted in ``LAYOUT_FAULTS`` before it is saved."""
    base, result, holds = traced
    out = tmp_path_factory.mktemp("figures")
    reports = residual_reports(base, none_result)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(calibrate_figures, "save_figure", _checked_save)
        return {"effect": (calibration_figures(out / "effect" / "fig", base, result, holds=holds), None),
                "none": (calibration_figures(out / "none", base, none_result, holds=None, reports=reports), reports)}


def _check_pngs(paths, names):
    assert [p.stem for p in paths] == names
    for p in paths:
        assert p.is_file() and p.suffix == ".png"
        data = p.read_bytes()
        assert data[:8] == PNG and len(data) > 20_000, p


# --- figures ------------------------------------------------------------------------------------

def test_figures_effect_case(drawn):
    paths, _ = drawn["effect"]
    _check_pngs(paths, ALL + ["creep_holds"])
    folder = paths[0].parent
    assert folder.name == "fig" and all(p.parent == folder for p in paths)


def test_figures_none_case(traced, drawn):
    base, _, _ = traced
    paths, reports = drawn["none"]
    assert reports["after"] is None and reports["before"].n == base.t.size
    _check_pngs(paths, ALL)
    assert not (paths[0].parent / "creep_holds.png").exists()


@pytest.mark.parametrize("case", ("effect", "none"))
def test_figures_laid_out_once_are_the_same_pngs(traced, none_result, drawn, tmp_path, monkeypatch, case):
    """Every figure saved with its constrained layout computed once (``_save``: the module's ``drawn``) has the
    bytes of the figure saved as matplotlib does it (laid out while saving, twice) at the same PNG compression,
    and the pixels of the figure saved at Pillow's default compression, effect and none cases."""
    from matplotlib.image import imread

    from workbench.report import calibrate_figures
    from workbench.report.output import save_figure
    base, result, holds = traced
    result, holds = (result, holds) if case == "effect" else (none_result, None)
    fast, _ = drawn[case]
    for level, folder in ((calibrate_figures.PNG_LEVEL, "slow"), (None, "default")):
        monkeypatch.setattr(calibrate_figures, "_save", lambda fig, path, dpi=120, level=level: save_figure(
            fig, path, dpi=dpi, png_compress_level=level))
        slow = calibration_figures(tmp_path / folder, base, result, holds=holds)
        assert [p.name for p in fast] == [p.name for p in slow] and len(fast) >= 5
        for a, b in zip(fast, slow):
            if level is not None:
                assert a.read_bytes() == b.read_bytes(), a.name
            else:
                assert np.array_equal(imread(a), imread(b)), a.name


def test_figures_texts_inside_the_canvas_and_clear_of_each_other(drawn, tmp_path, monkeypatch):
    """Every figure as it is saved (its fixed margins, or the candidates' constrained layout) keeps every text inside
    the canvas and each axes' labels, titles and legends clear of the other axes': the effect case's six figures
    and the none case's five (the ``drawn`` fixture), and holds whose tick labels and notes are as wide as they
    come (gamma negative with four significant digits, L0 near -1000 of its unit, voltages of three digits)."""
    from workbench.report import calibrate_figures as cf
    monkeypatch.setattr(cf, "save_figure", _checked_save)
    wide = [{"start_s": 1.0 + k, "voltage_v": -88.8, "step_v": -111.1, "gamma": -0.0012345 * (1 + 0.1 * k),
             "sigma_gamma": 1e-5, "l0": -987.6e-6 * (1 - 0.01 * k), "sigma_l0": 1e-7} for k in range(6)]
    cf._plot_holds(wide, tmp_path / "wide_holds.png")
    assert len(LAYOUT_FAULTS) == 6 + 5 + 1 and not any(LAYOUT_FAULTS.values()), LAYOUT_FAULTS


def test_candidates_and_holds_figures_when_nothing_fitted(traced, none_result, tmp_path):
    from workbench.report.calibrate_figures import _plot_candidates, _plot_holds
    _, _, holds = traced
    skipped = [h for h in holds if not np.isfinite(h["gamma"])]
    for path in (_plot_candidates({**none_result, "candidates": []}, tmp_path / "c.png"),
                 _plot_holds(skipped, tmp_path / "h.png")):
        assert Path(path).read_bytes()[:8] == PNG and Path(path).stat().st_size > 3_000


def test_residual_models_before_and_after(traced, none_result):
    base, result, _ = traced
    ch, before, after, term = residual_models(base, result)
    assert ch == result["channel"]
    np.testing.assert_array_equal(before, base.channels[ch].yhat)
    np.testing.assert_allclose(after, result["terms"]["base"] + result["terms"]["term"])
    np.testing.assert_array_equal(term, result["terms"]["term"])
    ch, before, after, term = residual_models(base, none_result)
    assert ch == "displacement" and after is None and term is None


def test_gauge_nonlinearity_is_scored_against_the_gauge_line(traced, tmp_path):
    base, result, _ = traced
    line = base.gauge_offset_v + base.gauge_gain_v_per_m * base.channels["displacement"].y
    g = base.channels["gauge"]
    fake = {**result, "effect": "gauge_nonlinearity", "channel": "gauge", "parameters": {"coefficient_per_m": 3e3},
            "terms": {"channel": "gauge", "base": line, "term": np.zeros_like(line)},
            "error_before": {"rms": float(np.sqrt(np.mean((g.y - line)[~base.train] ** 2))), "max": 0.05, "units": "V"},
            "error_after": {"rms": 0.007, "max": 0.03, "units": "V"}}
    ch, before, after, _ = residual_models(base, fake)
    assert ch == "gauge"
    np.testing.assert_allclose(before, line)
    md = calibration_markdown("r.csv", PLANT, base, fake, None, [], None, 1.0)
    assert "the line gauge offset + gain x of the recorded displacement" in md
    assert "bow coefficient beta (eq. 27)" in md
    from workbench.report.calibrate_figures import _plot_residual
    assert Path(_plot_residual(base, fake, tmp_path / "residual.png")).stat().st_size > 20_000


# --- report -------------------------------------------------------------------------------------

def test_markdown_effect_case(traced, tmp_path):
    base, result, holds = traced
    figures = [tmp_path / f"{name}.png" for name in ALL + ["creep_holds"]]     # as calibration_figures names them
    md = calibration_markdown(Path("data/rec.csv"), PLANT, base, result, holds, figures,
                              tmp_path / "plant_calibrated.toml", 12.34, report_dir=tmp_path)
    assert md.startswith("# Calibration of `p888_51_sn637.toml` against `rec.csv`")
    assert f"**{result['effect']}** on the **{result['channel']}** channel" in md
    # the error table: the answer's channel with its held-out numbers in readable units
    eb, ea = result["error_before"], result["error_after"]
    f, unit = si_scale("m", max(eb["max"], ea["max"]))
    assert unit == "nm"
    row = (f"| **{result['channel']}** | {_num(eb['rms'] * f)} | {_num(eb['max'] * f)} | {_num(ea['rms'] * f)} | "
           f"{_num(ea['max'] * f)} | nm | {ea['rms'] / eb['rms']:.3f} |")
    assert row in md
    assert "| charge |" in md and "1 (unchanged)" in md
    # base fit, gains, candidates, holds, figures
    assert base.voltage_source in md and "Starts from rest: **yes**" in md
    assert "nm/uC" in md and "uF" in md and "mV/um" in md
    assert md.count("**chosen**") == 1
    assert len(result["candidates"]) == sum(1 for line in md.splitlines() if line.startswith("| ")
                                                        and line.split("|")[2].strip() in
                                                        {c["name"] for c in result["candidates"]}
                                                        and line.split("|")[1].strip().isdigit()
                                                        and "±" not in line)
    assert "## Creep per hold (seed 001)" in md and "L0 ± sigma (um)" in md
    first = holds[0]
    assert f"{_num(first['gamma'])} ± {_num(first['sigma_gamma'], 2)}" in md
    assert "no constant input before the hold" in md
    for name in ALL + ["creep_holds"]:
        assert f"![{name}]({name}.png)" in md
    assert "plant_calibrated.toml" in md and "12.3 s" in md
    for note in base.notes:
        assert f"- {note}" in md


def test_markdown_none_case_without_holds(traced, none_result):
    base, _, _ = traced
    md = calibration_markdown("rec.csv", "plant.toml", base, none_result, None, [], None, 3.0)
    assert "**No effect added.**" in md and "forced by the test" in md
    assert "No plant file written." in md
    assert "Creep per hold" not in md and "## Figures" not in md
    assert "**displacement**" not in md and md.count("1 (unchanged)") == len(base.channels)


@pytest.mark.parametrize("effect, params, unit, expected", [
    ("creep", {"gains": [0.0, 0.02, 0.0, 0.01], "taus_s": [0.001, 0.01, 0.1, 1.0]}, "m",
     ["2 of 4", "branch tau = 10 ms", "branch tau = 1 s", "total creep gain sum c_j"]),
    ("leakage", {"gain_per_s": -1e-8}, "C", ["S (A/V)", "100 Mohm"]),
    ("dielectric_absorption", {"gain": 7.6e-7, "tau_s": 4.46}, "C", ["760 | nF", "4.46 | s"]),
    ("resonance", {"gain": 1.0, "f_n_hz": 683.7, "zeta": 0.048}, "m", ["683.7 | Hz", "0.048 | 1"]),
    ("delay", {"delay_samples": 6.5, "delay_s": 6.5e-4}, "m", ["6.5 | samples", "650 | us"]),
    ("drift", {"coefficients": [0.0, 2e-7, -1e-7], "t0_s": 0.0, "t_end_s": 11.5}, "m",
     ["s^1", "200 | nm", "-100 | nm", "11.5 | s"]),
    ("mystery", {"k_new": 3.0}, "m", ["k_new | 3 | SI"]),
])
def test_parameter_rows_units(effect, params, unit, expected):
    text = "\n".join(" | ".join(str(c) for c in r) for r in parameter_rows(effect, params, unit))
    for e in expected:
        assert e in text, text


# --- helpers ------------------------------------------------------------------------------------

@pytest.mark.parametrize("unit, typical, factor, label", [
    ("m", 12e-6, 1e6, "um"), ("m", 3.9e-9, 1e9, "nm"), ("C", 8.9e-4, 1e6, "uC"), ("V", 0.0073, 1e3, "mV"),
    ("V", 4.1, 1.0, "V"), ("ohm", 5e7, 1e-6, "Mohm"), ("m", 0.0, 1.0, "m"), ("m", float("nan"), 1.0, "m"),
])
def test_si_scale(unit, typical, factor, label):
    assert si_scale(unit, typical) == (factor, label)


def test_decimate_keeps_extremes_and_order():
    rng = np.random.default_rng(7)
    n = 350_001
    t = np.arange(n) * 1e-4
    y = 1e-3 * rng.standard_normal(n)
    y[123_457] = 5.0                       # a one-sample spike must survive
    y[200_000:200_010] = np.nan            # rows not plotted stay out of the min/max
    td, yd = decimate(t, y)
    assert td.size <= MAX_POINTS + 10
    assert np.all(np.diff(td) >= 0)
    assert np.nanmax(yd) == 5.0 and np.nanmin(yd) == np.nanmin(y)
    short_t, short_y = decimate(t[:100], y[:100])
    np.testing.assert_array_equal(short_y, y[:100])


def _file_after(result, factor):
    """``result`` as ``workbench calibrate`` reports it with a written file replayed: error_after the file's
    (here ``factor`` x the tracing model's), error_after_model the tracing model's."""
    model = result["error_after"]
    return {**result, "error_after": {**model, "rms": model["rms"] * factor, "max": model["max"] * factor},
            "error_after_model": model, "error_after_source": "updated plant"}


@pytest.mark.parametrize("factor", [0.5, 3.0])
def test_the_residual_figure_names_whose_after_it_prints(traced, tmp_path, monkeypatch, factor):
    """The residual figure plots the tracing model's residual: its 'after' figure is the tracing model's,
    named so, and the written file's (the reported error_after) is printed under its own name (review of s15_rt:
    the figure printed the model's number as 'held-out RMS after' beside a report giving the file's)."""
    from workbench.report import calibrate_figures as cf
    base, result, _ = traced
    fake = _file_after(result, factor)
    seen = []
    real = cf._text
    monkeypatch.setattr(cf, "_text", lambda ax, lines, **k: (seen.extend(lines), real(ax, lines, **k)))
    cf._plot_residual(base, fake, tmp_path / "residual.png")
    m, f = result["error_after"], fake["error_after"]
    fb, lb = si_scale("m", max(abs(result["error_before"]["max"]), 1e-300))
    assert any(s.startswith(f"held-out RMS after (tracing model) {cf._fmt(m['rms'] * fb)} {lb}") for s in seen), seen
    assert any(s.startswith(f"held-out RMS after (written plant file) {cf._fmt(f['rms'] * fb)} {lb}")
               for s in seen), seen


@pytest.mark.parametrize("factor", [0.5, 3.0])
def test_the_error_tables_ratio_says_it_is_the_files_over_the_tracings_before(traced, factor):
    """With the file's replay as 'after', the table's ratio is the file's over the tracing's 'before', and the
    note under it says so and gives the tracing model's own ratio (review of s15_rt)."""
    base, result, _ = traced
    fake = _file_after(result, factor)
    md = calibration_markdown("r.csv", PLANT, base, fake, None, [], None, 1.0)
    eb, ea, em = fake["error_before"], fake["error_after"], result["error_after"]
    assert f"| {ea['rms'] / eb['rms']:.3f} |" in md
    assert "'after' is the written plant file's replay on the test rows" in md
    assert f"the tracing model's own RMS after / before: {em['rms'] / eb['rms']:.3f}" in md
