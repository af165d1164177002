"""The mirror's servo study: ``workbench study studies/fsm_servo.toml`` (issue 15, item 6).

Schema ``workbench.fsm_study/1``. Steps: load the mirror file, its small-signal family
(:func:`~workbench.linearize.mimo.mirror_family`), the decoupled notch-only design
(:func:`~workbench.design.mimo.design_mimo`) with a **gauge-noise budget derived from the plant**
(below), export it as a :class:`~workbench.export.mimo.MimoController` (NAME.json, NAME.h and each
axis' files), figures (MIMO Bode / singular values, disk margin over frequency, the modes) and
report.md / report.html.

Noise budget. Each stack's command must not lead its voltage by more than R min(I_source, I_sink)
/ 3 RMS (:func:`~workbench.design.budgets.plant_budgets`: the SISO study's rule; noise reaching the
+2 mA source limit is rectified into a position bias). The gauges' reading noise sigma_j (firmware V,
:func:`~workbench.plant.gauge.demod_noise_sigma_v` x trim) reaches axis a as sigma_a = sqrt(sum_j
Out[a, j]^2 sigma_j^2), and axis a's command noise reaches stack j through In[j, a]; with one bound
rho on every axis controller's noise gain ||K S|| (dimensionless: axis unit per axis unit), stack j
sees rho sqrt(sum_a In[j, a]^2 sigma_a^2), so rho = min_j B_j / sqrt(sum_a In[j, a]^2 sigma_a^2). The
loop-shaping tuner takes it as ``max_noise_command_v = rho`` with ``noise_reading_v = 1``
(``[design] noise_budget = false`` drops it).

Active damping (opt-in, ``[design] iff = true``). The same family and spec (noise budget included) are
also designed with integral force feedback from each stack's charge bridge
(``design_mimo(..., damping=True, iff_source="bridge")``, high-pass at
:func:`~workbench.design.mimo.iff_corner_hz` of the lowest crossover searched: the force estimate
T (V_t - q / C_R) that the charge amplifier with its reference capacitor reads, no gauge in it; with
the noise budget, the IFF's own noise counts against it) and exported beside the
notch-only controller as NAME_iff; the report sets the two designs side by side. Off by default: the
damped export is only as good as its verification (README, mirror section).
"""

import os
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import StudyDefinitionError
from ..fields import Field, check_table, read_toml

__all__ = ["FSM_STUDY_SCHEMA", "is_mirror_study", "run_mirror_study", "noise_gain_bound"]

FSM_STUDY_SCHEMA = "workbench.fsm_study/1"

_SCHEMA = {
    "": {"schema": Field("str", expect=f'the string "{FSM_STUDY_SCHEMA}"'),
         "name": Field("str", expect="a name (letters, digits, underscores), e.g. \"fsm_servo\""),
         "plant": Field("str", expect="the mirror file relative to this file, e.g. \"../plants/fsm_p888_51.toml\"")},
    "family": {"bias_v": Field("float", 0.0, 100.0, required=False,
                               expect="the operating bias in V inside the 0-100 V loop the family is taken on, "
                                      "e.g. 50.0")},
    "design": {"notch_depth_db": Field("float", 0.0, 80.0, lo_open=True, required=False,
                                       expect="the notch depth in dB, e.g. 20"),
               "noise_budget": Field("bool", required=False, expect="true or false"),
               "iff": Field("bool", required=False,
                            expect="true to also design and export the IFF-damped controller (NAME_iff), or false"),
               "fc_min_hz": Field("float", 0.0, 1e5, lo_open=True, required=False,
                                  expect="lowest crossover searched, Hz"),
               "fc_max_hz": Field("float", 0.0, 1e5, lo_open=True, required=False,
                                  expect="highest crossover searched, Hz")},
    "export": {"name": Field("str", required=False, expect="a C identifier, e.g. \"fsm_servo\""),
               "directory": Field("str", required=False,
                                  expect="a folder inside the output folder, e.g. \"controllers\"")},
}


def is_mirror_study(path):
    """True when the TOML file at ``path`` has ``schema = "workbench.fsm_study/1"`` (False on anything unreadable)."""
    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8")).get("schema") == FSM_STUDY_SCHEMA
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False


