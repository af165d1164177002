"""Synthetic records from the project's own simulator, with or without one added effect.

:func:`simulate_record` runs the compiled PZT (``workbench.plant.simulator``) on a command,
applies the plant file's additions (leakage, dielectric absorption, the displacement sensor's
latency and drift, a bowed gauge; ``workbench.plant.additions``), reads the displacement
through the strain-gauge chain (``gauge_run_equivalent``: bridge, x300, ADC, x2 demodulation,
trim, DAC) and adds sensor noise. The columns are what a lab would log:

* ``voltage`` -- the amplifier's OUTPUT as its monitor reads it, ``V_t + R i``: while the
  amplifier is current-limited this lags the command;
* ``current`` -- the terminal current (the core model's plus the leakage and absorption
  currents), each sample the MEAN over the interval ending at it, ``i_k = (q_k - q_{k-1}) / dt``
  (as ``plant.kernels.pzt_run`` logs it): :data:`CURRENT_KIND`, which :func:`write_record` declares
  as ``# current: averaged`` so the calibration integrates it exactly (running sum ``i dt``);
* ``displacement`` -- an external displacement sensor (capacitive or interferometric);
* ``gauge`` -- the firmware's DAC output, V: each row one period of the chain, whose bridge is
  averaged over the interval ending at the row (the displacement interpolated linearly within it):
  :data:`GAUGE_KIND`, which :func:`write_record` declares as ``# gauge: averaged`` so the base's gauge
  model carries the same half-sample mean (``base_fit.interval_mean``).

:func:`plant_with_effect` draws one effect with randomized, physically plausible values into a
copy of a plant: the test-bed for the calibration's effect tracing. The ranges are chosen so
each effect stands above the sensors' noise on the calibration protocol; they are stated in
``EFFECT_RANGES`` with why.
"""

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from ..plant.additions import Additions, absorption_charge, delayed, drift, gauge_bow, leakage_charge
from ..plant.creep import CreepParams
from ..plant.gauge import gauge_run_equivalent
from ..plant.pzt import Mode
from ..plant.simulator import PZTSimulator
from ..report.output import write_text

__all__ = ["SensorNoise", "simulate_record", "write_record", "plant_with_effect", "substeps", "EFFECTS",
           "EFFECT_RANGES", "CURRENT_KIND", "GAUGE_KIND", "N_SUB", "SETTLE_SUBSTEPS"]

#: What the simulated current column is (a record's ``# current:``): the mean over the interval ending at
#: each sample, so the running sum ``i dt`` is the simulator's charge to float rounding.
CURRENT_KIND = "averaged"
#: What the simulated gauge column is (a record's ``# gauge:``): each row the chain's mean over the interval
#: ending at it (``gauge_run_equivalent`` runs one modulation period per sample, the displacement interpolated
#: linearly within it: ``(x_{k-1} + x_k) / 2`` for a linear bridge), half a sample behind the motion.
GAUGE_KIND = "averaged"

EFFECTS = ("creep", "dielectric_absorption", "leakage", "resonance", "delay", "drift", "gauge_nonlinearity")

# Randomized ranges (uniform unless noted) and why: each must be visible on a ~35 s protocol.
EFFECT_RANGES = {
    # one Kelvin-Voigt branch per decade 0.1-1000 s; 0.4-1.4 uF each gives gamma ~0.01-0.03 (seed 001)
    "creep": {"branch_capacitance_f": (0.4e-6, 1.4e-6)},
    # k_s 1-4 % of the ~30 uF large-signal capacitance, tau 0.5-5 s (seed 002 Fig. 2.13: seconds)
    "dielectric_absorption": {"gain_f": (0.3e-6, 1.2e-6), "time_constant_s": (0.5, 5.0)},
    # a degraded stack or a damp cable: 20-200 Mohm (a sound stack is ~TOhm, seed 002 Fig. 2.12)
    "leakage": {"resistance_ohm": (2e7, 2e8)},
    # a stack loaded by a mirror or stage: first mode 150-400 Hz, 0.5-2 % damping. The P-888.51
    # amplifier's +2 mA limit shrinks the chirp at the stack as 1/f, so a mode's share of the
    # held-out error falls with f and damping: measured with a 4 s chirp from 1 Hz (the protocol's
    # chirp now dwells 1.5x longer per decade), 900 Hz / 1 % is found and halved (0.47),
    # 450 Hz / 3 % found but not halved (0.64), 663 Hz / 2.6 % and 1.37 kHz / 3 % answered none.
    # Halving needs the mode's RMS above ~1.7 x the rest (after = the rest): the range keeps it there
    "resonance": {"freq_hz": (150.0, 400.0), "damping_ratio": (0.005, 0.02)},
    # sensor electronics / filter latency 0.3-2 ms
    "delay": {"delay_s": (0.3e-3, 2e-3)},
    # thermal drift of the displacement sensor: 100-400 nm over the record (sign random)
    "drift": {"excursion_m": (100e-9, 400e-9)},
    # a bow in the gauge (eq. 27's shape with a larger coefficient) of 4-9 % of the stroke at its
    # end: 3000 /m is where the bow's RMS over the protocol reaches twice the gauge's 22 nm noise,
    # which a held-out error can at best halve (after = noise, before = sqrt(noise^2 + bow^2))
    "gauge_nonlinearity": {"coefficient_per_m": (3e3, 6e3)},
}


