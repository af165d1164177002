"""Table 1: the peak force of the measured ``R out`` runs, each held out (issue 16 item 2).

The model's force per volt of back EMF (k_p C_pp / T_em) reads every ``R out`` run 8 % too
compressive (the seed's C_p / T_em disagree with the Instron runs), so the gains are identified
on runs with a known load (seed 002 eq. 2.32) and each run is scored on gains its own force never
entered. Forms of the estimate (each uses the held-out run's back EMF V and/or its gauge
displacement x = gauge change x calibration, never its force), in three sets:

- pure back EMF (self-sensing, the run's own terminal voltage only): ``back_emf`` (F = G V),
  ``back_emf_serial`` (G of the same serial);
- back EMF with the gauge (the run's V and its x): ``linear`` (F = a V + b x),
  ``back_emf_and_gauge_mean`` (the mean of G V and G kappa_s x);
- gauge only (the run's x, no V of the run): ``gauge`` (F = K x), ``gauge_serial``, and
  ``gauge_through_back_emf``: F = G kappa_s x, the run's gauge times a gain calibrated on the
  other runs' back EMF (G = mean F/V of the training runs, kappa_s = mean V/x of the serial's
  other runs). It reads no back EMF of the scored run: it is not self-sensing.

With the model's force estimate of each run given (``model_estimate_n``: the run's back EMF read
through the hysteresis inverse with the serial's earlier runs' memory carried,
:func:`~.instron_sequence.table1_sequence_estimates`), one more pure back-EMF form:
``back_emf_hysteresis_inverse`` (F = G_h u, u the model estimate, G_h the mean F/u of the training runs).

Which run of the table is read with gauge and displacement exchanged is decided once, in
:func:`workbench.identify.transducer.table1_swap_decision`.
"""

import numpy as np

from ..identify.transducer import table1_swap_decision
from .force import FORCE_TARGET_PEAK_FRACTION

__all__ = ["TABLE1_FORMS", "TABLE1_FORM", "TABLE1_FORMS_PURE_BACK_EMF", "TABLE1_FORM_HYSTERESIS_INVERSE",
           "TABLE1_FORMS_BACK_EMF_WITH_GAUGE", "TABLE1_FORM_TITLES", "TABLE1_SCHEMES", "instron_held_out", "nested_held_out", "table1_spreads",
           "table1_held_out"]

TABLE1_FORMS = ("back_emf", "back_emf_serial", "gauge", "gauge_serial", "linear", "gauge_through_back_emf",
                "back_emf_and_gauge_mean")
TABLE1_FORM = "gauge_through_back_emf"     # the gauge-read form shown per run (chosen on the same 9 runs)
#: the forms that read the held-out run's own back EMF and nothing else of it (self-sensing)
TABLE1_FORMS_PURE_BACK_EMF = ("back_emf", "back_emf_serial")
#: the forms that read the held-out run's own back EMF and its strain gauge
TABLE1_FORMS_BACK_EMF_WITH_GAUGE = ("linear", "back_emf_and_gauge_mean")
#: the back EMF read through the hysteresis inverse with the state carried (needs the model's estimate per run)
TABLE1_FORM_HYSTERESIS_INVERSE = "back_emf_hysteresis_inverse"
#: what each form is, for printed lines, reports and legends
TABLE1_FORM_TITLES = {
    "back_emf": "back EMF x gain of the other runs (pure back EMF)",
    "back_emf_serial": "back EMF x gain of the serial's other runs (pure back EMF)",
    "gauge": "gauge x stiffness of the other runs (gauge only)",
    "gauge_serial": "gauge x stiffness of the serial's other runs (gauge only)",
    "linear": "a V + b x fitted on the other runs (back EMF with gauge)",
    "gauge_through_back_emf": "gauge x gain calibrated on other runs' back EMF (gauge only)",
    "back_emf_and_gauge_mean": "mean of back EMF x gain and gauge x back-EMF gain (back EMF with gauge)",
    TABLE1_FORM_HYSTERESIS_INVERSE: "back EMF through the hysteresis inverse, state carried, x gain of the other runs "
                                    "(pure back EMF)"}
TABLE1_SCHEMES = ("loo", "loso")