def _load(path):
    path = Path(path)
    doc = read_toml(path, StudyDefinitionError, "give an existing study file, e.g. studies/fsm_servo.toml")
    sections = [k for k in _SCHEMA if k]
    for key, value in doc.items():
        if isinstance(value, dict) and key not in _SCHEMA:
            raise StudyDefinitionError(path, key, f"unknown section; known: {', '.join(sections)}")
    out = {"": check_table(path, "", doc, _SCHEMA[""], StudyDefinitionError, sections=sections)}
    for sec in sections:
        out[sec] = check_table(path, sec, doc.get(sec, {}), _SCHEMA[sec], StudyDefinitionError)
    top = out[""]
    if top["schema"] != FSM_STUDY_SCHEMA:
        raise StudyDefinitionError(path, "schema", f"got {top['schema']!r}; expected {FSM_STUDY_SCHEMA!r}")
    d = out["design"]
    if d.get("fc_min_hz", 0) >= d.get("fc_max_hz", np.inf):
        raise StudyDefinitionError(path, "design.fc_min_hz", "must be below design.fc_max_hz")
    return path, out


def noise_gain_bound(fsm, decoupler, dt_s):
    """rho of the module docstring (dimensionless) and the per-stack budgets B_j (V RMS)."""
    from ..design.budgets import plant_budgets
    from ..plant.gauge import demod_noise_sigma_v
    sig = np.array([demod_noise_sigma_v(p.gauge) * p.gauge.trim_scale for p in fsm.plants])
    sa = np.sqrt((decoupler.out_q_per_v ** 2) @ sig ** 2)
    b = np.array([plant_budgets(p, dt_s)["noise_command_v"].value for p in fsm.plants], float)
    return float(np.min(b / np.sqrt((decoupler.in_v_per_q ** 2) @ sa ** 2))), b, sig


