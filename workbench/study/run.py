"""Run a design study: linearize, design (loop shaping, Glover-McFarlane, H-infinity, convex), margins, export, report.

Every stage reports progress through ``progress(stage, done, total)``; the result is
the ``summary.json`` dict, and the report, figures and exported controllers are
written into the output folder (whole or not at all, file by file).
"""

import time
from pathlib import Path

import control
import numpy as np

from ..errors import DesignError, StudyDefinitionError, StudyFailed
from ..linearize.limit_cycle import loop_responses, predict_limit_cycles, sampled_factor
from ..linearize.uncertainty import FamilySpec, plant_family, uncertainty_bound
from ..plant import load_plant
from .spec import load_study

__all__ = ["run_study", "StudyFailed", "ONLY"]

ONLY = ("loopshape",)          # --only: the exported design alone, no comparison designs
_DEFAULT = "default"


def _members_table(rows, freq_hz, members):
    """Margins grouped per serial and per amplitude/branch (worst over C_p corners and gauge extremes).

    ``linear_up_to_hz``: the highest frequency at which the member is in the family (describing
    functions of larger amplitudes slew above a few hertz and have no crossover of their own).
    """
    groups = {}
    for r in rows:
        ok = np.isfinite(members[r["member"]])
        top = float(freq_hz[ok][-1]) if ok.any() else float("nan")
        serial, _, rest = r["member"].partition(" C_p ")
        what = rest.split(", ")[1] if ", " in rest else rest
        g = groups.setdefault((serial, what), {"serial": serial, "member": what, "phase_margin_deg": np.inf,
                                                "gain_margin_db": np.inf, "crossover_min_hz": np.inf,
                                                "crossover_max_hz": 0.0, "disk_margin": np.inf,
                                                "linear_up_to_hz": 0.0})
        g["linear_up_to_hz"] = max(g["linear_up_to_hz"], top)
        g["phase_margin_deg"] = min(g["phase_margin_deg"], abs(r["phase_margin_deg"]))
        g["gain_margin_db"] = min(g["gain_margin_db"], abs(r["gain_margin_db"]))
        g["disk_margin"] = min(g["disk_margin"], r["disk_margin"])
        if np.isfinite(r["crossover_hz"]):
            g["crossover_min_hz"] = min(g["crossover_min_hz"], r["crossover_hz"])
            g["crossover_max_hz"] = max(g["crossover_max_hz"], r["crossover_hz"])
    return list(groups.values())


def _loops_continuous(ctrl_c, freq_hz, members, delay_s):
    c = np.asarray(control.frequency_response(ctrl_c, 2 * np.pi * freq_hz).complex).ravel()
    d = np.exp(-2j * np.pi * freq_hz * delay_s)
    return {n: c * d * g for n, g in members.items() if np.any(np.isfinite(g))}


def _loops_discrete(ctrl_d, freq_hz, members, delay_samples):
    from ..design.loopshape import family_loops
    return family_loops(ctrl_d, freq_hz, {n: g for n, g in members.items() if np.any(np.isfinite(g))},
                        delay_samples)


def _worst_summary(worst):
    keys = ("phase_margin_deg", "gain_margin_db", "delay_margin_s", "disk_margin", "s_peak_db", "t_peak_db",
            "crossover_hz_min", "crossover_hz_max")
    return {k: worst[k] for k in keys}


def _nominal_summary(m):
    return {"crossover_hz": m.crossover_hz, "phase_margin_deg": m.phase_margin_deg,
            "gain_margin_db": m.gain_margin_db, "pm_freq_hz": m.pm_freq_hz, "gm_freq_hz": m.gm_freq_hz}


def _binding_summary(ls_spec, ls, tune):
    """The constraint that bound the design, and the design with it relaxed by its stated amount."""
    from ..design.loopshape import CONSTRAINTS, relaxed
    b = dict(ls.binding)
    name = b["constraint"]
    field, _, _, said = CONSTRAINTS[name]
    r_spec = relaxed(ls_spec, name)
    try:
        r = tune(r_spec, "design: relaxed " + name)
        b["relaxed"] = {"by": said, "field": field, "limit": getattr(r_spec, field),
                        "crossover_hz_min": r.crossover_hz, "fc_hz": r.params["fc_hz"],
                        "then_binding": r.binding["constraint"]}
    except DesignError as err:
        b["relaxed"] = {"by": said, "field": field, "limit": getattr(r_spec, field), "error": str(err)}
    return b


