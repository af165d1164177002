"""The plant family a design must hold against, its nominal member and a multiplicative bound.

The loop sees G = K_g P: the gauge chain's firmware volts per metre times the PZT's
V_pea -> x. Members:

- describing functions of each serial (and C_p at its tolerance corners) at each
  amplitude, where the point is linear-like (periodic, no current saturation, no
  clipping). A slewing member is not a linear behaviour: the amplifier's current
  limit caps dV/dt at roughly I_max / C, so above f = I_max / (2 pi C A) the member
  at amplitude A is left out and counted; rate limiting and anti-windup (design
  issue) own that regime;
- small-signal models on each branch at each bias;
- each of those with the gauge gain at its extremes over x0 (eq. 26 curvature) and
  the arm imbalances at their tolerance corners, the serial's own trim kept.

The nominal is SN-first's small-signal model with the incremental capacitance that
minimizes the largest relative deviation; the bound |W_m(jw)| >= |G_i/G_nom - 1|
is then fitted by :func:`workbench.linearize.weight.fit_weight`.
"""

import itertools
from dataclasses import dataclass, replace

import control
import numpy as np
from scipy.optimize import minimize_scalar

from ..design.margins import response
from .pzt_describing import pzt_describing_function
from .sampled import gauge_gain_v_per_m
from .small_signal import BRANCHES, operating_point, small_signal_model
from .weight import coverage, envelope, fit_weight

__all__ = ["FamilySpec", "Family", "plant_family", "uncertainty_bound", "UncertaintyBound"]


@dataclass(frozen=True)
class FamilySpec:
    """What the family spans (defaults: the issue's ranges)."""

    amplitudes_v: tuple = (0.1, 0.3, 1.0, 3.0, 10.0, 20.0, 35.0, 50.0)
    freq_hz: tuple = tuple(np.geomspace(0.1, 5000.0, 26))
    bias_v: float = 50.0
    small_signal_biases_v: tuple = (20.0, 50.0, 80.0)
    v_range: tuple = (0.0, 100.0)
    cp_tolerance: float = 0.2
    imbalance_tolerance_ohm: float = 0.4
    x0_range_m: tuple = (0.0, 15e-6)


@dataclass(frozen=True)
class Family:
    """Members' loop responses G_i(jw) = K_g P_i (firmware V per V), NaN where left out."""

    freq_hz: np.ndarray
    members: dict            # name -> complex ndarray
    excluded_points: int     # (member, frequency) pairs left out as slewing/clipped/not periodic
    dfs: dict                # serial/tolerance label -> DFFamily (for plots and JSON)
    gauge_gains: dict        # serial -> (nominal, min, max) firmware V/m

    def frd(self, name):
        """Member ``name`` as a python-control FRD (firmware V per V), on the frequencies where it is in."""
        g = np.asarray(self.members[name])
        keep = np.isfinite(g)
        # python-control names may not hold '.': "C_p x1.00" becomes "C_p x1p00"
        return control.FRD(g[keep], 2 * np.pi * self.freq_hz[keep], name=name.replace(".", "p"))

    def frds(self):
        """Every member with at least one frequency in, as ``{name: control.FRD}``."""
        return {n: self.frd(n) for n, g in self.members.items() if np.any(np.isfinite(g))}


def _gauge_range(plant, spec):
    """Nominal chain gain at mid-stroke and its extremes over x0 and the imbalance corners."""
    g = plant.gauge
    nominal = gauge_gain_v_per_m(0.5 * sum(spec.x0_range_m), g)
    tol = spec.imbalance_tolerance_ohm
    gains = []
    for corner in itertools.product((-tol, tol), repeat=4):
        gc = g.replace(imbalance_ohm=tuple(corner))
        gains += [gauge_gain_v_per_m(x0, gc) for x0 in spec.x0_range_m]
    return nominal, min(gains), max(gains)


def _case_df(args):
    """Describing functions of one (plant, C_p factor) case; runs in a worker process."""
    pzt, amplitudes_v, freq, bias_v, qs_phase = args
    return pzt_describing_function(pzt, sorted(amplitudes_v), freq, (bias_v,), skip_above_saturation=True,
                                   quasi_static_phase_rad=qs_phase)