def run_mirror_study(study_path, out_dir, progress=None):
    """Run a ``workbench.fsm_study/1`` file (module docstring); returns a summary dict (paths, margins, budget)."""
    from ..controller import plant_window
    from ..design.mimo import (MIMO_SPEC, AXIS_NAMES, damped_gauges, decoupled, design_mimo, kinematic_decoupler,
                               nominal_name)
    from ..export.mimo import MimoController
    from ..linearize.mimo import mirror_family
    from ..plant.mirror import load_mirror
    from ..report.html import write_html_report
    from ..report.markdown import md_image, md_table
    from ..report.mirror_figures import plot_disk_margins, plot_mimo_bode, plot_modes
    from ..report.output import write_json, write_text
    from ..errors import PlantDefinitionError

    path, spec = _load(study_path)
    top, fam_s, des_s, exp_s = spec[""], spec["family"], spec["design"], spec["export"]
    plant_path = Path(os.path.normpath(path.parent / top["plant"]))
    try:
        fsm = load_mirror(plant_path)
    except PlantDefinitionError as err:
        raise StudyDefinitionError(path, "plant", f"{top['plant']!r} does not load: {err}") from err
    nyquist_hz = 0.5 / float(fsm.plants[0].gauge.period_s)
    for key in ("fc_min_hz", "fc_max_hz"):
        if des_s.get(key, 0.0) >= nyquist_hz:
            raise StudyDefinitionError(path, f"design.{key}", f"got {des_s[key]:g} Hz; a crossover must lie below "
                                                              f"the servo's Nyquist frequency {nyquist_hz:g} Hz")
    out = Path(out_dir)
    t0 = time.perf_counter()
    stage = (lambda s, d, t: progress(s, d, t)) if progress else (lambda *a: None)
    stage("family", 0, 1)
    fam = mirror_family(fsm, bias_v=fam_s.get("bias_v", 50.0))
    stage("family", 1, 1)
    nom = fam[nominal_name(fam_s.get("bias_v", 50.0))] if nominal_name(fam_s.get("bias_v", 50.0)) in fam else \
        fam[next(iter(fam))]
    dt = float(fsm.plants[0].gauge.period_s)
    dec = kinematic_decoupler(fsm, nom)
    rho, budgets, sig = noise_gain_bound(fsm, dec, dt)
    lsspec = replace(MIMO_SPEC, dt_s=dt, fc_range_hz=(des_s.get("fc_min_hz", MIMO_SPEC.fc_range_hz[0]),
                                                      des_s.get("fc_max_hz", MIMO_SPEC.fc_range_hz[1])))
    if des_s.get("noise_budget", True):
        alpha = min(plant_window(p, dt)[0] for p in fsm.plants)
        lsspec = replace(lsspec, max_noise_command_v=rho, noise_reading_v=1.0, voltage_alpha=float(alpha))
    design = design_mimo(fsm, fam, damping=False, spec=lsspec, notch_depth_db=des_s.get("notch_depth_db", 20.0),
                         nominal=nom, progress=lambda d, t: stage("design", d, t))
    summ = design.summary()
    name = exp_s.get("name", top["name"])
    ctrl = MimoController.from_design(design, fsm, name=name,
                                      record={"study": str(path), "design": summ,
                                              "noise_gain_bound": rho})
    cdir = out / exp_s.get("directory", "controllers")
    paths = ctrl.write(cdir)
    damped = damped_paths = None
    if des_s.get("iff", False):
        damped = design_mimo(fsm, fam, damping=True, spec=lsspec, nominal=nom, iff_source="bridge",
                             progress=lambda d, t: stage("damped design", d, t))
        verified_drift = _verified_drift(fsm, plant_path, lsspec.fc_range_hz[0])
        dctrl = MimoController.from_design(damped, fsm, name=f"{name}_iff",
                                           record={"study": str(path), "design": damped.summary(),
                                                   "noise_gain_bound": rho})
        damped_paths = dctrl.write(cdir)
    # figures
    f = design.freq_hz
    plants = {n: decoupled(design.decoupler, damped_gauges(fsm, m, f, None)) for n, m in fam.items()}
    nname = nominal_name(fam_s.get("bias_v", 50.0)) if nominal_name(fam_s.get("bias_v", 50.0)) in plants else \
        next(iter(plants))
    figs = {"bode": plot_mimo_bode(out / "mimo_bode.png", f, plants, nname),
            "disk": plot_disk_margins(out / "disk_margins.png", f, design.loop_out, design.disk_out["alpha"])}
    modes_hz, zeta, labels = _modes(nom)
    figs["modes"] = plot_modes(out / "modes.png", f, np.stack([plants[nname][:, i, i] for i in range(3)], axis=1),
                               modes_hz, labels, design.notches)
    data = {"name": top["name"], "study": str(path), "plant": str(plant_path), "members": len(fam),
            "seconds": time.perf_counter() - t0, "noise_gain_bound": rho,
            "noise_budget_v": budgets.tolist(), "gauge_noise_v": sig.tolist(),
            "noise_budget_used": bool(des_s.get("noise_budget", True)), "design": summ,
            "modes_hz": list(map(float, modes_hz)), "mode_damping": list(map(float, zeta)),
            "exported": {k: str(v) for k, v in paths.items() if k in ("json", "h")},
            "damped": None if damped is None else {
                "design": damped.summary(), "verified_drift": verified_drift,
                "exported": {k: str(v) for k, v in damped_paths.items() if k in ("json", "h")}},
            "figures": {k: str(v) for k, v in figs.items()},
            "axis_ranges_v": {k: list(c.output_limits_v) for k, c in ctrl.axes.items()},
            "axis_windows": {k: list(c.voltage_model) for k, c in ctrl.axes.items()}}
    md = out / "report.md"
    lines = [f"# Mirror servo study: {top['name']}", "",
             f"Mirror `{plant_path}` ({fsm.name}); {len(fam)} small-signal members at {fam_s.get('bias_v', 50.0):g} V "
             f"(4 branches x gauge gain nominal/min/max). Kinematic decoupling, per-axis structured loop shaping, "
             f"a notch per axis at its structural resonance (design/mimo.py).", "",
             "## Noise budget (from the plant)", "",
             f"Per stack R min(I_source, I_sink) / 3 = {_fmt_list(budgets, '.3g')} V RMS; gauge reading noise "
             f"{_fmt_list(np.array(sig) * 1e3, '.3g')} mV RMS; bound on each axis loop's noise gain ||K S|| "
             f"(RMS over the band): rho = {rho:.3g} "
             + ("(used)." if des_s.get("noise_budget", True) else "(NOT used: `design.noise_budget = false`)."), "",
             "## Per-axis loops (loop-at-a-time, worst member)", ""]
    rows = []
    for ax in AXIS_NAMES:
        a = summ["axes"][ax]
        rows.append([ax, f"{a['bandwidth_hz']['value']:.0f} ({a['bandwidth_hz']['member']})",
                     f"{a['crossover_hz_min']['value']:.0f}", f"{a['phase_margin_deg']['value']:.1f} "
                     f"({a['phase_margin_deg']['member']})", f"{a['gain_margin_db']['value']:.2f}",
                     f"{a['disk_margin']['value']:.3f}",
                     "none" if a["notch"] is None else f"{a['notch'][0]:.0f} Hz, {a['notch'][1]:g} dB"])
    lines += md_table(["axis", "closed-loop bandwidth, Hz (worst member)", "lowest crossover, Hz", "PM deg (worst)",
                       "GM dB (worst)", "SISO disk alpha", "notch"], rows)
    di, do = summ["disk_in"], summ["disk_out"]
    pm_ok = all(summ["axes"][a]["phase_margin_deg"]["value"] >= 40 and summ["axes"][a]["gain_margin_db"]["value"] >= 6
                for a in AXIS_NAMES)
    lines += ["", f"Simultaneous disk margin (mu, AB13MD): alpha = {di['alpha']:.3f} at the stack inputs "
              f"({di['member']}, {di['freq_hz']:.0f} Hz), {do['alpha']:.3f} at the axis outputs. Floors (issue 15): "
              f"PM >= 40 deg / GM >= 6 dB loop-at-a-time **{'met' if pm_ok else 'MISSED'}**, alpha >= 0.4 "
              f"**{'met' if min(di['alpha'], do['alpha']) >= 0.4 else 'MISSED'}**.", "",
              "## Exported controller", "",
              f"`{paths['json']}` and `{paths['h']}` (+ one SISO header per axis): gauges -> axes matrix, three "
              f"32-bit cascades (axis volts; ranges "
              + ", ".join(f"{k} {v[0]:.4g}..{v[1]:.4g}" for k, v in data["axis_ranges_v"].items())
              + " axis V), axes -> stacks matrix, each axis with a current-limit window (alpha, +h, -h): "
              + ", ".join(f"{k} ({v[0]:.4g}, {v[1]:.3g} V, {v[2]:.3g} V)" for k, v in data["axis_windows"].items())
              + f". Verify it with "
              f"`workbench verify {plant_path} --controller {paths['json']}`.", "",
              "## Figures", "", md_image("MIMO Bode", figs["bode"], md), "", md_image("disk margins", figs["disk"], md),
              "", md_image("modes", figs["modes"], md), ""]
    if damped is not None:
        lines += _damped_section(summ, damped, damped_paths, plant_path, budgets, verified_drift)
    rows = [[lab, f"{fm:.1f}", f"{100 * z:.2f}"] for lab, fm, z in zip(labels, modes_hz, zeta)]
    lines += [f"Structural modes of the nominal member ({nname}: amplifiers in the loop, stacks at their slopes):", ""] + md_table(["mode", "Hz", "damping %"], rows)
    write_text(md, "\n".join(lines) + "\n")
    data["report"] = str(md)
    data["report_html"] = str(write_html_report(md))
    data["json"] = str(write_json(out / "study.json", data))
    return data


