"""Design budgets derived from the plant: the gauge-noise command budget, the current-limit window, slew limits.

The amplifier's current limits and the series resistor R set what the controller may
ask of the stack:

- **current-limit window**: firmware models the stack voltage as the RC response to its
  output at the largest terminal capacitance and keeps the command within
  [v - R I_sink, v + R I_source] (:func:`~.antiwindup.current_limit_model`); with the
  series resistor out, within [u_last - I_sink T / C, u_last + I_source T / C];
- **slew limits**: I_source / C and I_sink / C at that capacitance, V/s
  (:func:`~.antiwindup.rate_limits_v_per_s`);
- **noise budget**: the gauge noise passed to the command through K S makes the command
  lead the modelled stack voltage by u - v; that lead over R is current asked of the
  amplifier. Noise that reaches the smaller of the two limits is rectified by their
  asymmetry into a position bias (the verification issue found this), so the budget is
  R min(I_source, I_sink) / k with k = 3 (the limit at 3 sigma of a Gaussian lead):
  80 ohm x 2 mA / 3 = 53 mV for the flight amplifier, 533 mV for a +/-20 mA one. With the
  series resistor out the window is a slew of I T / C a sample around the last output
  (alpha = 1) and the lead is the command's change per sample: the budget is
  min(I_source, I_sink) T / (k C), 2 mA x 0.1 ms / (11.9 uF x 3) = 5.6 mV for SN637. Measured
  (benchmarks/logs/s38_phys, `verify` with gauge noise on SN637 with creep, R out): the
  design without it (crossover 246-548 Hz, 51 mV of command change per sample) had the window
  hold 52 % of the 0.1 Hz triangle's samples and tracked it to 11.8 nm RMS; with it (65-145 Hz)
  0.06 % and 4.5 nm.

A study may override each (``loop_shape.max_noise_command_v``); the result says which
value was used and where it came from.
"""

from dataclasses import dataclass

__all__ = ["Budget", "NOISE_SIGMAS", "plant_budgets", "reading_noise_budget", "tracking_budget"]

NOISE_SIGMAS = 3.0     # the noise lead stays below the current limit at this many sigma


@dataclass(frozen=True)
class Budget:
    """One budget: its value (SI, ``unit``), ``source`` ("plant" or "study") and how it was derived."""

    name: str
    value: object
    unit: str
    source: str
    derivation: str

    def as_dict(self):
        v = self.value
        return {"name": self.name, "value": list(v) if isinstance(v, tuple) else v, "unit": self.unit,
                "source": self.source, "derivation": self.derivation}