def _form_estimate(form, f, v, x, serial, train, i, u=None):
    """Peak force of run ``i`` by a form that needs no kappa_s, from the forces of ``train`` only; NaN if the form
    lacks data (a per-serial gain with no run of the serial in ``train``)."""
    train = np.asarray(train, int)
    same = train[serial[train] == serial[i]]
    if form == "back_emf":
        return np.mean(f[train] / v[train]) * v[i]
    if form == TABLE1_FORM_HYSTERESIS_INVERSE:
        return np.mean(f[train] / u[train]) * u[i]
    if form == "back_emf_serial":
        return np.mean(f[same] / v[same]) * v[i] if same.size else np.nan
    if form == "gauge":
        return np.mean(f[train] / x[train]) * x[i]
    if form == "gauge_serial":
        return np.mean(f[same] / x[same]) * x[i] if same.size else np.nan
    if form == "linear":
        coef = np.linalg.lstsq(np.column_stack([v[train], x[train]]), f[train], rcond=None)[0]
        return float(coef @ np.array([v[i], x[i]]))
    raise ValueError(f"unknown Table 1 form {form!r}; the forms are {', '.join(TABLE1_FORMS)}")


def _kappa_form(form, f, v, x, serial, train, calib, i):
    """The forms that read the back EMF through the gauge: G from ``train``'s forces, kappa_s = mean V/x over the runs
    of ``calib`` of run i's serial other than i (back EMF and gauge only, no force). On the model's open-lead
    stack V/x = -T_em / C_p (eq. 9 with q = 0) for every serial; kappa_s per serial absorbs each serial's
    gauge calibration error."""
    calib = np.asarray([j for j in calib if j != i and serial[j] == serial[i]], int)
    if calib.size == 0:
        return np.nan
    g = np.mean(f[train] / v[train])
    kappa = np.mean(v[calib] / x[calib])
    if form == "gauge_through_back_emf":
        return g * kappa * x[i]
    return 0.5 * (g * v[i] + g * kappa * x[i])          # back_emf_and_gauge_mean


def _estimate(form, f, v, x, serial, train, calib, i, u=None):
    if i in set(np.asarray(train, int).tolist()):
        raise ValueError(f"run {i} is in its own training set")
    if form in ("gauge_through_back_emf", "back_emf_and_gauge_mean"):
        return float(_kappa_form(form, f, v, x, serial, train, calib, i))
    return float(_form_estimate(form, f, v, x, serial, train, i, u))


def _check_model_estimate(forms, model_estimate_n, n):
    """The model's estimate per run as floats (None if no form needs it), or ValueError."""
    known = TABLE1_FORMS + ((TABLE1_FORM_HYSTERESIS_INVERSE,) if model_estimate_n is not None else ())
    unknown = [fm for fm in forms if fm not in known]
    if unknown or not forms:
        hint = (f" ({TABLE1_FORM_HYSTERESIS_INVERSE!r} needs model_estimate_n)"
                if TABLE1_FORM_HYSTERESIS_INVERSE in unknown else "")
        raise ValueError(f"unknown Table 1 form(s) {unknown}{hint}; the forms are {', '.join(known)}")
    if model_estimate_n is None:
        return None
    u = np.asarray(model_estimate_n, float)
    if u.shape != (n,) or not np.all(np.isfinite(u)) or np.any(u == 0):
        raise ValueError(f"model_estimate_n must be {n} finite nonzero forces (N), one per run")
    return u


def _check_runs(force_n, back_emf_v, x_m, serial, scheme):
    """The runs as float arrays, or ValueError naming what is wrong."""
    if scheme not in TABLE1_SCHEMES:
        raise ValueError(f"unknown scheme {scheme!r}; use 'loo' (leave one run out) or 'loso' (leave one serial out)")
    f, v, x = (np.asarray(a, float) for a in (force_n, back_emf_v, x_m))
    s = np.asarray(serial)
    if not (f.shape == v.shape == x.shape == s.shape and f.ndim == 1 and f.size >= 3):
        raise ValueError("force, back EMF, displacement and serial must be 1-D of one length (at least 3 runs)")
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(v)) and np.all(np.isfinite(x))):
        raise ValueError("force, back EMF and displacement must be finite numbers (N, V, m)")
    if np.any(f == 0):
        raise ValueError("every run needs a nonzero peak force (the error is relative to it)")
    if np.any(v == 0) or np.any(x == 0):
        raise ValueError("every run needs a nonzero back EMF and gauge displacement (R out runs)")
    return f, v, x, s