def damped_ratio_met(ratios, floor=2.0):
    """Issue 15's damping floor on the unrounded (tip, tilt, ...) damped / notch-only bandwidth ratios: True when
    tip and tilt both reach ``floor``."""
    return bool(all(float(r) >= floor for r in list(ratios)[:2]))


def _verified_drift(fsm, plant_path, fc_min_hz):
    """The IFF corner checked against the mirror ``workbench verify`` runs by default (every stack with the creep
    branches of :data:`~workbench.verify.mirror.VERIFY_CREEP_FILE`, next to the mirror file): :func:`iff_corner_hz`'s
    info dict plus ``creep_file``; refused (:class:`DesignError`) when the corner does not clear that drift by
    :data:`~workbench.design.mimo.IFF_DRIFT_MARGIN`. None when that creep file is not there (verify would then need
    ``creep_file``)."""
    from ..design.mimo import iff_corner_hz
    from ..plant.files import load_plant
    from ..verify.mirror import VERIFY_CREEP_FILE, verification_mirror
    creep = Path(plant_path).parent / VERIFY_CREEP_FILE
    if not creep.is_file():
        return None
    _, info = iff_corner_hz(verification_mirror(fsm, (1.0, 1.0, 1.0), load_plant(creep)), fc_min_hz)
    return {**info, "creep_file": str(creep)}