@dataclass(frozen=True)
class SensorNoise:
    """White noise RMS of each logged channel (the gauge's own noise is its chain's)."""

    displacement_m: float = 1e-9       # capacitive or interferometric sensor at 10 kHz bandwidth
    current_a: float = 0.5e-6          # current monitor
    voltage_v: float = 2e-3            # amplifier monitor


#: Samples simulated per call when the command is upsampled (:func:`simulate_record`): the fine command
#: of one chunk is ``upsample x REPLAY_CHUNK`` rows, whatever the record's length.
REPLAY_CHUNK = 1 << 15


#: Sub-steps a sample where a sample is shorter than the settle (:func:`substeps`): the simulator's historic
#: default, kept there so the records at 1 kHz and above are the ones every earlier figure was measured on.
N_SUB = 4
#: Where each command step settles within a sample (:func:`substeps`), the sub-steps resolve the fastest
#: settle ``R C_min`` by this many. Measured (100 Hz, the P-888.51, drawn modes 46-1600 Hz, creep, delay,
#: drift + mode; /work/notes/s32/alias/conv.py): the simulator's modes are discretized exactly for an input
#: linear over a sub-step, and their input, the quasi-static motion, bends within a sub-step only in the
#: settle, so the record's error falls as ``h^2``; at ``h = RC / 6`` (~80 us, 125 a sample) doubling the
#: sub-steps changes the displacement by at most 0.019 of the sensor's noise RMS (0.11 at the worst sample),
#: every other channel by less, where 4 sub-steps (2.5 ms, five RC) changed it by up to 9.7x (80x at a sample).
SETTLE_SUBSTEPS = 6


def substeps(pzt, dt_s):
    """Sub-steps a sample of ``dt_s`` (s) the simulator needs for a converged record of ``pzt``.

    Where a command step settles within a sample, ``exp(-dt / (R C_min)) <=``
    :data:`~workbench.calibrate.effects.HELD_SETTLED` (100 Hz on the P-888.51), every sample holds a whole
    transient: the charge ramps at the current limit (linear in time: a sub-step carries it exactly, and the
    simulator's electrical step is exact on it), then settles through the series resistor with ``R C_min``,
    ``C_min`` the terminal's smallest incremental capacitance (the PI operator's at a reversal, as at rest:
    6.0 uF on the P-888.51, 0.48 ms; a continuing step's ~11.6 uF settles slower), and the stack's modes ring
    on it. The sub-step is then ``R C_min /`` :data:`SETTLE_SUBSTEPS`, at least :data:`N_SUB` a sample. A mode's
    period needs no sub-steps of its own (its discretization is exact for an input linear over the sub-step:
    the P-888.51's own 70 kHz mode and drawn modes to 1.6 kHz converge at the same sub-step). Elsewhere (1 kHz
    and above, no series resistor) :data:`N_SUB`: the records every earlier figure used, byte for byte (at
    1 kHz, doubling them changes the displacement or the current by 0.03-0.31 of their noise RMS on drawn
    modes and creep, up to 4x at a sample: not refined here, a decision left open).

    Returns
    -------
    int
        ``n_sub`` for :class:`~workbench.plant.simulator.PZTSimulator`.
    """
    from .effects import HELD_SETTLED
    tau = pzt.settle_time_constant_s()
    if not tau > 0:
        return N_SUB
    if np.exp(-float(dt_s) / tau) > HELD_SETTLED:
        return N_SUB
    return max(N_SUB, int(np.ceil(float(dt_s) * SETTLE_SUBSTEPS / tau)))