def _fix_for(ls_spec, ls, target_hz, tune, max_steps=4):
    """The change that makes the lowest crossover reach ``target_hz``: relax the binding constraint(s) step by step."""
    from ..design.loopshape import CONSTRAINTS, relaxed
    spec, steps, cur = ls_spec, [], ls
    for _ in range(max_steps):
        name = cur.binding["constraint"]
        field = CONSTRAINTS[name][0]
        spec = relaxed(spec, name)
        steps.append({"constraint": name, "field": field, "limit": getattr(spec, field)})
        try:
            cur = tune(spec, "fix: relax " + name)
        except DesignError:
            continue
        if cur.crossover_hz >= target_hz:
            return {"passes": True, "changes": steps, "crossover_hz_min": cur.crossover_hz}
    return {"passes": False, "changes": steps, "crossover_hz_min": cur.crossover_hz}


def run_study(study_path, out_dir, progress=None, overrides=None, only=None, cache_dir=_DEFAULT, workers=None):
    """Run the study file ``study_path``; write the report into ``out_dir``; return the summary.

    Parameters
    ----------
    study_path, out_dir : str or Path
    progress : callable(stage, done, total), optional
    overrides : list of str or dict, optional
        ``section.key=value`` items (or ``{"section.key": value}`` in SI) for plant and study
        values (:mod:`.overrides`); plant sections apply to every plant of the study.
    only : {None, "loopshape"}
        ``"loopshape"``: the exported design alone (no Glover-McFarlane, H-infinity, convex).
    cache_dir : path, "default" or None
        Where the family is cached (:mod:`.cache`; "default": the user cache folder; None: no cache).
    workers : int, optional
        Processes the family runs on (default: the machine's cores).

    Raises
    ------
    StudyFailed
        After writing the report, when the best design misses ``targets.min_crossover_hz``
        or no design meets the targets (the CLI exits 2).
    """
    from ..design.antiwindup import current_limit_model, discretize
    from ..design.budgets import plant_budgets
    from ..design.coprime import ncf_synthesis
    from ..design.loopshape import LoopShapeSpec, noise_command_rms_v, nominal_step, tune_loop_shape
    from ..design.nominal import nominal_plant
    from ..plant.gauge import demod_noise_sigma_v
    from ..design.margins import family_margins
    from ..design.reduce import reduce_controller
    from ..report import design_figures as figs
    from ..report.html import write_html_report
    from ..report.markdown import write_report
    from ..design.budgets import reading_noise_budget, tracking_budget
    from ..design.loopshape import triangle_harmonics
    from .cache import cached_family, default_cache_dir, family_key
    from .sensor import apply_sensor, sensor_model
    from .overrides import parse_overrides, split_overrides
    from .sections import failure_report, study_lines

    ovr = dict(overrides) if isinstance(overrides, dict) else parse_overrides(overrides)
    plant_ovr, study_ovr = split_overrides(ovr)
    if only is not None and only not in ONLY:
        raise StudyDefinitionError("--only", only, f"unknown; expected one of {', '.join(ONLY)}")
    from .overrides import naming_set
    with naming_set(ovr, None if isinstance(overrides, dict) else overrides):      # an error at a --set key names it
        spec = load_study(study_path, study_ovr)
        plant = load_plant(spec.plant, plant_ovr)
        serials = [load_plant(p, plant_ovr) for p in spec.serials]
    out = Path(out_dir)
    say = (lambda stage, d, t: progress(stage, d, t)) if progress else (lambda *a: None)
    t0 = time.perf_counter()
    g = plant.gauge
    dt = g.period_s
    delay_samples = 1
    fb = spec.sensor.get("blend_crossover_hz")
    if spec.sensor.get("kind") == "fused" and fb is not None:
        # the firmware blend's word must exist at this rate: checked now, not after the family and sensor records
        from ..export.sensor import SensorBlend
        try:
            SensorBlend(kind="fused", crossover_hz=float(fb), dt_s=dt, v_per_m=1.0)
        except ValueError as exc:
            raise StudyDefinitionError(spec.path, "sensor.blend_crossover_hz", f"got {fb:g} Hz: {exc}") from None
    fam_spec = spec.family
    freq = np.geomspace(fam_spec["freq_min_hz"], fam_spec["freq_max_hz"], fam_spec["freq_points"])
    if freq[-1] >= 0.5 / dt:
        raise DesignError(f"{spec.path}: family.freq_max_hz = {freq[-1]:g} Hz must stay below the servo's "
                          f"Nyquist frequency {0.5 / dt:g} Hz")
    fspec = FamilySpec(amplitudes_v=tuple(sorted(fam_spec["amplitudes_v"])), freq_hz=tuple(freq),
                       bias_v=fam_spec["bias_v"], cp_tolerance=fam_spec["cp_tolerance"],
                       imbalance_tolerance_ohm=fam_spec["imbalance_tolerance_ohm"])
    cache = default_cache_dir() if cache_dir == _DEFAULT else cache_dir
    key = family_key([spec.plant, *spec.serials], plant_ovr, fspec)
    family, cache_path, hit = cached_family(
        key, cache, lambda: plant_family([plant] + serials, fspec, workers=workers,
                                         progress=lambda d, t: say("linearize: family", d, t)))
    if hit:
        say("linearize: family (cached)", 1, 1)
    t_family = time.perf_counter() - t0
    ub = uncertainty_bound(family, plant)
    members = family.members
    summary = {"study": str(spec.path), "name": spec.name, "plant": str(spec.plant),
               "serials": [str(p) for p in spec.serials], "members": len(members),
               "excluded_points": family.excluded_points, "overrides": {k: v for k, v in ovr.items()},
               "only": only,
               "family_cache": {"path": None if cache_path is None else str(cache_path), "hit": hit,
                                "seconds": t_family},
               "uncertainty": {"weight": {"zeros_hz": list(ub.fit.zeros_hz), "poles_hz": list(ub.fit.poles_hz),
                                          "gain": ub.fit.gain, "order": ub.fit.order},
                               "coverage_margin_db": ub.coverage.margin_db, "worst_member": ub.coverage.member,
                               "nominal_capacitance_f": ub.nominal_capacitance_f},
               "designs": {}, "figures": {}}

    # 1. structured loop shaping: the exported design, its budgets derived from the plant
    lsk = spec.loop_shape
    grid = {key: tuple(float(v) for v in lsk[key]) for key in ("integral_ratios", "lead_ratios", "rolloff_ratios")
            if key in lsk}
    if "integral_orders" in lsk:
        grid["integral_orders"] = tuple(int(v) for v in lsk["integral_orders"])
    nom = nominal_plant(plant, fam_spec["bias_v"], delay_samples)
    # the feedback sensor (study/sensor.py): gauge (the members as they are), charge or fused (each member's
    # loop taken on the sensor's path, the noise that of the sensor's reading)
    sensor = sensor_model(plant, [spec.plant, *spec.serials], plant_ovr, spec.sensor, nom.gauge_v_per_m, cache, say)
    members = apply_sensor(sensor, freq, family.members, family)
    summary["sensor"] = sensor.as_dict()
    budgets = plant_budgets(plant, dt, lsk.get("max_noise_command_v"), spec.path)
    budgets["reading_noise_v"] = reading_noise_budget(sensor, demod_noise_sigma_v(g) * g.trim_scale)
    noise_v = budgets["reading_noise_v"].value                # one reading's noise, firmware V
    tracking = {}
    if "triangle_hz" in spec.targets:
        tb = tracking_budget(spec.targets["triangle_hz"], spec.targets["triangle_rms_percent_stroke"], sensor,
                             lsk["fc_min_hz"])
        budgets["triangle_tracking"] = tb
        f_tr, a_tr = triangle_harmonics(spec.targets["triangle_hz"], 0.8, 0.45 / dt)
        tracking = {"tracking_freq_hz": tuple(f_tr), "tracking_amplitudes": tuple(a_tr),
                    "max_tracking_rms": tb.value if tb.value is not None else 0.0,
                    "target_crossover_hz": spec.targets["min_crossover_hz"]}
    summary["budgets"] = {k: b.as_dict() for k, b in budgets.items()}
    summary["budgets"]["noise_command_v"]["series_resistance_ohm"] = plant.pzt.series_resistance_ohm
    model = current_limit_model(plant.pzt, dt)               # the exported current-limit window
    summary["nominal_plant"] = {"definition": "small-signal model on the ascending branch at the bias, gauge at "
                                              "mid-stroke, sampled chain (workbench.design.nominal)",
                                "bias_v": nom.bias_v, "capacitance_f": nom.capacitance_f,
                                "gauge_v_per_m": nom.gauge_v_per_m, "states": int(nom.continuous.nstates),
                                "creep_states_truncated": nom.truncated}
    ls_spec = LoopShapeSpec(phase_margin_deg=spec.targets["phase_margin_deg"],
                            gain_margin_db=spec.targets["gain_margin_db"],
                            fc_range_hz=(lsk["fc_min_hz"], lsk["fc_max_hz"]), dt_s=dt, delay_samples=delay_samples,
                            max_noise_command_v=budgets["noise_command_v"].value, noise_reading_v=noise_v,
                            voltage_alpha=None if model is None else model[0],
                            max_overshoot_percent=lsk.get("max_overshoot_percent"), **tracking, **grid)
    step_plant = nom.continuous        # the overshoot is judged on the nominal: where a small step up runs
    gauge = sensor.kind == "gauge"
    nominal_factor = None if gauge else sensor.factor
    step_plant_d = None if gauge else sensor.discrete_plant(nom.firmware)

    def tune(s, stage="design: loop shape"):
        return tune_loop_shape(freq, members, nom.continuous, s, progress=lambda d, t: say(stage, d, t),
                               step_plant=step_plant, nominal_factor=nominal_factor, step_plant_d=step_plant_d)

    min_fc = spec.targets["min_crossover_hz"]
    if tracking and budgets["triangle_tracking"].value is None:
        summary["failure"] = {"constraint": "targets.triangle_rms_percent_stroke",
                              "message": budgets["triangle_tracking"].derivation}
        _fail(out, spec, summary, freq, family, ub, None, failure_report, t0)
    try:
        ls = tune(ls_spec)
    except DesignError as err:
        summary["failure"] = {"constraint": "targets", "message": str(err)}
        _fail(out, spec, summary, freq, family, ub, None, failure_report, t0)
    fc = ls.params["fc_hz"]
    summary["binding"] = _binding_summary(ls_spec, ls, tune)
    overshoot, settling = nominal_step(ls.controller_d, step_plant, delay_samples, plant_d=step_plant_d)
    summary["designs"]["loop_shape"] = {"params": ls.params, "crossover_hz": ls.crossover_hz,
                                        "nominal": _nominal_summary(_nominal_margins(ls.controller_d, nom, sensor)),
                                        "worst_discrete": _worst_summary(ls.worst), "shapes_searched": ls.searched,
                                        "noise_command_rms_v": noise_command_rms_v(
                                            ls.controller_d, nom.continuous, noise_v, delay_samples,
                                            None if model is None else model[0], nominal_factor=nominal_factor),
                                        "noise_reading_v": noise_v, "step_overshoot_percent": overshoot,
                                        "step_settling_s": settling, "tracking": ls.tracking}
    if ls.crossover_hz < min_fc:
        summary["failure"] = {"constraint": "targets.min_crossover_hz", "limit": min_fc,
                              "value": ls.crossover_hz, "fix": _fix_for(ls_spec, ls, min_fc, tune)}
        _fail(out, spec, summary, freq, family, ub, ls, failure_report, t0)

    if only is None:
        # 2. Glover-McFarlane on the same shape, reduced and discretized
        say("design: coprime factors", 0, 1)
        delayed = ub.nominal * control.ss(control.tf(*control.pade(dt * (1 + delay_samples), 2)))
        ncf = ncf_synthesis(delayed, ls.controller_c, beta=0.9)
        red = reduce_controller(ncf.controller, min(ncf.controller.nstates, control.ss(ls.controller_c).nstates + 2))
        ncf_d = discretize(red.controller, dt, fc)
        ncf_rows, ncf_worst = family_margins(freq, _loops_discrete(ncf_d, freq, members, delay_samples))
        summary["designs"]["coprime"] = {"eps_max": ncf.eps_max, "eps": ncf.eps, "order_full": red.order_before,
                                         "order_reduced": red.order_after, "reduction_error_bound": red.error_bound,
                                         "reduction_error_measured": red.error_measured,
                                         "worst_discrete": _worst_summary(ncf_worst)}
        say("design: coprime factors", 1, 1)

        # 3. H-infinity (slycot, time-limited) and the convex route on the same weights, cross-checked
        summary["designs"].update(_hinf_and_convex(spec, ub, g, plant.pzt, dt, delay_samples, delayed, freq, members,
                                                   say))

    # 4. margins of the continuous, discrete and quantized exported controller
    cont_rows, cont_worst = family_margins(freq, _loops_continuous(ls.controller_c, freq, members, 0.0))
    summary["designs"]["loop_shape"]["worst_continuous_no_sampling"] = _worst_summary(cont_worst)
    from ..controller import Controller
    from dataclasses import replace as _replace_ctrl
    lim = tuple(float(v) for v in spec.export["output_limits_v"])
    f_max = min(10 * fc, 0.499 / dt)
    # the exported controller: sections, 32-bit words and the current-limit window (anti-windup):
    # firmware models the stack voltage (RC at the largest capacitance) and never commands more
    # than R I_max beyond it, so a large step slews in the controller as in the stack while small
    # and noisy moves pass. Controller.from_lti derives that window from the plant.
    ctrl = Controller.from_lti(ls.controller_d, plant, output_limits_v=lim, input_range_v=spec.export["input_range_v"],
                               f_max_hz=f_max, name=spec.export["name"],
                               method="structured loop shaping (PI, lead, roll-off) against the describing-function "
                                      "family")
    fxp = ctrl.fixed
    ctrl_q = control.ss(ctrl.as_lti(quantized=True))
    q_rows, q_worst = family_margins(freq, _loops_discrete(ctrl_q, freq, members, delay_samples))
    summary["designs"]["loop_shape"]["worst_quantized"] = _worst_summary(q_worst)
    summary["designs"]["loop_shape"]["nominal_quantized"] = _nominal_summary(_nominal_margins(ctrl_q, nom, sensor))
    meets = all(w["phase_margin_deg"]["value"] >= spec.targets["phase_margin_deg"]
                and w["gain_margin_db"]["value"] >= spec.targets["gain_margin_db"] for w in (ls.worst, q_worst))
    summary["designs"]["loop_shape"]["meets_targets"] = bool(meets)

    # 5. export with anti-windup (the conditioned cascade the fixed-point step runs)
    record = {**ctrl.record, "gauge_chain": {"volts_per_meter": ub.nominal_gauge_v_per_m,
                                             "trim": {"scale": g.trim_scale, "bias_v": g.trim_bias_v}},
              "margins": {"discrete": _worst_summary(ls.worst), "quantized": _worst_summary(q_worst),
                          "continuous_no_sampling": _worst_summary(cont_worst)},
              "anti_windup": {**ctrl.record["anti_windup"], "output_slew_limit_v_per_s": list(fxp.slew_limits_v_per_s)},
              "noise": {"reading_rms_v": noise_v,
                        "command_change_rms_v": summary["designs"]["loop_shape"]["noise_command_rms_v"]},
              "provenance": {**_provenance(spec, plant), "serial": plant.serial}}
    if sensor.kind != "gauge":
        record["sensor_model"] = sensor.record()        # how the charge estimate and the blend were derived
    ctrl = _replace_ctrl(ctrl, record=record)
    # the controller's own sensor block: the blend and error scaling run inside its firmware step
    # (NAME_sensor_step of its C header, bit for bit with Controller.run_sensors), with firmware's startup
    # settings derived on this study's nominal plant and sensor records (verify/sensors.py: firmware_startup):
    # the wait before closing (the reading's own settle: the gauge's is one period), the velocity feedforward
    # 1/K_v on ramps' planned slope and the gauge bridge's curvature. The gauge study carries them too.
    say("export: firmware startup", 0, 1)
    from ..export.sensor import STARTUP_FIELDS
    from ..verify.sensors import with_firmware_startup
    ctrl = ctrl.with_sensor(sensor.kind, sensor.blend.crossover_hz if sensor.kind == "fused" else None,
                            v_per_m=ub.nominal_gauge_v_per_m)
    ctrl = with_firmware_startup(sensor.firmware_setup(plant), ctrl, bias_v=fam_spec["bias_v"])
    summary["firmware_startup"] = {k: getattr(ctrl.sensor, k) for k in STARTUP_FIELDS}
    if ls.tracking is not None and ls.tracking_loop is not None:
        # the search ruled on the triangle without a lead (its constraint, unchanged); the export's velocity
        # feedforward takes the ramp lag out: the prediction with it, |S_k (1 - D_k L L_k)| on the same harmonics
        from ..design.loopshape import tracking_rms
        lead = ctrl.sensor.ref_lead_s or 0.0
        ls.tracking.update(rms_with_lead=tracking_rms(ls.tracking_loop, a_tr, f_tr, lead, dt), lead_s=lead)
    say("export: firmware startup", 1, 1)
    paths = ctrl.write(out / spec.export["directory"], spec.export["name"])
    summary["exported"] = {k: str(v) for k, v in paths.items()}

    # 6. figures and report
    say("report", 0, 1)
    nominal_df = family.dfs[f"{plant.serial} C_p x1.00"]
    loops_d = _loops_discrete(ls.controller_d, freq, members, delay_samples)
    fw_sf = sampled_factor(freq, dt, delay_samples)
    lc_loops = loop_responses(ls.controller_d, ub.nominal_gauge_v_per_m, nominal_df, delay_samples=delay_samples)
    lc_loops = lc_loops * sensor.factor(nominal_df.freq_hz)[None, :]       # 1 for the gauge
    cycles, _ = predict_limit_cycles(nominal_df.amplitudes_v, freq, lc_loops)
    summary["designs"]["loop_shape"]["limit_cycles"] = [c.__dict__ for c in cycles]
    fig = summary["figures"]
    fig["loop_bode"] = str(figs.plot_loop_family(freq, loops_d, out / "loop_bode.png", ls.params))
    fig["sensitivity"] = str(figs.plot_sensitivities(freq, loops_d, ub, out / "sensitivity.png"))
    fig["nyquist"] = str(figs.plot_nyquist_family(freq, loops_d, nominal_df, ub, ls.controller_d, fw_sf,
                                                  cycles, out / "nyquist.png"))
    if only is None:
        fig["steps"] = str(figs.plot_steps(plant, serials, ls.controller_d, ncf_d, dt, delay_samples,
                                           out / "steps.png"))
    table = _members_table(q_rows, freq, members)
    summary["margins_table"] = table
    summary["seconds"] = time.perf_counter() - t0
    summary["study_sections"] = study_lines(summary)
    summary["report"] = str(write_report(out / "report.md", spec, summary, table))
    summary["report_html"] = str(write_html_report(out / "report.md"))
    from ..report import write_json
    write_json(out / "summary.json", summary)
    say("report", 1, 1)
    return summary