def instron_held_out(force_n, back_emf_v, x_m, serial, *, form=TABLE1_FORM, scheme="loo", model_estimate_n=None):
    """Each run's peak force estimated from the other runs' forces, and its error.

    Parameters
    ----------
    force_n, back_emf_v, x_m : array_like of float
        Per ``R_out`` run: peak force, N (compression negative); back EMF, V; gauge
        displacement at the peak, m.
    serial : array_like of str
        Serial of each run.
    form : str, default ``"gauge_through_back_emf"``
        One of ``TABLE1_FORMS``. ``gauge_through_back_emf``: F = G kappa_s x, G the mean F/V
        of the training runs and kappa_s the mean V/x of the same serial's other runs (the
        run's gauge times a gain calibrated on the other runs' back EMF; the run's own V is
        not used, so it is not self-sensing). ``back_emf``: F = G V.
        ``gauge``: F = K x. ``*_serial``: the gain of the same serial's training runs.
        ``linear``: F = a V + b x by least squares. ``back_emf_and_gauge_mean``: the mean of
        G V and G kappa_s x. ``back_emf_hysteresis_inverse`` (with ``model_estimate_n``):
        F = G_h u, G_h the mean F/u of the training runs.
    scheme : {"loo", "loso"}
        ``loo``: the training runs are all others; ``loso``: the runs of the other serials
        (the serial's own forces all withheld; its other runs' V/x still calibrate kappa_s).
    model_estimate_n : array_like of float, optional
        The model's force estimate u per run, N, made without any run's force
        (:func:`~.instron_sequence.table1_sequence_estimates`).

    Returns
    -------
    dict
        ``estimate_n``, ``error_fraction`` (signed, (estimate - F)/|F|) per run; ``max_error_fraction``,
        ``rms_error_fraction`` (NaN if a run has no estimate), ``form``, ``scheme``.
    """
    f, v, x, s = _check_runs(force_n, back_emf_v, x_m, serial, scheme)
    u = _check_model_estimate((form,), model_estimate_n, f.size)
    n = f.size
    est = np.empty(n)
    for i in range(n):
        train = [j for j in range(n) if j != i and (scheme == "loo" or s[j] != s[i])]
        est[i] = _estimate(form, f, v, x, s, train, range(n), i, u)
    err = (est - f) / np.abs(f)
    return {"form": form, "scheme": scheme, "estimate_n": est.tolist(), "error_fraction": err.tolist(),
            "max_error_fraction": float(np.max(np.abs(err))), "rms_error_fraction": float(np.sqrt(np.mean(err ** 2)))}


def nested_held_out(force_n, back_emf_v, x_m, serial, *, forms=TABLE1_FORMS, scheme="loo", model_estimate_n=None):
    """Each run held out with the form chosen without it: per outer fold, the form of least inner RMS error.

    Parameters
    ----------
    force_n, back_emf_v, x_m, serial : array_like
        As :func:`instron_held_out`.
    forms : sequence of str, default ``TABLE1_FORMS``
        The candidate forms.
    scheme : {"loo", "loso"}
        Outer and inner folds alike: ``loo`` holds out one run (the inner leave-one-out runs
        on the other runs); ``loso`` holds out the run's serial's forces (the inner
        leave-one-serial-out runs on the other serials' runs, and the estimate of the held-out
        run uses its serial's other runs' V/x only, as :func:`instron_held_out` does).
    model_estimate_n : array_like of float, optional
        As :func:`instron_held_out` (needed by ``back_emf_hysteresis_inverse``).

    Returns
    -------
    dict
        ``estimate_n``, ``error_fraction``, ``chosen_form`` per run; ``max_error_fraction``,
        ``rms_error_fraction``, ``scheme``.

    Notes
    -----
    The held-out run's force, V and x never enter the choice: the inner folds' training and
    kappa_s calibration runs are drawn from the outer training runs only. A form without an
    estimate on some inner fold (a per-serial gain with no run of the serial left) is not a
    candidate for that outer fold.
    """
    f, v, x, s = _check_runs(force_n, back_emf_v, x_m, serial, scheme)
    u = _check_model_estimate(tuple(forms), model_estimate_n, f.size)
    n = f.size
    est, chosen = np.empty(n), []
    for i in range(n):
        rest = [j for j in range(n) if j != i and (scheme == "loo" or s[j] != s[i])]
        score = {}
        for form in forms:
            e = [(_estimate(form, f, v, x, s, [k for k in rest if k != j and (scheme == "loo" or s[k] != s[j])],
                            rest, j, u) - f[j]) / abs(f[j]) for j in rest]
            if np.all(np.isfinite(e)):
                score[form] = float(np.sqrt(np.mean(np.square(e))))
        if not score:
            raise ValueError(f"no form among {', '.join(forms)} can be scored under {scheme!r} without run {i}")
        best = min(score, key=score.get)
        chosen.append(best)
        est[i] = _estimate(best, f, v, x, s, rest, range(n), i, u)
    err = (est - f) / np.abs(f)
    return {"scheme": scheme, "estimate_n": est.tolist(), "error_fraction": err.tolist(), "chosen_form": chosen,
            "max_error_fraction": float(np.max(np.abs(err))), "rms_error_fraction": float(np.sqrt(np.mean(err ** 2)))}