def _damped_section(summ, damped, paths, plant_path, budgets_v, verified_drift=None):
    """Report lines: the IFF-damped design beside the notch-only one (worst members), and its export."""
    from ..design.mimo import AXIS_NAMES, IFF_DRIFT_MARGIN, IFF_MIN_OUTER_NOISE_SHARE, IFF_PHASE_COST_DEG
    from ..report.markdown import md_table
    ds = damped.summary()
    i = ds["iff"]
    rows, ratios = [], []
    for ax in AXIS_NAMES:
        n, d = summ["axes"][ax], ds["axes"][ax]
        ratios.append(d["bandwidth_hz"]["value"] / n["bandwidth_hz"]["value"])
        rows.append([ax, f"{n['bandwidth_hz']['value']:.0f} / {d['bandwidth_hz']['value']:.0f}",
                     f"{d['bandwidth_hz']['value'] / n['bandwidth_hz']['value']:.2f}",
                     f"{n['phase_margin_deg']['value']:.1f} / {d['phase_margin_deg']['value']:.1f}",
                     f"{n['gain_margin_db']['value']:.2f} / {d['gain_margin_db']['value']:.2f}"])
    alpha = min(ds["disk_in"]["alpha"], ds["disk_out"]["alpha"])
    return ["## IFF-damped design (opt-in: `[design] iff = true`)", "",
            f"Integral force feedback per stack from its charge bridge (force estimate T (V_t - q / C_R), C_R = "
            f"the nominal incremental C_h): gain {i['gain_v_per_n']:.4g} V/N, high-pass {i['corner_hz']:.3g} Hz; "
            f"flexure damping {100 * i['zeta_min_open']:.2f} % -> {100 * i['zeta_min_damped']:.2f} % (nominal "
            f"member). Same family and spec as above (noise budget included). The high-pass is tan({IFF_PHASE_COST_DEG:g} deg) x the "
            f"lowest crossover searched (design.mimo.iff_corner_hz), at least {IFF_DRIFT_MARGIN:g}x the fastest "
            f"drift the bridge reads: in the serial files {i['drift_hz']:.3g} Hz ({i['drift_source']}; "
            f"{i['drift_margin']:.3g}x)" + (
                "; the verified mirror's creep file was not found, so it was not checked against verify's creep."
                if verified_drift is None else
                f"; on the mirror `workbench verify` runs (every stack with the creep of "
                f"`{verified_drift['creep_file']}`) {verified_drift['drift_hz']:.3g} Hz ({verified_drift['drift_source']}): "
                f"corner {verified_drift['drift_margin']:.3g}x above it, the high-pass passing "
                f"{100 * verified_drift['drift_gain']:.0f} % of that drift.")
            + f" The bridge noise through the IFF leads each stack's "
            f"command by {_fmt_list(np.array(i['command_noise_v']) * 1e3, '.3g')} mV RMS against the current "
            f"window's budget {_fmt_list(np.array(budgets_v) * 1e3, '.3g')} mV"
            + ("" if i.get("outer_noise_share") is None else
               f"; the outer loops keep {i['outer_noise_share']:.5f} of it (RMS share; warned below "
               f"{IFF_MIN_OUTER_NOISE_SHARE:.3f}, an equal split of its variance)"
               + ("" if not i.get("outer_noise_share_warning") else f". **Warning**: {i['outer_noise_share_warning']}"))
            + "; the export holds each stack's whole command (axes + IFF) within R min(I_source, I_sink) of its RC "
              "model.", ""] + md_table(
        ["axis", "bandwidth notch only / damped, Hz (worst member)", "damped / notch only", "PM deg notch / damped",
         "GM dB notch / damped"], rows) + [
        "", f"Damped simultaneous alpha {alpha:.3f}. Issue 15's 2x target: "
            f"**{'met' if damped_ratio_met(ratios) else 'MISSED'}** on tip/tilt. Exported as "
            f"`{paths['json']}` (+ per-stack IFF headers); verify with `workbench verify {plant_path} --controller "
            f"{paths['json']}`.", ""]


def _fmt_list(v, f):
    return "/".join(format(float(x), f) for x in v)


def _modes(member):
    """Structural modes of a small-signal member (its complex poles above 50 Hz): Hz, damping ratios, labels."""
    p = member.poles()
    p = p[(p.imag > 0) & (np.abs(p) > 2 * np.pi * 50.0)]
    order = np.argsort(np.abs(p))
    wn = np.abs(p[order])
    return wn / (2 * np.pi), -p.real[order] / wn, [f"mode {i + 1}" for i in range(len(wn))]