def _map(fn, items, workers, progress):
    """``fn`` over ``items`` in order, on ``workers`` local processes (1: in this process)."""
    if workers <= 1 or len(items) <= 1:
        out = []
        for i, item in enumerate(items):
            out.append(fn(item))
            if progress is not None:
                progress(i + 1, len(items))
        return out
    import concurrent.futures
    import multiprocessing
    pool = concurrent.futures.ProcessPoolExecutor(max_workers=min(workers, len(items)),
                                                  mp_context=multiprocessing.get_context("spawn"))
    try:
        futures = [pool.submit(fn, item) for item in items]
        for i, _ in enumerate(concurrent.futures.as_completed(futures)):
            if progress is not None:
                progress(i + 1, len(items))
        return [fut.result() for fut in futures]
    except BaseException:
        # an error, Ctrl-C or a plain kill (workbench.cli raises on SIGTERM): the workers are stopped now, not
        # after every queued member has run (the pool's own exit waits for them); as verify/sweep.py does
        for process in list((pool._processes or {}).values()):
            process.kill()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def plant_family(plants, spec=FamilySpec(), progress=None, workers=1, quasi_static_phase_rad=1e-3):
    """Responses of every member over ``plants`` (loaded plant files, one per serial).

    Parameters
    ----------
    plants : list of Plant
    spec : FamilySpec
    progress : callable(done, total), optional
        Called per (serial, C_p corner) case done.
    workers : int or None
        Local processes the describing functions run on (one case per task); None: the
        machine's cores (``os.cpu_count()``); 1: in this process.
    quasi_static_phase_rad : float or None
        Frequencies long against every time constant but creep's by this phase are
        computed as their quasi-static limit (:func:`~.pzt_describing.quasi_static_below_hz`).
    """
    import os
    freq = np.asarray(spec.freq_hz, dtype=float)
    members, dfs, gauges = {}, {}, {}
    excluded = 0
    cases = [(p, f) for p in plants for f in (1.0 - spec.cp_tolerance, 1.0, 1.0 + spec.cp_tolerance)]
    pzts = [replace(plant.pzt, working_capacitance_f=plant.pzt.working_capacitance_f * cp_factor)
            for plant, cp_factor in cases]
    n_workers = (os.cpu_count() or 1) if workers is None else int(workers)
    fams = _map(_case_df, [(pzt, tuple(spec.amplitudes_v), freq, spec.bias_v, quasi_static_phase_rad)
                           for pzt in pzts], n_workers, progress)
    for (plant, cp_factor), pzt, fam in zip(cases, pzts, fams):
        label = f"{plant.serial} C_p x{cp_factor:.2f}"
        if plant.serial not in gauges:
            gauges[plant.serial] = _gauge_range(plant, spec)
        _, k_lo, k_hi = gauges[plant.serial]
        dfs[label] = fam
        for a, amp in enumerate(fam.amplitudes_v):
            p = np.where(fam.linear_ok[0, a], fam.x_m_per_v[0, a], np.nan)
            excluded += int(np.sum(~fam.linear_ok[0, a]))
            for kname, k in (("K_g min", k_lo), ("K_g max", k_hi)):
                members[f"{label}, DF A={amp:g} V, {kname}"] = k * p
        for bias in spec.small_signal_biases_v:
            for branch in BRANCHES:
                if branch == "descending" and bias == spec.v_range[1]:
                    continue
                op = operating_point(pzt, bias, branch, spec.v_range)
                ss = small_signal_model(pzt, op.capacitance_f)
                p = response(ss[0, 0], freq)
                for kname, k in (("K_g min", k_lo), ("K_g max", k_hi)):
                    members[f"{label}, {branch} at {bias:g} V, {kname}"] = k * p
    return Family(freq, members, excluded, dfs, gauges)


@dataclass(frozen=True)
class UncertaintyBound:
    """Nominal loop plant, the relative deviations, and the fitted weight W_m."""

    nominal: control.StateSpace       # V_pea -> firmware volts (continuous)
    nominal_capacitance_f: float
    nominal_gauge_v_per_m: float
    deltas: dict                      # name -> complex ndarray (0 where the member is left out)
    envelope: np.ndarray
    fit: object                       # WeightFit
    coverage: object                  # Coverage over every member


def uncertainty_bound(family, nominal_plant, max_order=3, guard_db=0.5):
    """Choose the nominal, form the deviations, fit W_m and check it covers every member."""
    k_nom = family.gauge_gains[nominal_plant.serial][0]
    pzt = nominal_plant.pzt
    names = list(family.members)
    resp = np.array([family.members[n] for n in names])

    def deltas_for(c_f):
        g = k_nom * response(small_signal_model(pzt, c_f)[0, 0], family.freq_hz)
        d = resp / g[None, :] - 1.0
        return np.where(np.isnan(d), 0.0, d)

    lo = pzt.hysteresis.weights[0]
    hi = float(np.sum(pzt.hysteresis.weights))
    # minimize the worst relative deviation over members and frequencies (log-scale search)
    res = minimize_scalar(lambda lc: np.max(np.abs(deltas_for(np.exp(lc)))),
                          bounds=(np.log(lo), np.log(hi)), method="bounded", options={"xatol": 1e-4})
    c_nom = float(np.exp(res.x))
    d = deltas_for(c_nom)
    deltas = dict(zip(names, d))
    env = envelope(deltas)
    fit = fit_weight(family.freq_hz, env, max_order=max_order, guard_db=guard_db)
    cov = coverage(fit.weight, family.freq_hz, deltas)
    nominal = k_nom * small_signal_model(pzt, c_nom, name="nominal")[0, 0]
    return UncertaintyBound(nominal, c_nom, k_nom, deltas, env, fit, cov)