def table1_spreads(decided, held):
    """The repeat runs' scatter and what it implies for a new run.

    Parameters
    ----------
    decided : list of dict
        :func:`~workbench.identify.transducer.table1_swap_decision`'s output.
    held : dict
        :func:`instron_held_out`'s output for the same runs.

    Returns
    -------
    dict
        ``f_per_v_relative_std``: per serial, the sample standard deviation (ddof = 1) of F/V
        over its runs relative to their mean (NaN for a serial with one run);
        ``pooled_f_per_v_relative_std``; ``held_out_rms_error_fraction``; and
        ``exceed_target_fraction_normal``: the share of new runs whose error would exceed the 5 %
        target if errors are normal with zero mean and the held-out RMS as standard deviation,
        2 (1 - Phi(0.05 / RMS)) (0 when the held-out RMS is 0, NaN when it is NaN).
    """
    from scipy.stats import norm
    serials = sorted({d["serial"] for d in decided})
    fv = {}
    resid = []
    for sn in serials:
        rows = [d for d in decided if d["serial"] == sn]
        a = np.array([d["force_n"] / d["back_emf_v"] for d in rows])
        fv[sn] = float(np.std(a, ddof=1) / abs(np.mean(a))) if a.size > 1 else np.nan
        resid.extend((a / np.mean(a) - 1.0).tolist())
    dof = len(resid) - len(serials)
    rms = float(held["rms_error_fraction"])
    p = 0.0 if rms == 0.0 else 2.0 * norm.sf(FORCE_TARGET_PEAK_FRACTION / rms)
    return {"f_per_v_relative_std": fv,
            "pooled_f_per_v_relative_std": float(np.sqrt(np.sum(np.square(resid)) / dof)) if dof > 0 else np.nan,
            "held_out_rms_error_fraction": rms, "exceed_target_fraction_normal": float(p)}