def _fail(out, spec, summary, freq, family, ub, ls, failure_report, t0):
    """Write the failed study's report and summary, then raise :class:`StudyFailed`."""
    from ..report import write_json
    summary["seconds"] = time.perf_counter() - t0
    report, message = failure_report(out, spec, summary, freq, family, ub, ls)
    summary["report"] = str(report)
    from ..report.html import write_html_report
    summary["report_html"] = str(write_html_report(report))
    write_json(out / "summary.json", summary)
    raise StudyFailed(f"{spec.path}: {message}; report {report}")


def _hinf_and_convex(spec, ub, g, plant_pzt, dt, delay_samples, delayed, freq, members, say):
    """Both optimal designs at a 200 Hz bandwidth target with W_m on T; errors are reported, not fatal."""
    from ..design.antiwindup import discretize
    from ..design.convex import youla_mixed_sensitivity
    from ..design.hinf import default_weights, mixed_sensitivity
    from ..design.margins import family_margins
    from ..linearize.sampled import firmware_plant
    out = {}
    target_hz = 200.0
    lim = spec.export["output_limits_v"]
    weights = default_weights(delayed, target_hz, ub.fit.weight, (float(lim[0]), float(lim[1])),
                              error_range_v=spec.export["input_range_v"])
    say("design: H-infinity", 0, 2)
    try:
        h = mixed_sensitivity(delayed, *weights, time_limit_s=spec.hinf["time_limit_s"])
        kd = discretize(h.controller, dt, min(max(h.crossover_hz, 1.0), 0.4 / dt))
        _, worst = family_margins(freq, _loops_discrete(kd, freq, members, delay_samples))
        out["hinf"] = {"gamma": h.gamma, "norms": h.closed_loop_norms, "meets_specs": h.meets_specs,
                       "crossover_hz": h.crossover_hz, "order": int(control.ss(h.controller).nstates),
                       "seconds": h.seconds, "worst_discrete": _worst_summary(worst)}
    except DesignError as err:
        out["hinf"] = {"error": str(err)}
    say("design: convex", 1, 2)
    try:
        # the creep branches put poles within 1e-7 of z = 1, which the FIR Youla parameter and the
        # reduction's bilinear map cannot resolve: the convex route designs on the plant without
        # them (integral action covers their slow drift) and is checked on the full family below
        from dataclasses import replace as _replace
        from ..linearize.small_signal import small_signal_model
        p_nc = small_signal_model(_replace(plant_pzt, creep=None), ub.nominal_capacitance_f)[0, 0]
        gz = firmware_plant(p_nc, g, 7.5e-6, delay_samples)
        c = youla_mixed_sensitivity(gz, *weights, taps=60)
        _, worst = family_margins(freq, _loops_discrete(c.controller, freq, members, delay_samples))
        out["convex"] = {"gamma": c.gamma, "norms": c.closed_loop_norms, "meets_specs": c.meets_specs,
                         "crossover_hz": c.crossover_hz, "order": c.order, "solver": c.solver,
                         "seconds": c.seconds, "worst_discrete": _worst_summary(worst)}
    except DesignError as err:
        out["convex"] = {"error": str(err)}
    say("design: convex", 2, 2)
    if "gamma" in out.get("hinf", {}) and "gamma" in out.get("convex", {}):
        out["cross_check"] = {"hinf_over_convex_stacked_norm": out["hinf"]["norms"].get("stacked", float("nan"))
                              / max(out["convex"]["norms"].get("stacked", float("nan")), 1e-300)}
    return out


def _nominal_margins(controller_d, nom, sensor):
    """Margins of the nominal loop through the study's sensor (design/nominal.py's definition for the gauge)."""
    from ..design.margins import margins_of
    from ..design.nominal import nominal_margins
    if sensor.kind == "gauge":
        return nominal_margins(controller_d, nom)
    loop = control.ss(controller_d) * sensor.discrete_plant(nom.firmware)
    return margins_of(loop, np.geomspace(0.1, 0.4999 / loop.dt, 4000))


def _provenance(spec, plant):
    import datetime
    import hashlib
    from importlib.metadata import version
    text = Path(plant.source).read_bytes()
    return {"plant_file": plant.source, "plant_sha256": hashlib.sha256(text).hexdigest(),
            "study": str(spec.path), "workbench_version": version("workbench"),
            "date": datetime.date.today().isoformat()}
