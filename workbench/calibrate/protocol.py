"""The calibration protocol: one record that shows every effect the library knows.

Three parts, each aimed at a group of effects:

1. **Decaying sines** over 0..``v_max`` at 0.5 Hz (``(1 - cos) / 2`` cycles whose envelope
   shrinks by ``sine_decay`` per cycle): nested hysteresis loops from full range down, so the
   Prandtl-Ishlinskii weights are identified over the whole threshold range; rate-dependent
   charge terms (leakage, absorption) show as loops that do not close.
2. **A staircase of holds** (``hold_s`` each): creep, dielectric absorption, leakage and drift
   show while the input is constant; the steps give seed 001's creep per hold.
3. **A small-signal chirp** (logarithmic, ``chirp_f0_hz`` .. ``chirp_f1_hz``) about the last
   stair: mechanical modes and latencies.

The commands are the amplifier's input; the amplifier's current limits shape what the stack
receives (a 25 V step takes ~0.4 s at the P-888.51's +2 mA), which is why the calibration
works from the recorded voltage and current rather than from these commands.
"""

import numpy as np
from scipy.signal import chirp

__all__ = ["calibration_protocol"]


def calibration_protocol(dt_s=1e-4, rest_s=0.5, v_max=100.0, sine_hz=0.5, sine_cycles=4, sine_decay=0.65,
                         stairs_v=(25.0, 50.0, 75.0, 100.0, 60.0, 30.0, 10.0), hold_s=3.0,
                         chirp_amplitude_v=0.5, chirp_f0_hz=10.0, chirp_f1_hz=None, chirp_s=6.0):
    """Time and command of the protocol, sampled at ``dt_s``; about 35.5 s by default.

    The chirp starts at 10 Hz (the sines and holds cover the slower range) and takes 6 s, so it
    dwells ~2.6 s per decade: a light mode's ringing then lasts long enough to be both fitted
    and tested. It ends at ``chirp_f1_hz``, by default 2 kHz or 0.3 of the sample rate, whichever
    is lower (a chirp past Nyquist would alias); a given end at or above Nyquist is refused.

    Returns
    -------
    t_s, v_v : ndarray
        Sample times (from ``dt_s``) and amplifier commands, V.
    """
    def n(seconds):
        return int(round(seconds / dt_s))

    nyquist_hz = 0.5 / dt_s
    if chirp_f1_hz is None:
        chirp_f1_hz = min(2000.0, 0.3 / dt_s)
    if chirp_s > 0 and not (0 < chirp_f0_hz < chirp_f1_hz < nyquist_hz):
        raise ValueError(f"the chirp {chirp_f0_hz:g}-{chirp_f1_hz:g} Hz must rise within (0, {nyquist_hz:g} Hz), "
                         f"the Nyquist frequency of dt_s = {dt_s:g} s")

    parts = [np.zeros(n(rest_s))]
    ts = np.arange(n(sine_cycles / sine_hz)) * dt_s
    envelope = sine_decay ** (ts * sine_hz)
    parts.append(v_max * envelope * 0.5 * (1.0 - np.cos(2 * np.pi * sine_hz * ts)))
    parts.extend(np.full(n(hold_s), float(v)) for v in stairs_v)
    tc = np.arange(n(chirp_s)) * dt_s
    bias = float(stairs_v[-1]) if len(stairs_v) else 0.0
    if tc.size > 1:
        parts.append(bias + chirp_amplitude_v * chirp(tc, chirp_f0_hz, tc[-1], chirp_f1_hz, method="logarithmic",
                                                      phi=-90.0))
    v = np.concatenate(parts)
    t = (np.arange(v.size) + 1) * dt_s
    return t, v
