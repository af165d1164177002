"""The ``workbench linearize`` job: every linear view of a plant, as one JSON-ready result.

Reads the plant (and the other serials of the family), computes the describing
functions, small-signal models, the sampled gauge chain, the uncertainty bound and,
with a controller, the describing-function loop analysis; figures go to ``out_dir``.
"""

from pathlib import Path

import control
import numpy as np

from ..plant import load_plant
from .describing import pi_df
from .limit_cycle import load_controller, loop_responses, predict_limit_cycles
from .pzt_describing import pzt_describing_function
from .sampled import firmware_plant, gauge_gain_v_per_m
from .small_signal import BRANCHES, capacitances, dc_gain_m_per_v, operating_point, small_signal_model
from .uncertainty import FamilySpec, plant_family, uncertainty_bound

__all__ = ["run_linearize", "check_amplitudes"]


def check_amplitudes(pzt, amplitudes_v, *, name="amplitudes_v", where="the plant"):
    """Refuse a sine amplitude the amplifier cannot drive: the one home of the (0, span] V range.

    Parameters
    ----------
    pzt : PZTParams
        The stack (``plant.pzt``); its amplifier range ``voltage_min_v``..``voltage_max_v`` sets the span, V.
    amplitudes_v : iterable of float
        Sine amplitudes, V.
    name : str
        The flag or key named in the message (``--amplitudes``, ``[family.amplitudes_v]``).
    where : str
        The plant file named in the message.

    Raises
    ------
    FlagRangeError
        If an amplitude is not finite or outside (0, voltage_max_v - voltage_min_v] V.
    """
    from ..errors import FlagRangeError
    span = pzt.voltage_max_v - pzt.voltage_min_v
    for a in amplitudes_v:
        a = float(a)
        if not (np.isfinite(a) and 0.0 < a <= span):
            raise FlagRangeError(f"{name} {a:g} V: out of range (0, {span:g}] V (the amplifier's "
                                 f"{pzt.voltage_min_v:g}..{pzt.voltage_max_v:g} V span of {where}); e.g. 50V")


def _poles_hz(sys):
    return sorted(float(abs(p) / (2 * np.pi)) for p in sys.poles())


def _small_signal_rows(pzt, biases_v, v_range):
    rows, models = [], {}
    for bias in biases_v:
        for branch in BRANCHES:
            op = operating_point(pzt, bias, branch, v_range)
            ss = small_signal_model(pzt, op.capacitance_f)
            c_series = 1.0 / (1.0 / op.capacitance_f + 1.0 / pzt.c_pp_f)
            rows.append({"branch": branch, "bias_v": bias, "capacitance_f": op.capacitance_f,
                         "dc_gain_m_per_v": dc_gain_m_per_v(pzt, op.capacitance_f), "poles_hz": _poles_hz(ss),
                         "electrical_pole_hz": (1.0 / (2 * np.pi * pzt.series_resistance_ohm * c_series)
                                                if pzt.series_resistance_ohm > 0 else None),
                         "x0_m": op.x_m, "v_h_v": op.v_h_v})
            models[(branch, bias)] = ss
    return rows, models