def simulate_record(plant, t_s, v_cmd, seed=0, noise=SensorNoise(), n_sub=None, gauge=True, gauge_noise=True,
                    upsample=1, held=None):
    """Simulate a record of ``plant`` driven by ``v_cmd`` sampled at ``t_s``.

    ``noise`` is the logged channels' white noise; the gauge's is its chain's own (demodulator
    noise and ADC quantization, :func:`~workbench.plant.gauge.gauge_run_equivalent`), switched off
    by ``gauge_noise=False``: a noise-free simulation (a round trip through a calibrated plant)
    passes ``SensorNoise(0, 0, 0)`` and ``gauge_noise=False``. ``upsample``: the command is
    interpolated linearly onto ``upsample`` points per sample (each held for ``n_sub`` sub-steps)
    and the stack's trajectories taken back at the samples: a sampled *terminal* voltage driving a
    plant without its series resistor (a recorded drive replayed) ramps between samples instead of
    stepping, which a mode near the sample rate tells apart. ``held``: a
    :class:`~workbench.calibrate.effects.HeldDrive` (with ``upsample`` > 1): the command between samples follows
    its path instead, ``v_{k-1} + (v_k - v_{k-1}) rho_k(s)`` (:meth:`~workbench.calibrate.effects.HeldDrive.path`:
    a held amplifier command's ramp at the current limit and settle, which a recorded terminal voltage sampled
    at 100 Hz went through between samples).

    Returns
    -------
    dict of ndarray
        ``time_s``, ``voltage_v``, ``current_a``, ``displacement_m``, ``gauge_v`` (SI) and the
        noise-free truths ``x_true_m`` (the stack), ``v_t_v`` (terminal voltage) and ``q_true_c`` (the
        terminal charge with the additions' charges, C: the charge the logged current averages).
    """
    t = np.asarray(t_s, float)
    dt = float(np.mean(np.diff(t)))
    up = max(1, int(upsample))
    if n_sub is None:
        n_sub = substeps(plant.pzt, dt / up)
    sim = PZTSimulator(plant.pzt, dt / up, n_sub=n_sub)
    v_cmd = np.asarray(v_cmd, float)
    if up > 1:
        # fine step j ends at t0 + (j - up + 1) dt / up: every up-th (the kept one) ends on a sample.
        # In chunks of REPLAY_CHUNK samples (the simulator keeps its state between calls): the fine
        # command is never held whole (a 35.5 s record at 1 MHz would need up x 3 columns of 8 B a row)
        parts = []
        for a in range(0, t.size, REPLAY_CHUNK):
            b = min(a + REPLAY_CHUNK, t.size)
            if held is None:
                tf = t[0] + (np.arange(a * up, b * up) - (up - 1)) * (dt / up)
                fine = np.interp(tf, t, v_cmd)
                del tf
            else:
                # the same fine points: sample k's up points end interval k at s = dt (m + 1) / up
                v0 = v_cmd[max(a - 1, 0):b - 1] if a > 0 else np.r_[v_cmd[0], v_cmd[:b - 1]]
                rho = held.path(np.arange(1, up + 1) * (dt / up), slice(a, b))
                fine = (v0[:, None] + (v_cmd[a:b] - v0)[:, None] * rho).ravel()
                del rho
            parts.append(sim.run(fine, decimate=up))
            del fine
        tr = SimpleNamespace(**{k: np.concatenate([getattr(p, k) for p in parts]) for k in ("x_m", "q_c", "i_a", "v_t_v")})
        del parts
    else:
        tr = sim.run(v_cmd)
    add = plant.additions
    rng = np.random.default_rng(seed)
    r = plant.pzt.series_resistance_ohm
    q = tr.q_c.copy()
    if add.leakage_resistance_ohm:
        q += leakage_charge(t, tr.v_t_v, add.leakage_resistance_ohm)
    if add.absorption_gain_f:
        qa = absorption_charge(t, tr.v_t_v, add.absorption_gain_f, add.absorption_time_constant_s)
        q += qa - qa[0]
    # current as the per-sample mean (the charge difference over the step), the first from rest
    i = np.diff(q, prepend=0.0) / dt
    i[0] = tr.i_a[0]
    v_mon = tr.v_t_v + r * i
    x_sensor = tr.x_m
    if add.sensor_delay_s:
        x_sensor = delayed(t, x_sensor, add.sensor_delay_s)
    x_sensor = x_sensor + drift(t, add.sensor_drift_rate_m_per_s, add.sensor_drift_curvature_m_per_s2)
    out = {
        "time_s": t,
        "voltage_v": v_mon + noise.voltage_v * rng.standard_normal(t.size),
        "current_a": i + noise.current_a * rng.standard_normal(t.size),
        "displacement_m": x_sensor + noise.displacement_m * rng.standard_normal(t.size),
        "x_true_m": tr.x_m,
        "v_t_v": tr.v_t_v,
        "q_true_c": q,
    }
    if gauge:
        x_g = tr.x_m
        if add.gauge_nonlinearity_per_m:
            x_g = gauge_bow(x_g, add.gauge_nonlinearity_per_m, x_ref_m=0.0)
        out["gauge_v"] = gauge_run_equivalent(x_g, plant.gauge, seed=int(rng.integers(2**31)),
                                              noise=bool(gauge_noise)).dac_v
    return out


