"""The ``workbench sweep`` job: verification and margins over serials x C_p tolerances x amplitudes.

One case is one plant (a serial of the study with its working capacitance scaled by
1 - tol, 1 or 1 + tol) and one signal amplitude A (PZT volts, from the study's
``family.amplitudes_v``). For each case:

- **margins**: the exported controller's loop with that plant's describing function at
  amplitude A (bias at mid-range), seen through the sampled gauge chain with the gauge
  gain at its two extremes (over x0 and the bridge tolerance), on the study's frequency
  grid: exactly the study family's members "DF A=... V, K_g min/max" for this serial and
  C_p, and the worst of the two, as the study takes it
  (:func:`workbench.design.margins.family_margins`). The small-signal members of the
  study's family are NOT swept (they have no amplitude): the study's worst member is
  often one of them (e.g. PM 62 deg on "initial at 50 V" against 95 deg on the
  describing functions), so compare like with like: the table's ``members`` column says
  what each row covers;
- **verification**: the compiled closed loop (the controller as firmware runs it) with
  that plant: a 0.1 Hz triangle of +/- A volts' worth of stroke around mid-stroke, fed with the
  export's velocity feedforward on its planned slope when the sensor block carries ``ref_lead_s``
  (tracking error RMS after the first period, % of the triangle's span) and a step of
  the same size (overshoot, settling, time at the current limit, residual oscillation).
  Without gauge noise by default: at 1 V a triangle spans ~0.3 um and the 22 nm gauge
  noise would be most of the error (``workbench verify`` scores the noise).

Cases run on local processes (default) or a dask.distributed cluster
(:func:`workbench.verify.sweep.run_cases`); one table (CSV or Parquet) with the worst
cases named.
"""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import StudyDefinitionError
from ..study.spec import load_study
from .sweep import Case, grid, run_cases, worst, write_table

__all__ = ["sweep_cases", "run_case", "run_sweep"]

SWEEP_FREQ_HZ = tuple(np.geomspace(5.0, 4990.0, 40))
WORST = (("phase_margin_deg", False), ("gain_margin_db", False), ("crossover_hz", False),
         ("triangle_error_percent", True), ("step_overshoot_percent", True), ("step_settling_s", True))


def sweep_cases(study, controller_path, amplitudes_v=None, noise=False):
    """The cases of a study: every serial x C_p factor x amplitude (payloads are plain data)."""
    plants = [study.plant, *study.serials]
    tol = study.family["cp_tolerance"]
    amps = [float(a) for a in (study.family["amplitudes_v"] if amplitudes_v is None else amplitudes_v)]
    cases = []
    for point in grid(plant=[str(p) for p in plants], cp_factor=sorted({1.0 - tol, 1.0, 1.0 + tol}),
                      amplitude_v=amps):
        key = {"serial": Path(point["plant"]).stem, **{k: point[k] for k in ("cp_factor", "amplitude_v")}}
        fam = study.family
        cases.append(Case(key, {**point, "controller": str(controller_path), "bias_v": fam["bias_v"],
                                "noise": bool(noise), "imbalance_tolerance_ohm": fam["imbalance_tolerance_ohm"],
                                "freq_hz": (fam["freq_min_hz"], fam["freq_max_hz"], fam["freq_points"])}))
    return cases


