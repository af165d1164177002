"""The study's feedback sensor (``[sensor] kind = "gauge" | "charge" | "fused"``): its noise and its loop path.

- **gauge** (default): the gauge chain alone; the study is what it always was (the family's
  members are the loops' plants as they are).
- **charge**: the compensated charge estimate of :mod:`workbench.selfsense` (stage 4 static
  estimate, E(z) for its dynamics) alone: quiet (0.27 nm per sample on SN637) but drifting.
- **fused**: the complementary blend of :mod:`workbench.selfsense.fusion`, the gauge through
  F_low(z), the charge estimate through F_high(z) = 1 - F_low(z); its crossover is chosen by
  :func:`~workbench.selfsense.fusion.choose_crossover` from the two sensors' error spectra
  (the gauge's white noise, the charge's white noise and the Welch spectrum of its stage-4
  error over a staircase record), unless ``sensor.blend_crossover_hz`` gives it.

The sensors are simulated on the nominal plant as ``workbench selfsense --fused`` does (the
same records, seeds and functions): the estimator identified on a 700 s identification
record, the noise per 10 kHz sample on a hold at 50 V (:func:`~workbench.selfsense.run.noise_comparison`),
the drift on a ``drift_record_s`` staircase. That costs ~25 s and is cached beside the family.

**Loop path of each member.** The search multiplies C(z) by the sampled gauge chain (hold,
period average, compute delay: :func:`~workbench.linearize.limit_cycle.sampled_factor`) and
the member G_i = K_g,i P_i. The charge path of the nominal, from the self-sensing model
(:func:`~workbench.selfsense.run.loop_analysis`: V_pea -> V_t through the 80 ohm -> the true
charge-amplifier circuit -> the static estimate -> E(z), DAC hold, one sample of delay),
relative to the gauge path of the same small-signal plant is

    R(f) = delay(f) E_d(e^{jwT}) [x_hat / V_pea](jw) hold(f) / (x / V_pea (jw) sampled_factor(f)).

Each member's fused loop is taken as C sampled_factor G_i (F_low + F_high R K_g,nom / K_g,i):
the charge estimate tracks each member's displacement with the nominal's dynamics (the estimator
is identified on the stack it runs on) and does not pass through the gauge chain, so its gain is
the nominal firmware gain, not the member's K_g extreme. For ``charge``, F_low = 0.
"""

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["SensorModel", "sensor_model", "apply_sensor"]

DEFAULT_DRIFT_RECORD_S = 1000.0
DEFAULT_SEED = 2
BIAS_V = 50.0