def plant_budgets(plant, dt_s, noise_override_v=None, study_path=None):
    """The budgets of ``plant`` (a loaded Plant) at the servo period ``dt_s``.

    Parameters
    ----------
    plant : Plant
    dt_s : float
        Servo period, s.
    noise_override_v : float, optional
        ``loop_shape.max_noise_command_v`` from the study: used instead of the derived budget.
    study_path : str, optional
        Named in the override's derivation.

    Returns
    -------
    dict of str to Budget
        ``noise_command_v`` (with R = 0, min(I_source, I_sink) T / (3 C): the slew window's smaller headroom
        at 3 sigma; None for an amplifier without a current limit),
        ``current_window`` (alpha, headroom up V, headroom down V), ``slew_v_per_s`` (up, down).
    """
    from .antiwindup import _largest_capacitance_f, current_limit_model, rate_limits_v_per_s
    pzt = plant.pzt
    r = pzt.series_resistance_ohm
    i_src, i_snk = pzt.current_limit_source_a, pzt.current_limit_sink_a
    src = f"{plant.source}"
    model = current_limit_model(pzt, dt_s)
    c = _largest_capacitance_f(pzt)
    if noise_override_v is not None:
        would = (f"R min(I_source, I_sink) / {NOISE_SIGMAS:g} = {r * min(i_src, i_snk) / NOISE_SIGMAS:.4g} V" if r > 0
                 else "no budget" if model is None else
                 f"min(I_source, I_sink) T / ({NOISE_SIGMAS:g} C) = {min(model[1:]) / NOISE_SIGMAS:.4g} V")
        noise = Budget("noise_command_v", float(noise_override_v), "V RMS", "study",
                       f"`loop_shape.max_noise_command_v = {noise_override_v:g}` V in {study_path} (the plant would "
                       f"give {would})")
    elif not r > 0 and model is not None:
        # the series resistor out: the window is a slew of I T / C a sample around the last output (alpha 1), so
        # the lead that noise puts on the command is its change per sample; at 3 sigma within the smaller headroom
        noise = Budget("noise_command_v", min(model[1:]) / NOISE_SIGMAS, "V RMS", "plant",
                       f"series resistor out (R = 0): min(I_source, I_sink) T / ({NOISE_SIGMAS:g} C) = "
                       f"{min(i_src, i_snk) * 1e3:g} mA x {dt_s:g} s / ({NOISE_SIGMAS:g} x {c * 1e6:.4g} uF), the "
                       f"smaller headroom of the slew window at {NOISE_SIGMAS:g} sigma (`current_limit_source_a`/"
                       f"`current_limit_sink_a` of {src}, C the largest terminal capacitance)")
    elif r > 0:
        noise = Budget("noise_command_v", r * min(i_src, i_snk) / NOISE_SIGMAS, "V RMS", "plant",
                       f"R min(I_source, I_sink) / {NOISE_SIGMAS:g} = {r:g} ohm x {min(i_src, i_snk) * 1e3:g} mA / "
                       f"{NOISE_SIGMAS:g} (`electrical.series_resistor_ohm`, `current_limit_source_a`/`current_limit_sink_a` of {src})")
    else:
        noise = Budget("noise_command_v", None, "V RMS", "plant",
                       f"no current limit in {src}: no current-limit window, no noise budget")
    if model is None:
        window = Budget("current_window", None, "(1, V, V)", "plant",
                        f"no current limit in {src}: no window")
    elif not r > 0:
        alpha, h_up, h_down = model
        window = Budget("current_window", model, "(1, V, V)", "plant",
                        f"series resistor out in {src} (R = 0): a slew window around the last output, alpha = 1, "
                        f"headroom I_source T / C = {h_up:.4g} V up, I_sink T / C = {h_down:.4g} V down; "
                        f"C = {c * 1e6:.4g} uF (largest terminal capacitance), T = {dt_s:g} s")
    else:
        alpha, h_up, h_down = model
        window = Budget("current_window", model, "(1, V, V)", "plant",
                        f"alpha = 1 - exp(-T / (R C)), headroom R I_source = {h_up:.4g} V up, R I_sink = {h_down:.4g} "
                        f"V down; R = {r:g} ohm, C = {c * 1e6:.4g} uF (largest terminal capacitance), T = {dt_s:g} s")
    up, down = rate_limits_v_per_s(pzt)
    slew = Budget("slew_v_per_s", (up, down), "V/s", "plant",
                  f"I_source / C = {i_src * 1e3:g} mA / {c * 1e6:.4g} uF, I_sink / C = {i_snk * 1e3:g} mA / "
                  f"{c * 1e6:.4g} uF")
    return {"noise_command_v": noise, "current_window": window, "slew_v_per_s": slew}