_CSV_COLUMNS = (("time_s", "time[s]"), ("voltage_v", "voltage[V]"), ("current_a", "current[A]"),
                ("displacement_m", "displacement[m]"), ("gauge_v", "gauge[V]"))


RECORD_SUFFIXES = (".csv",)       # the only format write_record produces (the record reader's CSV)


def write_record(path, record, metadata=None):
    """Write a simulated record as the calibration's CSV (written whole or not at all).

    ``metadata`` items are written as ``# key: value`` lines; a record with a current column is
    declared ``# current: averaged`` (:data:`CURRENT_KIND`, what :func:`simulate_record` logs) and one
    with a gauge column ``# gauge: averaged`` (:data:`GAUGE_KIND`) unless ``metadata`` says otherwise.

    Raises
    ------
    ValueError
        If the suffix of ``path`` is not one of ``RECORD_SUFFIXES`` (a CSV under a ``.toml`` name).
    """
    if Path(path).suffix.lower() not in RECORD_SUFFIXES:
        raise ValueError(f"cannot write a record to {str(path)!r}: the suffix must be one of {RECORD_SUFFIXES} "
                         f"(the record is a CSV), got {Path(path).suffix!r}")
    cols = [(k, h) for k, h in _CSV_COLUMNS if k in record]
    metadata = dict(metadata or {})
    if "current_a" in record:
        metadata.setdefault("current", CURRENT_KIND)
    if "gauge_v" in record:
        metadata.setdefault("gauge", GAUGE_KIND)
    lines = [f"# {k}: {v}" for k, v in metadata.items()]
    lines.append(",".join(h for _, h in cols))
    data = np.column_stack([record[k] for k, _ in cols])
    body = "\n".join(",".join(f"{v:.10g}" for v in row) for row in data)
    write_text(Path(path), "\n".join(lines) + "\n" + body + "\n")
    return Path(path)


def _uniform(rng, lo_hi, log=False):
    lo, hi = lo_hi
    if log:
        return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    return float(rng.uniform(lo, hi))


def plant_with_effect(plant, effect, rng, duration_s=35.0, size=1.0):
    """A copy of ``plant`` (no creep, no additions) with one effect drawn at random.

    ``effect`` may also be a tuple of effects (a record with two). ``size`` multiplies the
    effect's magnitude drawn from ``EFFECT_RANGES`` (creep capacitance, absorption gain,
    leakage conductance, delay, drift excursion, bow coefficient; for a resonance it divides
    the damping ratio's floor and lowers the frequency, ``f / sqrt(size)``): the confusion
    benchmark draws it from well below the noise floor to large.

    Returns
    -------
    plant, truth : Plant, dict
        The modified plant and the drawn values (SI).
    """
    rng = np.random.default_rng(rng)
    pzt = dataclasses.replace(plant.pzt, creep=None)
    add = Additions()
    effects = (effect,) if isinstance(effect, str) else tuple(effect)
    truth = {}
    for eff in effects:
        pzt, add, tr = _draw(eff, rng, pzt, add, duration_s, float(size))
        truth.update(tr)
    return dataclasses.replace(plant, pzt=pzt, additions=add), truth