@dataclass(frozen=True)
class SensorModel:
    """The feedback sensor of a study (module docstring).

    Attributes
    ----------
    kind : {"gauge", "charge", "fused"}
    dt_s : float
        Servo period, s.
    gauge_v_per_m : float
        Nominal firmware gain of the gauge chain at mid-stroke, V/m (the controller's input units).
    noise_m : dict
        RMS noise per reading, m: ``gauge`` (the plant file's chain, simulated), ``charge``
        (stage-4 estimate), ``reading`` (the sensor's own: fused white-equivalent for "fused").
    blend : Blend or None
        The complementary pair ("fused" only).
    crossover_source : str or None
        "spectra" (chosen from them) or "study" (``sensor.blend_crossover_hz``).
    spectra : dict
        Error RMS over the record's band, m: ``gauge``, ``charge``, ``fused``, and ``band_hz``,
        ``drift_record_s``, ``drift_pp_m`` (empty for "gauge").
    stroke_m : float
        p-p true displacement of the staircase record, m (NaN for "gauge").
    """

    kind: str
    dt_s: float
    gauge_v_per_m: float
    noise_m: dict
    blend: object = None
    crossover_source: str = None
    spectra: dict = field(default_factory=dict)
    stroke_m: float = float("nan")
    _systems: dict = field(default=None, repr=False)

    def charge_ratio(self, freq_hz):
        """R(f) of the module docstring: the charge path over the gauge path of the nominal, complex."""
        from ..design.margins import response
        from ..linearize.limit_cycle import sampled_factor
        f = np.asarray(freq_hz, dtype=float)
        s = self._systems
        wt = 2 * np.pi * f * self.dt_s
        hold = np.where(wt > 0, (1 - np.exp(-1j * wt)) / (1j * np.where(wt > 0, wt, 1.0)), 1.0)
        delay = np.exp(-1j * wt)
        est = response(s["E_d"], f) * response(s["sensor"], f) / response(s["E"], f)
        return delay * est * hold / (response(s["x_of_vpea"], f) * sampled_factor(f, self.dt_s, 1))

    def factor(self, freq_hz, gain_ratio=1.0):
        """Member response multiplier: F_low + F_high R K_g,nom / K_g,i (``gain_ratio`` = K_g,i / K_g,nom)."""
        f = np.asarray(freq_hz, dtype=float)
        if self.kind == "gauge":
            return np.ones(f.shape, complex)
        charge = self.charge_ratio(f) / gain_ratio
        if self.kind == "charge":
            return charge
        z = np.exp(2j * np.pi * f * self.dt_s)
        a = self.blend.pole
        f_low = (1 - a) * z / (z - a)
        return f_low + (1 - f_low) * charge

    def discrete_plant(self, nominal_firmware):
        """The sampled plant as the controller sees it through this sensor, discrete StateSpace.

        ``nominal_firmware``: the gauge chain's sampled nominal (hold, average, delay), firmware V
        per V. The charge path is the self-sensing model's V_pea -> x_hat held by the DAC (ZOH),
        one sample of delay, times K_g; fused: F_low(z) gauge + F_high(z) charge.
        """
        import control

        from ..linearize.sampled import compute_delay
        if self.kind == "gauge":
            return control.ss(nominal_firmware)
        dt = self.dt_s
        charge = (compute_delay(dt, 1) * control.ss(control.c2d(control.ss(self._systems["sensor"]), dt, "zoh"))
                  * self.gauge_v_per_m)
        if self.kind == "charge":
            return charge
        lo, hi = control.ss(self.blend.low_d()), control.ss(self.blend.high_d())
        return control.ss(lo * control.ss(nominal_firmware) + hi * charge)

    def record(self):
        """The sensor block an exported controller carries (firmware needs it to form its input)."""
        if self.kind == "gauge":
            return {"kind": "gauge", "input": "K_g (reference - gauge reading), firmware V"}
        out = {"kind": self.kind, "input": f"K_g (reference - {self.kind} reading), firmware V, K_g = "
                                           f"{self.gauge_v_per_m:.6g} V/m (the gauge chain's nominal gain)",
               "charge_estimate": "stage-4 static estimate and E(z) of workbench.selfsense (identified on the stack)"}
        if self.kind == "fused":
            from ..selfsense.blend_fixed import FixedBlend
            fb = FixedBlend(self.blend)
            out["blend"] = {"crossover_hz": self.blend.crossover_hz, "pole": self.blend.pole,
                            "source": self.crossover_source,
                            "form": "fused = charge + (1 - a)/(1 - a z^-1) (gauge - charge)",
                            "fixed_point": {"lsb_m": fb.lsb_m, "frac_bits": fb.frac_bits, "coef_bits": fb.coef_bits,
                                            "k": fb.k, "header": "the controller's own NAME.h (NAME_sensor_step)"}}
        return out

    def firmware_setup(self, plant):
        """The :class:`workbench.verify.sensors.SensorSetup` of this sensor on ``plant`` (the nominal it was
        simulated on): the study's own identified estimator, charge amplifier and E(z), so firmware's startup
        settings (:func:`workbench.verify.sensors.with_firmware_startup`) come from the records the design used,
        without identifying again. For "gauge" the plant alone (the gauge's settings need no charge channel)."""
        from ..verify.sensors import SensorSetup
        if self.kind == "gauge":
            return SensorSetup(plant, None, None, None, {})
        s = self._systems
        return SensorSetup(plant, s["ident"], s["amp"], s["E_d"], {})

    def reading_noise_v(self):
        """RMS noise of one reading in the controller's input units (firmware V)."""
        return self.noise_m["reading"] * self.gauge_v_per_m

    def as_dict(self):
        b = self.blend
        return {"kind": self.kind, "noise_per_reading_m": dict(self.noise_m),
                "blend": None if b is None else {"crossover_hz": b.crossover_hz, "pole": b.pole,
                                                 "source": self.crossover_source,
                                                 "form": "fused = charge + (1 - a)/(1 - a z^-1) (gauge - charge)"},
                "error_rms_m": dict(self.spectra), "stroke_m": self.stroke_m,
                "member_path": None if self.kind == "gauge" else
                ("C sampled_factor G_i (F_low + F_high R K_g,nom / K_g,i)" if self.kind == "fused"
                 else "C sampled_factor G_i R K_g,nom / K_g,i")}


