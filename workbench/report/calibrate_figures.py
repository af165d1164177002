"""Figures of the calibration (``workbench calibrate``): the record, the residual before and after
the effect the tracing names, its correlations and spectrum, the candidates' scores, and seed
001's creep per hold.

Every function reads the engine's objects as they are: a
:class:`~workbench.calibrate.base_fit.BaseFit` (``base``), the dict of
:func:`~workbench.calibrate.tracing.trace_effect` (``result``) and, optionally, the list of
:func:`~workbench.calibrate.creep_holds.fit_holds` (``holds``). Quantities are SI inside and
converted only on the axes (um, nm, uC, mV: the prefix that puts the largest value between 1
and 1000).

Long records (350,000 samples for the 35 s protocol at 10 kHz) are drawn decimated: each line
keeps the minimum and the maximum of every bucket of samples (at most ``MAX_POINTS`` points per
line), so spikes and envelopes survive while a figure renders in about a second.
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from scipy import signal  # noqa: E402

from ..calibrate.residual import analyze_residual, fit_percent  # noqa: E402
from .output import save_figure  # noqa: E402

__all__ = ["calibration_figures", "residual_models", "residual_reports", "si_scale", "decimate",
           "MAX_POINTS", "MAX_RATIO", "PENALTY"]

MAX_POINTS = 6000           # points per line, at most (min/max pairs keep the envelope)
PNG_LEVEL = 1               # zlib level of the PNGs: the same pixels as level 6, ~10 % larger, written faster
MAX_RATIO = 0.8             # kept for importers of the earlier interface (the decision is in tracing.py)
PENALTY = 0.02              # trace_effect's default parsimony penalty per parameter
HELD_OUT = dict(color="0.88", zorder=0, lw=0)
BOX = dict(boxstyle="round", fc="white", ec="0.7", alpha=0.9)
CHANNEL_TITLES = {"displacement": "displacement x", "charge": "charge q (integrated current)",
                  "gauge": "gauge (DAC output)"}
CHANNEL_COLORS = {"displacement": "C0", "charge": "C2", "gauge": "C4"}
_PREFIXES = ((1e12, 1e-12, "T"), (1e9, 1e-9, "G"), (1e6, 1e-6, "M"), (1e3, 1e-3, "k"), (1.0, 1.0, ""),
             (1e-3, 1e3, "m"), (1e-6, 1e6, "u"), (1e-9, 1e9, "n"), (1e-12, 1e12, "p"),
             (1e-15, 1e15, "f"))          # (prefix, exact factor, name)


def si_scale(unit, typical):
    """Factor and label that show values of size ``typical`` in ``unit`` between 1 and 1000.

    SI as it is (factor 1) when ``typical`` is zero, NaN or not a number.

    >>> si_scale("m", 12e-6)
    (1000000.0, 'um')
    >>> si_scale("V", 0.03)
    (1000.0, 'mV')
    >>> si_scale("ohm", 5e7)
    (1e-06, 'Mohm')
    """
    try:
        typical = abs(float(typical))
    except (TypeError, ValueError):
        typical = 0.0
    if not np.isfinite(typical) or typical == 0:
        return 1.0, unit                     # nothing to scale by: SI as it is
    for p, f, name in _PREFIXES:
        if typical >= p:
            return f, f"{name}{unit}"
    return _PREFIXES[-1][1], f"{_PREFIXES[-1][2]}{unit}"


def _peak(*arrays):
    vals = [np.nanmax(np.abs(a)) for a in arrays if a is not None and np.size(a) and np.any(np.isfinite(a))]
    return max(vals) if vals else 0.0


def decimate(t, y, max_points=MAX_POINTS):
    """``(t, y)`` thinned to at most ``max_points`` points: the min and max of each bucket, in time order.

    NaN samples (rows that are not plotted) are skipped by the min/max unless a bucket is all NaN.
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    n = t.size
    if n <= max_points:
        return t, y
    k = int(np.ceil(n / (max_points // 2)))
    m = n // k
    tb, yb = t[: m * k].reshape(m, k), y[: m * k].reshape(m, k)
    finite = np.isfinite(yb)
    any_finite = finite.any(axis=1)
    lo = np.argmin(np.where(finite, yb, np.inf), axis=1)
    hi = np.argmax(np.where(finite, yb, -np.inf), axis=1)
    first, second = np.minimum(lo, hi), np.maximum(lo, hi)
    rows = np.arange(m)
    td = np.column_stack([tb[rows, first], tb[rows, second]]).ravel()
    yd = np.column_stack([yb[rows, first], yb[rows, second]])
    yd[~any_finite] = np.nan
    yd = yd.ravel()
    if m * k < n:                                       # the tail that fills no bucket
        td, yd = np.r_[td, t[m * k:][:: max(1, k // 2)]], np.r_[yd, y[m * k:][:: max(1, k // 2)]]
    return td, yd


def _save(fig, path, dpi=120):
    """:func:`~workbench.report.output.save_figure`, the constrained layout computed once (the candidates'
    figure; the others have fixed margins, :func:`_fixed_layout`, and no layout engine).

    Saving a figure with a layout engine lays it out twice (matplotlib draws it once without
    output to place it, then again to render it, placing it again): here the engine places it
    once, at the saving resolution, and is then set aside, so the render draws what was placed:
    the same PNG bytes (``tests/calibrate/test_calibrate_report.py``), one layout and one
    traversal of the figure less (~15 % of the figures' time). The PNG is compressed at zlib level
    ``PNG_LEVEL`` (1): the same pixels as Pillow's default level 6, in a file ~10 % larger, ~20 ms
    a figure faster (``tests/calibrate/test_calibrate_report.py``).
    """
    engine = fig.get_layout_engine()
    if engine is not None and not plt.rcParams["figure.autolayout"] and \
            not plt.rcParams["figure.constrained_layout.use"]:
        old = fig.dpi
        fig.set_dpi(dpi)
        try:
            engine.execute(fig)
        finally:
            fig.set_dpi(old)
        fig.set_layout_engine(None)          # no engine (the rc's default): savefig draws once
    return save_figure(fig, path, dpi=dpi, png_compress_level=PNG_LEVEL)


#: The space above a figure's top text (its suptitle), inches: constrained layout's own pad (4 points).
TOP_PAD_IN = 4 / 72


def _top_text_y(fig):
    """The ``y`` (figure fraction) of a suptitle set ``TOP_PAD_IN`` below the top edge (``va="top"``), where
    constrained layout put it."""
    return 1.0 - TOP_PAD_IN / fig.get_figheight()


def _fixed_layout(fig, left, right, bottom, top, hgap=0.0, wgap=0.0):
    """Place ``fig``'s grid of axes with fixed margins, in inches: no layout engine to run.

    ``left``, ``right``, ``bottom`` and ``top`` are the margins from each edge of the figure to the grid's outer
    axes; ``hgap`` and ``wgap`` the space between two rows and between two columns. Constrained layout measured
    every tick label of every axes twice to place them (~1 s CPU of the six figures of a 355,000-row protocol
    record). The vertical margins are those it chose (the texts' heights do not depend on the data); the
    horizontal ones the widest it chose on records of each effect at 100 Hz, 10 kHz and 1 MHz, plus ~0.1 in (tick
    labels stay between 1 and 1000 of their unit, :func:`si_scale`). ``tests/calibrate/test_calibrate_report.py``
    checks every figure's texts inside the canvas and clear of the other axes'.
    """
    w, h = fig.get_size_inches()
    gs = fig.axes[0].get_subplotspec().get_gridspec()
    nrows, ncols = gs.get_geometry()
    width, height = w - left - right, h - bottom - top
    # subplots_adjust's spaces are fractions of the mean axes' size: gap = space * size, size = (span - gaps) / n
    hspace = nrows * hgap / (height - (nrows - 1) * hgap) if nrows > 1 else 0.0
    wspace = ncols * wgap / (width - (ncols - 1) * wgap) if ncols > 1 else 0.0
    fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h,
                        hspace=hspace, wspace=wspace)


def _plot(ax, t, y, *args, **kwargs):
    td, yd = decimate(t, y)
    return ax.plot(td, yd, *args, **kwargs)


def _spans(mask):
    """Index spans (start, stop) of the True runs of ``mask``."""
    edges = np.flatnonzero(np.diff(np.r_[0, np.asarray(mask, np.int8), 0]))
    return edges.reshape(-1, 2)


def _held_out(base):
    """The scored held-out rows (``base.test``; rows before a cycles split's training start are
    neither trained on nor scored)."""
    return base.test if getattr(base, "test", None) is not None else ~base.train


def _shade_held_out(ax, t, test):
    for i, j in _spans(np.asarray(test, bool)):
        ax.axvspan(t[i], t[j - 1], **HELD_OUT)


def _text(ax, lines, x=0.99, y=0.97, ha="right", va="top", fontsize=8):
    ax.text(x, y, "\n".join(lines), transform=ax.transAxes, ha=ha, va=va, fontsize=fontsize, bbox=BOX, zorder=10)


def _fmt(v, nd=3):
    if v is None or not np.isfinite(v):
        return "n/a"
    return f"{v:.0f}" if abs(v) >= 1000 else f"{v:.{nd}g}"


def _plot_channel(base, result):
    """The channel the residual figures show: the answer's, else displacement, else the first."""
    ch = result.get("channel")
    if ch in base.channels:
        return ch
    return "displacement" if "displacement" in base.channels else next(iter(base.channels))


def residual_models(base, result):
    """``(channel, before, after, term)`` of the plotted channel, full-length arrays in SI.

    ``before`` is the model the answer was scored against: the channel's base model, except for
    ``gauge_nonlinearity``, scored against the LINE ``gauge_offset + gauge_gain x`` from the
    recorded displacement (as :func:`~workbench.calibrate.tracing.trace_effect` does).
    ``after`` is ``terms["base"] + terms["term"]`` (the base refitted with the effect) and
    ``term`` the effect's correction; both are None when no effect was found.
    """
    ch = _plot_channel(base, result)
    m = base.channels[ch]
    before = m.yhat
    if result.get("effect") == "gauge_nonlinearity" and "displacement" in base.channels \
            and base.gauge_gain_v_per_m is not None:
        before = base.gauge_offset_v + base.gauge_gain_v_per_m * base.channels["displacement"].y
    terms = result.get("terms") or {}
    if result.get("effect", "none") == "none" or terms.get("channel", ch) != ch or "term" not in terms:
        return ch, before, None, None
    term = np.asarray(terms["term"], float)
    return ch, before, np.asarray(terms["base"], float) + term, term


def residual_reports(base, result, max_lag=50):
    """:func:`~workbench.calibrate.residual.analyze_residual` of the plotted channel before and after.

    Returns ``{"before": ResidualReport, "after": ResidualReport or None}``, the input being the
    driving voltage ``base.v_drive``. Rows where the channel is not valid (a gauge at its rails)
    get a zero residual, so the record stays evenly sampled.
    """
    ch, before, after, _ = residual_models(base, result)
    m = base.channels[ch]
    y = m.y
    out = {}
    for key, model in (("before", before), ("after", after)):
        if model is None:
            out[key] = None
            continue
        model = np.where(m.valid, model, y)
        out[key] = analyze_residual(base.t, base.v_drive, y, model, max_lag=max_lag, unit=m.units)
    return out


def _plot_overview(base, result, path):
    t = base.t
    names = list(base.channels)
    fig, axes = plt.subplots(len(names) + 1, 1, sharex=True, figsize=(11, 2.3 * (len(names) + 1) + 0.8))
    axes = np.atleast_1d(axes)
    test = _held_out(base)
    av = axes[0]
    _shade_held_out(av, t, _held_out(base))
    _plot(av, t, base.v_drive, "k", lw=0.7)
    av.set_ylabel("voltage (V)")
    av.set_title(f"driving voltage: {base.voltage_source}" + ("" if base.starts_from_rest else
                                                              " (record does not start from rest)"), fontsize=9)
    for ax, name in zip(axes[1:], names):
        m = base.channels[name]
        f, lab = si_scale(m.units, _peak(m.y))
        _shade_held_out(ax, t, _held_out(base))
        y = np.where(m.valid, m.y, np.nan)
        _plot(ax, t, y * f, color=CHANNEL_COLORS.get(name, "C0"), lw=0.8, label="measured")
        _plot(ax, t, m.yhat * f, "k--", lw=0.8, label="base model (PI of V)")
        if not m.valid.all():
            _plot(ax, t, np.where(m.valid, np.nan, m.y) * f, "C3", lw=1.2, label="invalid (at the rails)")
        ax.set_ylabel(f"{name} ({lab})")
        rows = test & m.valid
        e = m.residual[rows]
        fe, le = si_scale(m.units, _peak(e))
        fit = fit_percent(m.y[rows], m.yhat[rows]) if rows.sum() > 1 else float("nan")
        ax.set_title(f"{CHANNEL_TITLES.get(name, name)}: held-out RMS "
                     f"{_fmt(np.sqrt(np.mean(e * e)) * fe if e.size else np.nan)} {le}, max "
                     f"{_fmt(np.max(np.abs(e)) * fe if e.size else np.nan)} {le}, fit {_fmt(fit, 4)} %", fontsize=9)
        ax.legend(fontsize=7, loc="lower right", ncol=3)
    axes[-1].set_xlabel("time (s)")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.set_xlim(t[0], t[-1])
    axes[0].fill_between([], [], color=HELD_OUT["color"], label="held out (scored)")
    axes[0].legend(fontsize=7, loc="upper right")
    fig.suptitle(f"Record and base fit: {len(t)} samples, {t[-1] - t[0]:.3g} s; held-out rows shaded "
                 f"({100 * test.mean():.0f} %)", fontsize=11, y=_top_text_y(fig))
    fig.align_ylabels(axes)
    _fixed_layout(fig, left=0.9, right=0.3, bottom=0.475, top=0.457, hgap=0.31)
    return _save(fig, path)


def _running_mean(y, n):
    """Centred mean over ``n`` samples of the finite values (NaN where none, and at the incomplete ends)."""
    y = np.asarray(y, float)
    if n < 2 or y.size < n:
        return y
    ok = np.isfinite(y)
    c = np.cumsum(np.insert(np.where(ok, y, 0.0), 0, 0.0))
    m = np.cumsum(np.insert(ok.astype(float), 0, 0.0))
    cnt = m[n:] - m[:-n]
    out = np.full(y.size, np.nan)
    k = (n - 1) // 2
    with np.errstate(invalid="ignore", divide="ignore"):
        out[n - 1 - k:y.size - k] = np.where(cnt > 0, (c[n:] - c[:-n]) / np.maximum(cnt, 1), np.nan)
    return out


def _zoom_window(t, signal_abs):
    """Index range around the largest value of ``signal_abs`` where it stays above 30 % of it."""
    n = t.size
    a = np.nan_to_num(np.asarray(signal_abs, float))
    k = int(np.argmax(a))
    thr = 0.3 * a[k]
    lo = k
    while lo > 0 and a[lo - 1] >= thr:
        lo -= 1
    hi = k
    while hi < n - 1 and a[hi + 1] >= thr:
        hi += 1
    width = hi - lo + 1
    pad = max(width // 2, 50)
    lo, hi = max(0, lo - pad), min(n, hi + pad + 1)
    cap = max(200, n // 10)                              # at most a tenth of the record
    if hi - lo > cap:
        lo, hi = max(0, k - cap // 2), min(n, k + cap // 2)
    return lo, hi


def _plot_residual(base, result, path):
    t = base.t
    ch, before, after, term = residual_models(base, result)
    m = base.channels[ch]
    valid = m.valid
    e0 = np.where(valid, m.y - before, np.nan)
    e1 = None if after is None else np.where(valid, m.y - after, np.nan)
    f, lab = si_scale(m.units, _peak(e0, e1))
    fig = plt.figure(figsize=(11, 8))
    gs = fig.add_gridspec(2, 2, height_ratios=[1.2, 1])
    ax = fig.add_subplot(gs[0, :])
    _shade_held_out(ax, t, _held_out(base))
    test = _held_out(base)
    _plot(ax, t, e0 * f, color="0.6", lw=0.6, label="before (training rows)")
    _plot(ax, t, np.where(test, e0, np.nan) * f, color="C0", lw=0.6, alpha=0.7, label="before (held out)")
    if e1 is not None:
        _plot(ax, t, e1 * f, color="C1", lw=0.6, alpha=0.6, label=f"after adding {result['effect']}")
    # running means: the systematic part under the sensor noise
    w = max(5, t.size // 2000)
    _plot(ax, t, _running_mean(e0, w) * f, color="navy", lw=1.0, label=f"before, {w}-sample mean")
    if e1 is not None:
        _plot(ax, t, _running_mean(e1, w) * f, color="darkred", lw=1.0, label=f"after, {w}-sample mean")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlim(t[0], t[-1])
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"{ch} residual ({lab})")
    ax.legend(fontsize=7, loc="lower right", ncol=3)
    eb, ea = result.get("error_before") or {}, result.get("error_after") or {}
    fb, lb = si_scale(m.units, _peak(eb.get("max", np.nan)))
    lines = [f"held-out RMS before {_fmt(eb.get('rms', np.nan) * fb)} {lb}, max {_fmt(eb.get('max', np.nan) * fb)} {lb}"]
    if e1 is not None:
        # the plotted 'after' is the tracing model's; with an updated plant file replayed, the reported error_after
        # is the file's (``error_after_source``), printed beside it under its own name (review of s15_rt)
        file_after = ea if result.get("error_after_source") == "updated plant" else None
        em = (result.get("error_after_model") or {}) if file_after is not None else ea
        lines.append(f"held-out RMS after (tracing model) {_fmt(em.get('rms', np.nan) * fb)} {lb}, max "
                     f"{_fmt(em.get('max', np.nan) * fb)} {lb}")
        if file_after is not None:
            lines.append(f"held-out RMS after (written plant file) {_fmt(file_after.get('rms', np.nan) * fb)} {lb}, "
                         f"max {_fmt(file_after.get('max', np.nan) * fb)} {lb}")
    _text(ax, lines)
    effect = result.get("effect", "none")
    title = (f"{ch} residual (measured - model) before and after {effect}" if e1 is not None
             else f"{ch} residual (measured - base model); effect: {effect}")
    ax.set_title(title, fontsize=10)

    # the zoom: where the effect changes the model most (else where the residual is largest). The
    # net change (after - before) rather than the raw term: a term's static part (dielectric
    # absorption's k lowpass(V)) is absorbed by the refitted base and changes nothing.
    net = None if after is None else after - before
    lo, hi = _zoom_window(t, np.abs(net - np.median(net)) if net is not None else np.abs(np.nan_to_num(e0)))
    sl = slice(lo, hi)
    az = fig.add_subplot(gs[1, 0])
    ar = fig.add_subplot(gs[1, 1], sharex=az)
    fy, ly = si_scale(m.units, _peak(m.y[sl]))
    tz = t[sl]
    for a in (az, ar):
        _shade_held_out(a, tz, _held_out(base)[sl])
    _plot(az, tz, np.where(valid[sl], m.y[sl], np.nan) * fy, color=CHANNEL_COLORS.get(ch, "C0"), lw=1.0,
          label="measured")
    _plot(az, tz, before[sl] * fy, "k--", lw=0.9, label="model before")
    if after is not None:
        _plot(az, tz, after[sl] * fy, "C1", lw=0.9, label="model after")
    az.set_ylabel(f"{ch} ({ly})")
    az.ticklabel_format(axis="y", useOffset=False)
    az.legend(fontsize=7, loc="best")
    az.set_title("zoom: " + ("where adding the effect changes the model most" if net is not None
                             else "where the residual is largest"), fontsize=9)
    fr, lr = si_scale(m.units, _peak(e0[sl], None if e1 is None else e1[sl], None if net is None else net[sl]))
    _plot(ar, tz, e0[sl] * fr, "C0", lw=0.8, label="residual before")
    if e1 is not None:
        _plot(ar, tz, e1[sl] * fr, "C1", lw=0.8, label="residual after")
        _plot(ar, tz, net[sl] * fr, "C3--", lw=1.0, label=f"model after - before (what {effect} adds)")
    ar.axhline(0, color="k", lw=0.5)
    ar.set_ylabel(f"residual ({lr})")
    ar.legend(fontsize=7, loc="best")
    ar.set_title(f"zoom: residuals, {tz[0]:.4g}-{tz[-1]:.4g} s", fontsize=9)
    for a in (az, ar):
        a.set_xlabel("time (s)")
        a.set_xlim(tz[0], tz[-1])
    for a in (ax, az, ar):
        a.grid(True, alpha=0.3)
    fig.suptitle(f"Residual of the {ch} (held-out rows shaded); answer: {effect}", fontsize=11, y=_top_text_y(fig))
    _fixed_layout(fig, left=0.85, right=0.35, bottom=0.475, top=0.47, hgap=0.695, wgap=1.15)
    return _save(fig, path)


def _corr_panel(ax, lags, before, after, b_before, b_after, lag_s):
    off = 0.15
    ax.fill_between(lags, -b_before, b_before, color="C0", alpha=0.15, lw=0,
                    label=f"band before (+/-{b_before:.3g})")
    ax.vlines(lags - off, 0, before, color="C0", lw=1.2)
    ax.plot(lags - off, before, "o", color="C0", ms=2.5, label="before")
    if after is not None:
        ax.axhline(b_after, color="C1", ls="--", lw=0.9, label=f"band after (+/-{b_after:.3g})")
        ax.axhline(-b_after, color="C1", ls="--", lw=0.9)
        ax.vlines(lags + off, 0, after, color="C1", lw=1.2)
        ax.plot(lags + off, after, "s", color="C1", ms=2.5, label="after")
    ax.axhline(0, color="k", lw=0.5)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    sec = ax.secondary_xaxis("top", functions=(lambda k: k * lag_s * 1e3, lambda ms: ms / (lag_s * 1e3)))
    sec.set_xlabel("lag (ms)", fontsize=8)
    sec.tick_params(labelsize=7)


def _verdict(rep, key):
    return "none (no effect added)" if rep is None else ("pass" if getattr(rep, key) else "FAIL")


def _plot_correlation(base, result, reports, path):
    ch = _plot_channel(base, result)
    rb, ra = reports.get("before"), reports.get("after")
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 7.5))
    lag_s = rb.sample_period_s
    k = rb.lags[1:]
    _corr_panel(a1, k, rb.autocorr[1:], None if ra is None else ra.autocorr[1:], rb.autocorr_bound,
                None if ra is None else ra.autocorr_bound, lag_s)
    a1.set_xlabel("lag k (samples)")
    a1.set_ylabel("R_e(k) / R_e(0)")
    a1.set_title(f"autocorrelation of the {ch} residual (whiteness): before {_verdict(rb, 'white')}, "
                 f"after {_verdict(ra, 'white')}", fontsize=10)
    xl = rb.crosscorr_lags
    _corr_panel(a2, xl, rb.crosscorr, None if ra is None else ra.crosscorr, rb.crosscorr_bound,
                None if ra is None else ra.crosscorr_bound, lag_s)
    a2.set_xlabel("lag tau (samples; > 0: the input leads the residual)")
    a2.set_ylabel("R_eu(tau) / sqrt(R_e(0) R_u(0))")
    a2.set_title(f"cross-correlation of the residual with the driving voltage (independence): before "
                 f"{_verdict(rb, 'independent')}, after {_verdict(ra, 'independent')}", fontsize=10)
    fig.suptitle(f"Residual tests as MATLAB resid: {100 * rb.confidence:.0f} % bands, N = {rb.n} samples, "
                 f"effect: {result.get('effect', 'none')}", fontsize=11, y=_top_text_y(fig))
    _fixed_layout(fig, left=1.05, right=0.15, bottom=0.475, top=0.813, hgap=1.051)
    return _save(fig, path)


def _welch(x, fs):
    n = x.size
    nper = int(min(65536, max(256, 2 ** int(np.floor(np.log2(max(n / 8, 2)))))))
    nper = min(nper, n)
    return signal.welch(x, fs=fs, nperseg=nper, detrend="constant", scaling="density")


def _plot_spectrum(base, result, path):
    t = base.t
    ch, before, after, term = residual_models(base, result)
    m = base.channels[ch]
    fs = (t.size - 1) / (t[-1] - t[0])
    e0 = np.where(m.valid, m.y - before, 0.0)
    f, lab = si_scale(m.units, _peak(e0))
    fig, ax = plt.subplots(figsize=(10, 5.5))
    curves = [("before", e0, "C0", "-")]
    if after is not None:
        net = after - before          # what the effect changes (its static part the refitted base absorbs)
        curves += [("after", np.where(m.valid, m.y - after, 0.0), "C1", "-"),
                   (f"model after - before (what {result['effect']} adds)", np.where(m.valid, net - np.mean(net), 0.0),
                    "C3", "--")]
    nper = None
    for label, x, col, ls in curves:
        fr, p = _welch(x * f, fs)
        nper = 2 * (fr.size - 1)
        keep = (fr > 0) & (p > 0)
        if keep.any():
            ax.loglog(fr[keep], p[keep], color=col, ls=ls, lw=1.0, label=f"{label}: whole-record RMS "
                      f"{_fmt(float(np.sqrt(np.mean((x * f) ** 2))))} {lab}")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel(f"PSD ({lab}^2/Hz)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")
    ax.set_title(f"Power spectral density of the {ch} residual, whole record (Welch, Hann, {nper}-sample "
                 f"segments = {fs / nper:.2g} Hz resolution)", fontsize=10)
    _fixed_layout(fig, left=1.0, right=0.15, bottom=0.503, top=0.233)
    return _save(fig, path)


def _plot_candidates(result, path):
    # the ratio at which a candidate explains the tracing's minimum share of the held-out variance
    max_ratio = float(np.sqrt(1.0 - float(result.get("min_share", 0.3))))
    penalty = float(result.get("penalty", PENALTY))
    cands = list(result.get("candidates") or [])
    chosen = (result.get("effect"), result.get("channel"))
    order = []
    channels = []
    for c in cands:
        if c["channel"] not in channels:
            channels.append(c["channel"])
    for chn in channels:          # grouped by channel, best first inside each group
        order += sorted((c for c in cands if c["channel"] == chn), key=lambda c: c["score"])
    n = len(order)
    fig, ax = plt.subplots(figsize=(10, 1.2 + 0.38 * max(n, 1)), layout="constrained")
    if not n:
        ax.text(0.5, 0.5, "no candidate could be fitted", ha="center", va="center", transform=ax.transAxes)
        ax.set_axis_off()
        return _save(fig, path)
    scores = np.array([c["score"] for c in order], float)
    finite = scores[np.isfinite(scores)]
    xmax = max(1.2, min(3.0, 1.08 * (finite.max() if finite.size else 1.0)))
    y = np.arange(n)[::-1]
    for yi, c, s in zip(y, order, scores):
        is_chosen = (c["name"], c["channel"]) == chosen
        col = CHANNEL_COLORS.get(c["channel"], "C7")
        ax.barh(yi, min(s, xmax) if np.isfinite(s) else xmax, color=col, alpha=1.0 if is_chosen else 0.45,
                edgecolor="k" if is_chosen else "none", lw=2.0 if is_chosen else 0, height=0.7)
        txt = f"{s:.3f}" + (" (clipped)" if np.isfinite(s) and s > xmax else "") + ("  << chosen" if is_chosen else "")
        ax.text(min(s, xmax) if np.isfinite(s) else xmax, yi, " " + txt, va="center", fontsize=8,
                fontweight="bold" if is_chosen else "normal")
    ax.set_yticks(y, [f"{c['name']} ({c['channel']}, {c.get('n_params', '?')} par.)" for c in order], fontsize=8)
    ax.axvline(max_ratio, color="C3", ls="--", lw=1.2)
    ax.axvline(1.0, color="k", lw=0.6)
    # channel group separators
    for i in range(1, n):
        if order[i]["channel"] != order[i - 1]["channel"]:
            ax.axhline(y[i] + 0.5, color="0.6", lw=0.6)
    handles = [Line2D([], [], color="C3", ls="--", lw=1.2, label=f"explains {100 * (1 - max_ratio ** 2):.0f} % of the variance "
                      f"(one of the tests a fold applies)")]
    handles += [Patch(color=CHANNEL_COLORS.get(chn, "C7"), alpha=0.6, label=f"{chn} channel") for chn in channels]
    handles.append(Patch(fc="0.6", ec="k", lw=2.0, label="chosen (bold edge)"))
    ax.set_xlim(0, xmax * 1.18)
    ax.set_xlabel(f"score: median over the validation folds of RMS after x (1 + {penalty:g} n_params) / RMS before "
                  f"(lower is better)")
    fig.legend(handles=handles, fontsize=8, loc="outside lower center", ncol=len(handles), frameon=False)
    ax.grid(True, axis="x", alpha=0.3)
    ax.set_title(f"Candidate effects, grouped by channel: answer {chosen[0]}"
                 + (f" on the {chosen[1]}" if chosen[0] != "none" else ""), fontsize=10)
    return _save(fig, path)


def _plot_holds(holds, path):
    fitted = [h for h in holds if np.isfinite(h.get("gamma", np.nan))]
    skipped = [h for h in holds if not np.isfinite(h.get("gamma", np.nan))]
    fig, (ag, al) = plt.subplots(2, 1, sharex=True, figsize=(10, 7))
    t0 = np.array([h["start_s"] for h in fitted], float)
    if fitted:
        g = np.array([h["gamma"] for h in fitted], float)
        sg = np.array([h["sigma_gamma"] for h in fitted], float)
        l0 = np.array([h["l0"] for h in fitted], float)
        sl = np.array([h["sigma_l0"] for h in fitted], float)
        fl, ll = si_scale("m", _peak(l0))
        ag.errorbar(t0, g, yerr=sg, fmt="o", color="C0", capsize=4, label="gamma +/- sigma (eq. 7)")
        al.errorbar(t0, l0 * fl, yerr=sl * fl, fmt="s", color="C2", capsize=4, label="L0 +/- sigma")
        starts = [float(h["start_s"]) for h in holds]
        mid = 0.5 * (min(starts) + max(starts))
        for ti, gi, h in zip(t0, g, fitted):
            # right of its point in the left half of the holds, left of it in the right half: inside the axes'
            # fixed frame (the skipped holds' lines are drawn too)
            right = ti > mid
            ag.annotate(f"{h['voltage_v']:.3g} V ({h['step_v']:+.3g} V)", (ti, gi), xytext=(-5 if right else 5, 5),
                        textcoords="offset points", fontsize=7, ha="right" if right else "left")
        al.set_ylabel(f"L0: change 0.1 s after the step ({ll})")
        ag.legend(fontsize=8, loc="best")
        al.legend(fontsize=8, loc="best")
        al.axhline(0, color="k", lw=0.5)
    else:
        al.set_ylabel("L0")
    for h in skipped:
        for a in (ag, al):
            a.axvline(h["start_s"], color="0.6", ls=":", lw=1)
    if skipped:
        _text(ag, [f"skipped at {h['start_s']:.3g} s: {h.get('skip_reason', '')}"[:90] for h in skipped][:6],
              x=0.01, y=0.03, ha="left", va="bottom", fontsize=7)
    ag.set_ylabel("gamma (creep per decade, 1)")
    al.set_xlabel("start of the hold (s)")
    for a in (ag, al):
        a.grid(True, alpha=0.3)
        a.margins(x=0.08, y=0.15)
    ag.set_title(f"Seed 001's log creep law per hold, L(t) = L0 (1 + gamma log10(t / 0.1 s)): "
                 f"{len(fitted)} fitted, {len(skipped)} skipped", fontsize=10)
    _fixed_layout(fig, left=1.15, right=0.25, bottom=0.475, top=0.233, hgap=0.132)
    return _save(fig, path)


def calibration_figures(out_dir, base, result, holds=None, reports=None):
    """Write the calibration's PNG figures into ``out_dir``; returns their paths in order.

    Parameters
    ----------
    out_dir : path-like
        Folder of the figures (created when missing).
    base : BaseFit
        From :func:`~workbench.calibrate.base_fit.fit_base`.
    result : dict
        From :func:`~workbench.calibrate.tracing.trace_effect`; ``terms`` is used when present.
    holds : list of dict, optional
        From :func:`~workbench.calibrate.creep_holds.fit_holds`; adds ``creep_holds.png``.
    reports : dict, optional
        ``{"before": ResidualReport, "after": ResidualReport or None}`` of the plotted channel
        (as :func:`residual_reports` returns them, computed when not given).

    Returns
    -------
    list of Path
        ``overview.png``, ``residual.png``, ``correlation.png``, ``spectrum.png``,
        ``candidates.png`` and, with holds, ``creep_holds.png``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if reports is None or reports.get("before") is None:
        reports = residual_reports(base, result)
    paths = [_plot_overview(base, result, out / "overview.png"),
             _plot_residual(base, result, out / "residual.png"),
             _plot_correlation(base, result, reports, out / "correlation.png"),
             _plot_spectrum(base, result, out / "spectrum.png"),
             _plot_candidates(result, out / "candidates.png")]
    if holds:
        paths.append(_plot_holds(holds, out / "creep_holds.png"))
    return [Path(p) for p in paths]