def _draw(effect, rng, pzt, add, duration_s, size):
    rg = EFFECT_RANGES.get(effect)
    truth = {}
    if effect == "none":
        pass
    elif effect == "creep":
        c = _uniform(rng, rg["branch_capacitance_f"]) * size
        tau = np.array([0.1, 1.0, 10.0, 100.0, 1000.0])
        pzt = dataclasses.replace(pzt, creep=CreepParams(tau, np.full(tau.size, c)))
        truth = {"branch_capacitance_f": c, "time_constants_s": tau.tolist()}
    elif effect == "dielectric_absorption":
        truth = {"gain_f": _uniform(rng, rg["gain_f"]) * size,
                 "time_constant_s": _uniform(rng, rg["time_constant_s"], True)}
        add = dataclasses.replace(add, absorption_gain_f=truth["gain_f"],
                                  absorption_time_constant_s=truth["time_constant_s"])
    elif effect == "leakage":
        truth = {"resistance_ohm": _uniform(rng, rg["resistance_ohm"], True) / size}
        add = dataclasses.replace(add, leakage_resistance_ohm=truth["resistance_ohm"])
    elif effect == "resonance":
        truth = {"freq_hz": _uniform(rng, rg["freq_hz"], True) / np.sqrt(size),
                 "damping_ratio": _uniform(rng, rg["damping_ratio"])}
        pzt = dataclasses.replace(pzt, modes=(Mode(truth["freq_hz"], truth["damping_ratio"]),))
    elif effect == "delay":
        truth = {"delay_s": _uniform(rng, rg["delay_s"]) * size}
        add = dataclasses.replace(add, sensor_delay_s=truth["delay_s"])
    elif effect == "drift":
        # a t + b t^2 with a random share of curvature, scaled to the drawn excursion
        ex = _uniform(rng, rg["excursion_m"]) * rng.choice([-1.0, 1.0]) * size
        share = rng.uniform(-1.0, 1.0)
        a, b = (1.0 - abs(share)) / duration_s, share / duration_s ** 2
        peak = np.max(np.abs(a * np.linspace(0, duration_s, 200) + b * np.linspace(0, duration_s, 200) ** 2))
        truth = {"drift_rate_m_per_s": ex * a / peak, "drift_curvature_m_per_s2": ex * b / peak}
        add = dataclasses.replace(add, sensor_drift_rate_m_per_s=truth["drift_rate_m_per_s"],
                                  sensor_drift_curvature_m_per_s2=truth["drift_curvature_m_per_s2"])
    elif effect == "gauge_nonlinearity":
        truth = {"coefficient_per_m": _uniform(rng, rg["coefficient_per_m"]) * rng.choice([-1.0, 1.0]) * size}
        add = dataclasses.replace(add, gauge_nonlinearity_per_m=truth["coefficient_per_m"])
    else:
        raise ValueError(f"unknown effect {effect!r}; known: none, {', '.join(EFFECTS)}")
    return pzt, add, truth


PROTOCOLS = ("calibration", "sine", "steps")


def benchmark_protocol(kind, rate_hz, n_rows):
    """The command of a confusion-benchmark record: ``n_rows`` samples at ``rate_hz``.

    The calibration protocol's parts (``calibration_protocol``) scaled in time to the record's
    duration ``D = n_rows / rate_hz`` (its nominal 14.5 s: 0.5 s rest, three 0.5 Hz decaying
    sines, four 1.5 s holds, a 2 s chirp from 10 Hz to ``min(2 kHz, 0.3 rate)``, all times
    times ``D / 14.5 s``); ``"sine"``: decaying sines only (0.5 s rest, then sines over the
    rest of the record, six cycles); ``"steps"``: holds only (rest, then eight steps between
    10 and 100 V).
    """
    from .protocol import calibration_protocol
    dt = 1.0 / float(rate_hz)
    dur = n_rows * dt
    k = dur / 14.5
    if kind == "calibration":
        t, v = calibration_protocol(dt_s=dt, rest_s=0.5 * k, sine_hz=0.5 / k, sine_cycles=3,
                                    stairs_v=(50.0, 20.0, 80.0, 40.0), hold_s=1.5 * k,
                                    chirp_f0_hz=10.0 / k, chirp_f1_hz=min(2000.0 / max(k, 1.0), 0.3 * rate_hz),
                                    chirp_s=2.0 * k)
    elif kind == "sine":
        t, v = calibration_protocol(dt_s=dt, rest_s=0.5 * k, sine_hz=6.0 / (dur - 0.5 * k), sine_cycles=6,
                                    sine_decay=0.8, stairs_v=(), chirp_s=0.0)
    elif kind == "steps":
        steps = (30.0, 80.0, 10.0, 100.0, 50.0, 20.0, 70.0, 40.0)
        t, v = calibration_protocol(dt_s=dt, rest_s=0.5 * k, sine_cycles=0, stairs_v=steps,
                                    hold_s=(dur - 0.5 * k) / len(steps), chirp_s=0.0)
    else:
        raise ValueError(f"protocol must be one of {', '.join(PROTOCOLS)}, got {kind!r}")
    return t, v