def _records(plant, seed, drift_record_s):
    """The expensive part (identification, noise, drift spectrum), the same calls as ``selfsense --fused``."""
    from ..selfsense.charge_amp import charge_amp_params
    from ..selfsense.fusion import (choose_crossover, drift_record, fused_error_variance, fused_noise_rms_per_sample,
                                    sensor_spectra)
    from ..selfsense.identify import identify, simulate_identification
    from ..selfsense.run import noise_comparison
    amp = charge_amp_params(plant)          # the plant file's [leakage] / [dielectric_absorption] when given
    dt = plant.gauge.period_s
    idrec = simulate_identification(plant.pzt, amp, hold_s=700.0, seed=seed + 100, dt_s=dt)
    ident = identify(idrec, amp)
    t_d, e_d, stroke = drift_record(plant, amp, ident, duration_s=drift_record_s, dt_s=dt, seed=seed)
    noise = noise_comparison(plant, ident, amp, seed=seed, dt_s=dt)
    sp = sensor_spectra(noise["gauge_rms_m"], noise["self_rms_m"], dt, t_d, e_d)
    fc = choose_crossover(sp)

    def rms(psd):
        return float(np.sqrt(np.trapezoid(psd, sp.freq_hz)))
    return {"ident": ident, "amp": amp, "gauge_rms_m": noise["gauge_rms_m"], "charge_rms_m": noise["self_rms_m"],
            "crossover_hz": fc, "stroke_m": stroke, "spectra": sp,
            "gauge_error_rms_m": rms(sp.gauge_m2_per_hz), "charge_error_rms_m": rms(sp.charge_m2_per_hz),
            "fused_error_rms_m": float(np.sqrt(fused_error_variance(sp, fc))),
            "fused_noise_rms_m": fused_noise_rms_per_sample(sp, fc), "band_hz": [float(sp.freq_hz[0]),
                                                                                float(sp.freq_hz[-1])],
            "drift_record_s": float(t_d[-1]), "drift_pp_m": float(np.ptp(e_d))}