def run_linearize(plant_path, serial_paths=(), controller_path=None, spec=FamilySpec(), out_dir=None,
                  delay_samples=1, progress=None, allow_unstable=False):
    """Linearize ``plant_path``; the family spans it and ``serial_paths``. Returns the JSON dict.

    ``allow_unstable``: analyse a controller with poles on or outside the unit circle (an
    analysis run may study one; verify and export refuse it).
    """
    from ..report.linearize_figures import (plot_capacitances, plot_df_bode, plot_nyquist, plot_sampled,
                                            plot_uncertainty)
    plant = load_plant(plant_path)
    others = [load_plant(p) for p in serial_paths if Path(p).resolve() != Path(plant_path).resolve()]
    pzt, g = plant.pzt, plant.gauge
    freq = np.asarray(spec.freq_hz, dtype=float)

    def stage(name):
        return None if progress is None else (lambda d, t: progress(name, d, t))

    df = pzt_describing_function(pzt, spec.amplitudes_v, freq, (spec.bias_v,), progress=stage("describing functions"))
    rows, models = _small_signal_rows(pzt, spec.small_signal_biases_v, spec.v_range)
    caps = capacitances(pzt, spec.bias_v, spec.v_range)
    q_op = pzt.terminal_operator().inverse()       # quasi-static V -> q_h, the hysteresis alone
    hyst_df = pi_df(q_op, np.asarray(spec.amplitudes_v))

    x0 = 0.5 * sum(spec.x0_range_m)
    k_g = gauge_gain_v_per_m(x0, g)
    family = plant_family([plant] + others, spec, progress=stage("uncertainty family"))
    ub = uncertainty_bound(family, plant)
    fw = firmware_plant(ub.nominal * (1.0 / ub.nominal_gauge_v_per_m), g, x0, delay_samples)

    result = {
        "plant": str(plant_path), "serial": plant.serial, "family": [str(plant_path)] + [str(p) for p in serial_paths],
        "df": df.records(),
        "df_summary": {"points": int(df.x_m_per_v.size), "current_saturated": int(df.saturated.sum()),
                       "voltage_clipped": int(df.clipped.sum()), "not_periodic": int((~df.periodic).sum()),
                       "subharmonic": int(df.subharmonic.sum()),
                       "max_thd_x_linear": float(np.nanmax(np.where(df.linear_ok, df.thd_x, np.nan)))},
        "hysteresis_df": [{"amplitude_v": float(a), "mag_c_per_v": float(abs(n)),
                           "phase_deg": float(np.degrees(np.angle(n)))}
                          for a, n in zip(spec.amplitudes_v, hyst_df)],
        "small_signal": rows,
        "capacitances": caps,
        "gauge": {"volts_per_meter": k_g, "x0_m": x0, "sample_rate_hz": g.modulation_hz,
                  "delay_samples": delay_samples,
                  "timing": "reading at t_k = mean of x over (t_k-1, t_k]; output from reading k applied at "
                            "t_k+delay and held",
                  "volts_per_meter_by_serial": {s: {"nominal": v[0], "min": v[1], "max": v[2]}
                                                for s, v in family.gauge_gains.items()},
                  "firmware_plant": {"dt_s": float(fw.dt), "states": int(fw.nstates),
                                     "dc_gain_v_per_v": float(np.real(control.dcgain(fw))),
                                     "poles": [[float(p.real), float(p.imag)] for p in fw.poles()]}},
        "uncertainty": {
            "weight": {"zeros_hz": list(ub.fit.zeros_hz), "poles_hz": list(ub.fit.poles_hz),
                       "gain": ub.fit.gain, "order": ub.fit.order},
            "coverage_margin_db": ub.coverage.margin_db, "worst_member": ub.coverage.member,
            "worst_freq_hz": ub.coverage.freq_hz, "tightness_db": ub.fit.tightness_db,
            "nominal": {"serial": plant.serial, "capacitance_f": ub.nominal_capacitance_f,
                        "gauge_v_per_m": ub.nominal_gauge_v_per_m,
                        "dc_gain_v_per_v": float(np.real(control.dcgain(ub.nominal))),
                        "poles_hz": _poles_hz(ub.nominal)},
            "members": len(ub.deltas), "excluded_points": family.excluded_points,
            "excluded_because": "current saturation (slewing), clipping or no periodic response",
            "envelope": [{"freq_hz": float(f), "max_rel_dev": float(e)} for f, e in zip(freq, ub.envelope)],
            "spec": {"amplitudes_v": list(spec.amplitudes_v), "bias_v": spec.bias_v,
                     "cp_tolerance": spec.cp_tolerance, "imbalance_tolerance_ohm": spec.imbalance_tolerance_ohm,
                     "x0_range_m": list(spec.x0_range_m)},
        },
        "figures": {},
    }
    if controller_path is not None:
        ctrl = load_controller(controller_path, allow_unstable=allow_unstable)
        if abs(ctrl.dt - g.period_s) > 1e-12 * g.period_s:
            from ..errors import DataFileError
            raise DataFileError(f"{controller_path}: sample rate {1 / ctrl.dt:g} Hz differs from the servo rate "
                                f"{g.modulation_hz:g} Hz of {plant_path}; export the controller at the servo rate")
        loops = loop_responses(ctrl, k_g, df, delay_samples=delay_samples)
        cycles, crossings = predict_limit_cycles(df.amplitudes_v, freq, loops)
        result["controller"] = {"path": str(controller_path), "limit_cycles": [
            {"amplitude_v": c.amplitude_v, "freq_hz": c.freq_hz, "stable": c.stable,
             "x_mean_shift_m": float(np.interp(np.log(c.amplitude_v), np.log(df.amplitudes_v),
                                               [np.interp(np.log(c.freq_hz), np.log(freq), row)
                                                for row in df.x_mean_shift_m[0]]))}
            for c in cycles],
            "phase_crossovers": [{"amplitude_v": float(a), "freq_hz": f, "loop_gain": m}
                                 for a, (f, m) in zip(df.amplitudes_v, crossings)]}
    if out_dir is not None:
        out = Path(out_dir)
        figs = result["figures"]
        figs["df_bode"] = str(plot_df_bode(df, models, spec.bias_v, out / "df_bode.png"))
        figs["capacitances"] = str(plot_capacitances(pzt, caps, spec, out / "capacitances.png"))
        figs["uncertainty"] = str(plot_uncertainty(family.freq_hz, ub, out / "uncertainty.png"))
        figs["sampled"] = str(plot_sampled(ub.nominal, fw, out / "sampled.png"))
        if controller_path is not None:
            figs["nyquist"] = str(plot_nyquist(ctrl, fw, df, loops, ub, result["controller"], out / "nyquist.png"))
    return result
