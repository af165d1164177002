"""The ``workbench verify`` job: scenarios, the issue's targets, predicted limit cycles, figures, report.

Every persistent oscillation a scenario shows is set beside the limit cycles the
describing-function analysis predicts for this controller on this plant (the loop of
:mod:`workbench.linearize.limit_cycle` over the PZT's describing functions at the
mid-stroke bias), so the report says whether the linear-plus-DF analysis saw it coming.
"""

import json
from pathlib import Path

import numpy as np

from ..errors import DataFileError
from ..plant import load_plant
from .closed_loop import controller_from_json
from .scenarios import SCENARIOS, run_scenario

__all__ = ["load_controller_json", "predicted_limit_cycles", "evaluate_targets", "run_verify"]

# the targets: (metric, limit, unit, sense) on plants/p888_51_sn637_creep.toml
TARGETS = {
    "triangle_0p1hz": ("error_rms_percent_of_stroke", 0.1, "% of stroke RMS", "max"),
    "hold": ("drift_m", 1e-9, "m", "abs_max"),
    "small_step": ("overshoot_difference_points", 3.0, "points of overshoot vs linear", "abs_max"),
    "large_step": ("oscillation_m", 1e-8, "m of persistent oscillation", "max"),
}
DF_AMPLITUDES_V = (0.05, 0.1, 0.3, 1.0, 3.0, 10.0)
DF_FREQ_HZ = tuple(np.geomspace(20.0, 4990.0, 28))


def load_controller_json(path, form=None, default_limits_v=None):
    """(json dict, FirmwareController) of an exported controller; DataFileError naming the file if not one."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        return data, controller_from_json(data, form, default_limits_v)
    except OSError as exc:
        raise DataFileError(f"{path}: cannot be read ({exc.strerror}); give an exported controller JSON, "
                            f"e.g. controllers/sn637_loopshape.json") from None
    except json.JSONDecodeError as exc:
        raise DataFileError(f"{path}: line {exc.lineno}: not JSON ({exc.msg}); give an exported controller JSON")
    except (ValueError, KeyError, TypeError) as exc:
        raise DataFileError(f"{path}: not an exported controller (missing or bad {exc}); export one with "
                            f"`workbench study`" + (f", or drop --form {form}" if form else "")) from None


def predicted_limit_cycles(plant, controller, bias_v=50.0):
    """Limit cycles the describing-function loop predicts (list of dicts: amplitude_v, freq_hz, stable)."""
    from ..linearize.limit_cycle import loop_responses, predict_limit_cycles
    from ..linearize.pzt_describing import pzt_describing_function
    from ..linearize.sampled import gauge_gain_v_per_m
    df = pzt_describing_function(plant.pzt, DF_AMPLITUDES_V, DF_FREQ_HZ, biases_v=(bias_v,))
    loops = loop_responses(controller.linear(), gauge_gain_v_per_m(7.5e-6, plant.gauge), df)
    cycles, _ = predict_limit_cycles(np.asarray(DF_AMPLITUDES_V), np.asarray(DF_FREQ_HZ), loops)
    return [{"amplitude_v": c.amplitude_v, "freq_hz": c.freq_hz, "stable": bool(c.stable)} for c in cycles]


def evaluate_targets(results):
    """{scenario: {metric, value, limit, unit, met}} for the scenarios run that carry a target."""
    out = {}
    for m in results:
        t = TARGETS.get(m["scenario"])
        if t is None or not (m.get("anti_windup", True)):
            continue
        key, limit, unit, sense = t
        value = m.get(key, float("nan"))
        met = bool(np.isfinite(value) and (abs(value) if sense == "abs_max" else value) <= limit)
        out[m["scenario"]] = {"metric": key, "value": value, "limit": limit, "unit": unit, "met": met}
    return out


def run_verify(plant_path, controller_path, scenarios=SCENARIOS, hold_s=1000.0, noise=True, anti_windup=True,
               form=None, out_dir=None, progress=None):
    """Run the scenarios; write figures and report.md into ``out_dir`` (if given); return the summary."""
    plant = load_plant(plant_path)
    # a bare controller (gain, sos) gets the amplifier's range as its output limits
    data, ctrl = load_controller_json(controller_path, form, (plant.pzt.voltage_min_v, plant.pzt.voltage_max_v))
    say = progress or (lambda *a: None)
    steps = list(scenarios) + ["limit cycles"]
    results, traces_all = [], {}
    for i, name in enumerate(scenarios):
        say("verify", i, len(steps))
        m, tr = run_scenario(plant, ctrl, name, hold_s=hold_s, anti_windup=anti_windup, noise=noise)
        results.append(m)
        traces_all[name] = (m, tr)
    if "large_step" in scenarios and anti_windup:
        # the report shows the same step without the anti-windup (the issue asks for it)
        m, tr = run_scenario(plant, ctrl, "large_step", anti_windup=False, noise=noise)
        m["scenario"] = "large_step_no_anti_windup"
        results.append(m)
        traces_all["large_step_no_anti_windup"] = (m, tr)
    say("verify", len(scenarios), len(steps))
    cycles = predicted_limit_cycles(plant, ctrl)
    for m in results:
        if "oscillation_m" in m:
            m["predicted_limit_cycles"] = cycles
    say("verify", len(steps), len(steps))
    summary = {"plant": str(plant_path), "controller": str(controller_path), "controller_name": data.get("name"),
               "controller_form": ctrl.describe(), "noise": noise, "anti_windup": anti_windup,
               "predicted_limit_cycles": cycles, "targets": evaluate_targets(results), "scenarios": results}
    if out_dir is not None:
        summary.update(_write_outputs(Path(out_dir), summary, traces_all))
    return summary


def _write_outputs(out, summary, traces_all):
    from ..report import write_json
    from ..report.verify_figures import plot_scenario
    from ..report.verify_report import write_verify_report
    figures = {}
    for name, (m, tr) in traces_all.items():
        if name == "large_step_no_anti_windup":
            continue
        companion = traces_all.get("large_step_no_anti_windup") if name == "large_step" else None
        figures[name] = str(plot_scenario(m, tr, out / f"{name}.png", companion=companion).name)
    header = {"plant": summary["plant"], "controller": summary["controller"],
              "controller_form": summary["controller_form"],
              "targets": {k: (v["value"], v["limit"], v["unit"], v["met"]) for k, v in summary["targets"].items()}}
    results = [{"metrics": m, "figure": figures.get(m["scenario"])} for m in summary["scenarios"]]
    report = write_verify_report(out / "report.md", header, results)
    from ..report.html import write_html_report
    write_html_report(report)
    write_json(out / "verify.json", {**summary, "figures": figures})
    return {"figures": figures, "report": str(report)}