def _selfsense_digest():
    import workbench
    h = hashlib.sha256()
    for p in sorted((Path(workbench.__file__).parent / "selfsense").glob("*.py")):
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def sensor_model(plant, plant_paths, plant_overrides, sensor_spec, gauge_v_per_m, cache_dir=None, progress=None):
    """The :class:`SensorModel` of a study's ``[sensor]`` table (``sensor_spec``) on ``plant``.

    Parameters
    ----------
    plant : Plant
        The nominal plant (the sensors are simulated on it).
    plant_paths, plant_overrides
        Name the cache entry (with the selfsense code and the sensor settings).
    sensor_spec : dict
        ``kind``, optional ``blend_crossover_hz``, ``drift_record_s``, ``seed``.
    gauge_v_per_m : float
        Nominal firmware gain of the gauge chain, V/m.
    cache_dir : path or None
        The study's family cache folder (None: no cache).
    """
    from ..selfsense.fusion import Blend, fused_noise_rms_per_sample
    from .cache import cached_family, family_key
    kind = sensor_spec.get("kind", "gauge")
    dt = plant.gauge.period_s
    if kind == "gauge":
        sigma = float(plant.gauge.noise_rms_m)
        return SensorModel("gauge", dt, gauge_v_per_m, {"gauge": sigma, "reading": sigma})
    seed = int(sensor_spec.get("seed", DEFAULT_SEED))
    drift_s = float(sensor_spec.get("drift_record_s", DEFAULT_DRIFT_RECORD_S))
    key = family_key(plant_paths, plant_overrides, ("sensor records", seed, drift_s),
                     extra=(_selfsense_digest(),))
    say = progress or (lambda *a: None)
    say("sensor: records", 0, 1)
    rec, _, _ = cached_family(key, cache_dir, lambda: _records(plant, seed, drift_s), prefix="sensor")
    say("sensor: records", 1, 1)
    systems = _systems(plant, rec["ident"], rec["amp"])
    noise = {"gauge": rec["gauge_rms_m"], "charge": rec["charge_rms_m"]}
    spectra = {k: rec[k] for k in ("gauge_error_rms_m", "charge_error_rms_m", "band_hz", "drift_record_s",
                                   "drift_pp_m")}
    blend, source = None, None
    if kind == "fused":
        fc = sensor_spec.get("blend_crossover_hz")
        source = "spectra" if fc is None else "study"
        blend = Blend(rec["crossover_hz"] if fc is None else float(fc), dt)
        noise["reading"] = fused_noise_rms_per_sample(rec["spectra"], blend.crossover_hz)
        spectra["fused_error_rms_m"] = (rec["fused_error_rms_m"] if fc is None else _fused_rms(rec["spectra"], fc))
        spectra["crossover_from_spectra_hz"] = rec["crossover_hz"]
    else:
        noise["reading"] = rec["charge_rms_m"]
    return SensorModel(kind, dt, gauge_v_per_m, noise, blend, source, spectra, rec["stroke_m"], systems)


def _fused_rms(spectra, fc):
    from ..selfsense.fusion import fused_error_variance
    return float(np.sqrt(fused_error_variance(spectra, fc)))


def _systems(plant, ident, amp):
    """E, E_d and the V_pea -> x_hat path of :func:`~workbench.selfsense.run.loop_analysis` (one home), x / V_pea."""
    from ..linearize.small_signal import operating_point, small_signal_model
    from ..selfsense.run import DEFAULT_CONTROLLER, loop_analysis
    # loop_analysis wants a controller for its margins; the sensor's systems do not depend on it
    la = loop_analysis(plant, ident, amp, DEFAULT_CONTROLLER, bias_v=BIAS_V)
    s = la["systems"]
    c_h = operating_point(plant.pzt, BIAS_V, "ascending").capacitance_f
    return {"E": s["E"], "E_d": s["E_d"], "sensor": s["sensor"],
            "x_of_vpea": small_signal_model(plant.pzt, c_h)[0, 0], "ident": ident, "amp": amp}


def member_gain_ratio(name, family, k_nominal_v_per_m):
    """K_g,i / K_g,nom: member ``name``'s gauge gain (its label names "K_g min" / "K_g max"; else its serial's
    nominal) over the firmware gain the charge estimate is scaled by (the nominal plant's), 1."""
    serial = name.partition(" C_p ")[0]
    nom, lo, hi = family.gauge_gains[serial]
    k = lo if name.endswith("K_g min") else hi if name.endswith("K_g max") else nom
    return k / k_nominal_v_per_m


def apply_sensor(model, freq_hz, members, family):
    """The members' responses seen through the sensor: ``{name: G_i factor_i}`` (the gauge: unchanged)."""
    if model.kind == "gauge":
        return members
    return {name: np.asarray(g) * model.factor(freq_hz, member_gain_ratio(name, family, model.gauge_v_per_m))
            for name, g in members.items()}