def run_case(payload):
    """Margins and closed-loop runs of one case (module docstring); a flat dict of metrics."""
    from ..linearize.limit_cycle import loop_responses
    from ..linearize.pzt_describing import pzt_describing_function
    from ..plant import load_plant
    from .closed_loop import ClosedLoop, controller_from_json
    from .scenarios import X_START_M, _oscillation, _step_metrics, _to_volts, planned_slope_lead, triangle_reference

    plant = load_plant(payload["plant"])
    pzt = replace(plant.pzt, working_capacitance_f=plant.pzt.working_capacitance_f * payload["cp_factor"])
    plant = replace(plant, pzt=pzt)
    data = json.loads(Path(payload["controller"]).read_text())
    ctrl = controller_from_json(data, None, (pzt.voltage_min_v, pzt.voltage_max_v))
    a_v = payload["amplitude_v"]
    g = plant.gauge
    dt = ctrl.dt_s

    # margins on the describing function at this amplitude: the study family's members for this case
    from ..design.margins import family_margins
    from ..linearize.uncertainty import FamilySpec, _gauge_range
    f = np.geomspace(*payload["freq_hz"][:2], payload["freq_hz"][2]) if "freq_hz" in payload \
        else np.asarray(SWEEP_FREQ_HZ)
    df = pzt_describing_function(pzt, (a_v,), f, biases_v=(payload["bias_v"],))
    _, k_lo, k_hi = _gauge_range(plant, FamilySpec(imbalance_tolerance_ohm=payload.get("imbalance_tolerance_ohm",
                                                                                         0.4)))
    lin = df.linear_ok[0, 0]
    # where the amplitude slews, clips or is not periodic the describing function is not a linear
    # behaviour to take margins on (as the study's family): those points are left out
    loops = {f"K_g {n}": np.where(lin, loop_responses(ctrl.linear(), k, df)[0], np.nan)
             for n, k in (("min", k_lo), ("max", k_hi))}
    out = {"members": f"DF A={a_v:g} V, K_g min and max (the study family's members of this serial and C_p; "
                      f"small-signal members not swept)",
           "linear_up_to_hz": float(f[lin][-1]) if np.any(lin) else float("nan")}
    _, w = family_margins(f, loops) if np.any(lin) else (None, None)
    # margins only when a gain crossover lies inside the linear range (else the amplitude slews there)
    out["slews_at_crossover"] = w is None or w["crossover_hz_min"]["member"] is None
    if not out["slews_at_crossover"]:
        out.update(phase_margin_deg=float(w["phase_margin_deg"]["value"]),
                   gain_margin_db=float(w["gain_margin_db"]["value"]),
                   crossover_hz=float(w["crossover_hz_min"]["value"]))
    else:
        out.update(phase_margin_deg=float("nan"), gain_margin_db=float("nan"), crossover_hz=float("nan"))

    # closed loop: a triangle and a step of the amplitude's worth of stroke around mid-stroke
    gain_m_per_v = float(np.real(df.x_m_per_v[0, 0, 0])) if np.isfinite(df.x_m_per_v[0, 0, 0]) else 1.5e-7
    half_m = min(a_v * abs(gain_m_per_v), 6.5e-6)
    cl = ClosedLoop(plant, ctrl, noise=payload.get("noise", False), seed=1)
    n = int(1.0 / dt)
    x_rest = pzt.k_q2x_m_per_c * pzt.hysteresis.output_at_rest()
    cl.run(_to_volts(np.concatenate([np.linspace(x_rest, X_START_M, n), np.full(n, X_START_M)]), g))
    fr = 0.1
    t, tri_next = triangle_reference(X_START_M - half_m, X_START_M + half_m, fr, 2, dt)   # verify's triangle
    tri = tri_next[:-1]
    dec = 50
    # fed with the export's velocity feedforward on the planned slope (ref_lead_s, 0: none), as verify's triangles
    r = cl.run(_to_volts(planned_slope_lead(tri_next, dt, ctrl.ref_lead_s), g), decimate=dec)
    after = t[dec - 1::dec][: r.x_m.size] >= 1 / fr
    err = r.x_m[after] - tri[dec - 1::dec][: r.x_m.size][after]
    out.update(triangle_span_m=2 * half_m, triangle_error_rms_m=float(np.sqrt(np.mean(err ** 2))),
               triangle_error_percent=float(np.sqrt(np.mean(err ** 2)) / (2 * half_m) * 100))
    cl.run(_to_volts(np.full(n, X_START_M), g))
    s = cl.run(_to_volts(np.full(int(0.5 / dt), X_START_M + half_m), g))
    ov, st = _step_metrics(s.t_s, s.x_m, X_START_M, X_START_M + half_m)
    amp, freq = _oscillation(s.x_m[-s.x_m.size // 2:], dt)
    out.update(step_m=half_m, step_overshoot_percent=ov, step_settling_s=st,
               step_time_at_current_limit_s=s.periods_at_current_limit * dt, step_oscillation_m=amp,
               step_oscillation_hz=freq)
    return out


def default_controller_path(study_file, export_name):
    """The controller a sweep runs without ``--controller``: ``controllers/NAME.json`` beside the study's folder."""
    return Path(study_file).parent.parent / "controllers" / f"{export_name}.json"


def run_sweep(study_path, controller_path=None, out_dir=None, table=None, scheduler=None, workers=None,
              amplitudes_v=None, noise=False, progress=None, timeout_s=None):
    """Run the sweep of a study file; write the table (and sweep.json) into ``out_dir``; return a summary."""
    if table is not None:
        from .sweep import check_table_path
        check_table_path(table)                     # before any case runs (a .txt table failed after the sweep)
    study = load_study(study_path)
    if controller_path is None:
        controller_path = default_controller_path(study.path, study.export["name"])
        if not controller_path.is_file():
            raise StudyDefinitionError(study.path, "export.name", f"no exported controller at {controller_path}; "
                                                                   f"give one with --controller")
    controller_path = Path(controller_path)
    from .run import load_controller_json
    load_controller_json(controller_path)           # a bad controller fails here, once, not per case
    from ..linearize.run import check_amplitudes           # the amplifier's span (one home), before any case
    from ..plant import load_plant
    amps = study.family["amplitudes_v"] if amplitudes_v is None else amplitudes_v
    for p in (study.plant, *study.serials):
        check_amplitudes(load_plant(p).pzt, amps, where=str(p),
                         name="amplitudes_v" if amplitudes_v is not None else f"{study.path}: [family.amplitudes_v]")
    cases = sweep_cases(study, controller_path, amplitudes_v, noise)
    rows = run_cases(run_case, cases, scheduler=scheduler, workers=workers, progress=progress, timeout_s=timeout_s)
    worst_cases = {}
    for metric, larger in WORST:
        try:
            w = worst(rows, metric, larger_is_worse=larger)
        except ValueError:       # no row has a number (e.g. every case slews at crossover): the table says why
            w = None
        if w is not None:
            worst_cases[metric] = {"value": w[metric], **{k: w[k] for k in ("serial", "cp_factor", "amplitude_v")}}
    summary = {"study": str(study.path), "controller": str(controller_path), "cases": len(rows),
               "members_covered": "margins on the describing-function members of the study's family (each serial x "
                                  "C_p corner x amplitude, worst of K_g min and max, the study's frequency grid); "
                                  "the small-signal members (branches at each bias) are in `workbench study`'s "
                                  "table, not here",
               "failed": sum(not r["ok"] for r in rows), "worst": worst_cases,
               "errors": [{**{k: r[k] for k in ("serial", "cp_factor", "amplitude_v")}, "error": r["error"]}
                          for r in rows if not r["ok"]]}
    if out_dir is not None or table is not None:
        out = Path(out_dir) if out_dir is not None else Path(table).parent
        path = Path(table) if table is not None else out / "sweep.csv"
        summary["table"] = str(write_table(rows, path))
        from ..report import write_json
        write_json(out / "sweep.json", summary)
    summary["rows"] = rows
    return summary