def reading_noise_budget(sensor, gauge_reading_v):
    """RMS noise of one reading in firmware V, the noise the command budget is checked against, with its derivation.

    Parameters
    ----------
    sensor : workbench.study.sensor.SensorModel
    gauge_reading_v : float
        One gauge reading's noise, firmware V (:func:`~workbench.plant.gauge.demod_noise_sigma_v`
        times the trim scale): the gauge sensor's value, unchanged.
    """
    n = sensor.noise_m
    k = sensor.gauge_v_per_m
    if sensor.kind == "gauge":
        return Budget("reading_noise_v", float(gauge_reading_v), "V RMS", "plant",
                      f"gauge chain: demodulated reading noise x trim scale = {gauge_reading_v:.4g} V "
                      f"(`gauge.noise_rms_m` = {n['gauge'] * 1e9:.3g} nm)")
    if sensor.kind == "charge":
        return Budget("reading_noise_v", n["reading"] * k, "V RMS", "plant",
                      f"charge estimate (stage 4): sigma_c K_g = {n['charge'] * 1e9:.3g} nm x {k:.4g} V/m = "
                      f"{n['reading'] * k:.4g} V (simulated hold at 50 V; its drift is not noise and is not counted)")
    b = sensor.blend
    a = b.pole
    return Budget("reading_noise_v", n["reading"] * k, "V RMS", "plant",
                  f"fused: sqrt(sigma_g^2 (1 - a)/(1 + a) + sigma_c^2 2 a^2/(1 + a)) K_g with sigma_g = "
                  f"{n['gauge'] * 1e9:.3g} nm, sigma_c = {n['charge'] * 1e9:.3g} nm, a = exp(-2 pi f_b T) = {a:.6f} "
                  f"(blend f_b = {b.crossover_hz:.3g} Hz from {sensor.crossover_source}), K_g = {k:.4g} V/m: "
                  f"{n['reading'] * 1e9:.3g} nm = {n['reading'] * k:.4g} V (the white noise each path passes; "
                  f"conservative: the low-passed gauge noise is counted as if white)")


def tracking_budget(triangle_hz, target_percent, sensor, fc_min_hz):
    """The triangle's tracking-error budget, fraction of stroke RMS: the target less the sensor's own error.

    The error of the true x is the loop's tracking error (reading - reference) plus the sensor's
    error (reading - x), independent: RMS^2 adds. The sensor's share is its error RMS over the band
    of the spectra (fused or charge: :mod:`workbench.selfsense.fusion`); for the gauge, its white
    noise up to the lowest crossover searched, sigma_g sqrt(2 f_c,min T) (a lower bound: the loop
    passes it up to its own crossover). None value when the sensor alone exceeds the target.
    """
    target = target_percent / 100.0
    if sensor.kind == "gauge":
        e_m = sensor.noise_m["gauge"] * (2 * fc_min_hz * sensor.dt_s) ** 0.5
        how = (f"gauge noise below the lowest searched crossover, sigma_g sqrt(2 f_c,min T) = "
               f"{sensor.noise_m['gauge'] * 1e9:.3g} nm x sqrt(2 x {fc_min_hz:g} Hz x {sensor.dt_s:g} s)")
        stroke = None
    else:
        key = "fused_error_rms_m" if sensor.kind == "fused" else "charge_error_rms_m"
        e_m = sensor.spectra[key]
        lo, hi = sensor.spectra["band_hz"]
        how = f"{sensor.kind} error RMS over {lo:.2g}-{hi:.4g} Hz (spectra)"
        stroke = sensor.stroke_m
    if stroke is None or not stroke == stroke:
        stroke = STROKE_M
        stroke_how = f"{STROKE_M * 1e6:.3g} um (SN637 staircase 0-100 V, assumed)"
    else:
        stroke_how = f"{stroke * 1e6:.4g} um (p-p of the simulated 0-100 V staircase)"
    share = e_m / stroke
    value = (target ** 2 - share ** 2) ** 0.5 if share < target else None
    derivation = (f"sqrt(target^2 - e_s^2): target {target_percent:g} % of stroke, sensor share e_s = {how} = "
                  f"{e_m * 1e9:.3g} nm / {stroke_how} = {100 * share:.3g} %"
                  + (f" -> tracking RMS <= {100 * value:.3g} % for the {triangle_hz:g} Hz triangle (10-90 % of stroke)"
                     if value is not None else ": the sensor alone misses the target; no tracking budget"))
    return Budget("triangle_tracking", value, "fraction of stroke RMS", "study", derivation)


STROKE_M = 15.58e-6    # m: SN637's 0-100 V staircase p-p (selfsense drift record); the gauge study's fallback