def table1_held_out(path=None, *, x_source="gauge", calibrations_m_per_v=None, model_estimate_n=None):
    """The Table 1 ``R_out`` runs' peak forces, each estimated on the others (module section notes).

    Parameters
    ----------
    path : str or path-like, optional
        Table 1 CSV; default ``plants/data/p888_51_instron_table1.csv``.
    x_source : {"gauge", "displacement"}
        The displacement each run is read with: gauge change x the serial's calibration
        (default), or the printed displacement column. Either as decided by
        :func:`~workbench.identify.transducer.table1_swap_decision`.
    calibrations_m_per_v : mapping of str to float, optional
        Gauge calibration per serial, m/V; default seed 000 sec. 3.1.
    model_estimate_n : array_like of float, optional
        Per ``R_out`` run in file order, the model's force estimate from its back EMF through the
        hysteresis inverse with the state carried, N
        (:func:`~.instron_sequence.table1_sequence_estimates`). When given, ``forms`` also holds
        ``back_emf_hysteresis_inverse`` and ``nested_pure_back_emf_hysteresis_inverse`` is the
        nested choice among the pure back-EMF forms and it.

    Returns
    -------
    dict
        ``runs`` (the swap decision per run), ``forms`` ({form: {scheme: instron_held_out(...)}}),
        ``reported`` (``TABLE1_FORM``'s ``loo`` and ``loso``; ``reported_form_title`` says what
        it is), ``nested_pure_back_emf`` (:func:`nested_held_out` over
        ``TABLE1_FORMS_PURE_BACK_EMF``: force self-sensing from the run's own back EMF),
        ``nested_back_emf_with_gauge`` (over ``TABLE1_FORMS_BACK_EMF_WITH_GAUGE``), ``nested``
        (every form) and ``nested_loso`` (every form, leave one serial out), ``spreads``
        ({scheme: :func:`table1_spreads` of the reported form}), ``target_fraction``,
        ``target_met_loo``, ``target_met_loso``, and ``target_met_<key>`` for each nested key,
        ``x_source``.

    Notes
    -----
    The reported form reads no back EMF of the run it scores (the run's gauge times a gain
    calibrated on the other runs' back EMF), and was chosen among ``TABLE1_FORMS`` on the same
    nine runs it is scored on (a selection on the scoring data); the ``nested*`` entries choose
    the form per held-out run without that run. Self-sensing proper is ``nested_pure_back_emf``.
    """
    if x_source not in ("gauge", "displacement"):
        raise ValueError(f"x_source must be 'gauge' or 'displacement', got {x_source!r}")
    from ..identify.transducer import DEFAULT_CALIBRATIONS_M_PER_V, DEFAULT_TABLE1_PATH, _read_table
    from .force import check_force_table
    table = DEFAULT_TABLE1_PATH if path is None else path          # a table no run can be scored on: named here
    check_force_table(table, _read_table(table, calibrations_m_per_v or DEFAULT_CALIBRATIONS_M_PER_V)[0])
    decided = table1_swap_decision(path, calibrations_m_per_v=calibrations_m_per_v)
    f = np.array([d["force_n"] for d in decided])
    v = np.array([d["back_emf_v"] for d in decided])
    x = np.array([d["x_gauge_m" if x_source == "gauge" else "displacement_m"] for d in decided])
    s = np.array([d["serial"] for d in decided])
    u = model_estimate_n
    all_forms = TABLE1_FORMS + ((TABLE1_FORM_HYSTERESIS_INVERSE,) if u is not None else ())
    forms = {form: {sch: instron_held_out(f, v, x, s, form=form, scheme=sch, model_estimate_n=u)
                    for sch in TABLE1_SCHEMES} for form in all_forms}
    nested = {"nested_pure_back_emf": nested_held_out(f, v, x, s, forms=TABLE1_FORMS_PURE_BACK_EMF),
              "nested_back_emf_with_gauge": nested_held_out(f, v, x, s, forms=TABLE1_FORMS_BACK_EMF_WITH_GAUGE),
              "nested": nested_held_out(f, v, x, s), "nested_loso": nested_held_out(f, v, x, s, scheme="loso")}
    if u is not None:
        nested["nested_pure_back_emf_hysteresis_inverse"] = nested_held_out(
            f, v, x, s, forms=TABLE1_FORMS_PURE_BACK_EMF + (TABLE1_FORM_HYSTERESIS_INVERSE,), model_estimate_n=u)
    rep = forms[TABLE1_FORM]
    tgt = FORCE_TARGET_PEAK_FRACTION
    ok = lambda h: bool(h["max_error_fraction"] <= tgt)    # noqa: E731 (NaN compares False: a missing estimate misses)
    return {"x_source": x_source, "runs": decided, "forms": forms, "reported_form": TABLE1_FORM,
            "reported_form_title": TABLE1_FORM_TITLES[TABLE1_FORM], "reported": rep, **nested,
            "spreads": {sch: table1_spreads(decided, rep[sch]) for sch in TABLE1_SCHEMES}, "target_fraction": tgt,
            "target_met_loo": ok(rep["loo"]), "target_met_loso": ok(rep["loso"]),
            **{f"target_met_{k}": ok(h) for k, h in nested.items()}}
