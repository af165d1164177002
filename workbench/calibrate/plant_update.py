"""The updated plant file: the plant with the core refitted on the record and the effects calibration found.

The declared file's text is kept line for line (its sources and comments stay true); the
section of the found effect is replaced or appended, with every value commented with the record
it came from. **The core** (session 13): ``[hysteresis]`` is replaced by the fitted model's own core,
its joint plays inverted through the declared C_pp into C_h (:mod:`.core_refit`, :func:`core_for`), so
the file is the fitted model wherever the effects' forms can copy it; C_p, T_em, k_p, the limits, modes
and gauge stay declared. Where the record's core cannot be a C_h (a loading slope at or above C_pp past
the cap, an amplifier command, the gauge channel) or the declared core replays the development rows
closer (:func:`choose_core`: a mode's gain other than 1, creep the branches cannot carry), the declared
core is kept and the header says why. Mapping of the tracing's parameters to plant-file sections
(``workbench.plant.additions`` and the core's ``[creep]`` / ``[[mechanics.modes]]``):

* ``leakage``: ``gain_per_s`` is charge per volt-second, ``1 / R_FP``;
* ``dielectric_absorption``: ``gain`` is ``k_s`` (C/V), ``tau_s`` the time constant;
* ``creep`` (displacement channel): Kelvin-Voigt branches across the core's C_h. With the refitted core
  (session 14), C_h and the branches are fitted together to the record's displacement
  (:func:`~workbench.calibrate.core_refit.direct_core_and_branches`: ``V_h = V_t - q / C_pp`` from the
  record, ``q`` linear in C_h's play weights and the ``C_j``; the sensor's delay searched with them,
  :func:`_delay_with_branches`); failing that, branches whose settled/instant ratio is the spectrum's and
  whose time constants at a held terminal voltage are the fitted ones (:func:`creep_branches`), sized as
  fractions of the instant response and refitted by simulation to the fitted model's creep
  (:func:`~workbench.calibrate.core_refit.refine_branches`); with the declared core, C_h from its terminal
  secant over the record's voltage span (no charge channel needed). Above the ceiling
  ``1 + C_pp / C_h`` a smaller share (or no section) is written, and the header says why;
* ``resonance``: an added ``[[mechanics.modes]]`` entry; on a plant with a modal ``[structure]`` (the whole
  M(.): the loader refuses modes beside it) one more mode of the structure holding the tracing's gain as its
  share of the static compliance, taken from the residual (:func:`_add_structure_mode`), or, where that share
  does not fit (or the structure is a state-space file), not written and the header says why;
* ``delay`` / ``drift`` on the displacement channel: ``[displacement_sensor]``;
* ``gauge_nonlinearity``: ``[gauge_nonlinearity] coefficient_per_m``.

An effect with no plant-file form (drift or delay of the gauge or the charge) is recorded in the
header comment only. A resonance named on the gauge is the stack's mode (the gauge reads the stack's
strain) and is written as one, like the displacement's.
"""

import datetime
import re

import numpy as np

__all__ = ["carried_stages", "unplaced_modes", "replayed", "replay_key", "bow_about_rest", "replay_above_before_warning", "written_stages", "choose_core", "reported_error_after", "declared_core", "core_for", "plant_file_gaps", "round_trip_note", "updated_plant_error_reason", "updated_plant_text", "creep_branches", "updated_plant_error", "replay_upsample", "held_replay_upsample", "round_trip_warning", "ROUND_TRIP_TOLERANCE"]

#: Issue 13 item 6: simulating the record through the updated plant reproduces the fitted model's
#: ``error_after`` within this fraction; a larger difference is warned about, with its reason.
ROUND_TRIP_TOLERANCE = 0.10

_REPLACED = ("leakage", "dielectric_absorption", "displacement_sensor", "gauge_nonlinearity", "creep", "hysteresis",
             "structure")


def _drop_sections(text, names):
    out, skip = [], False
    for line in text.splitlines():
        m = re.match(r"^\s*\[\[?\s*([A-Za-z0-9_.]+)\s*\]\]?", line)
        if m:
            skip = m.group(1) in names
        if not skip:
            out.append(line)
    return "\n".join(out).rstrip() + "\n"


def _fmt(x):
    return repr(float(x))


def updated_plant_text(plant_path, plant, base, result, data_path, plant_error=None, core=None, omit=None):
    """TOML text of the declared plant plus every effect found (see the module notes).

    Every stage of ``result["stages"]`` is written (the first is ``result["effect"]``) but those in ``omit``
    (``{(effect, channel): reason}``, :func:`carried_stages`: a stage whose written form does not replay the
    development rows closer), which the header names with the reason; a
    delay and a drift of the displacement sensor share one ``[displacement_sensor]`` section.
    ``plant_error``: this file's own simulated test error (:func:`updated_plant_error`,
    ``{rms, max, units}``), stated in the header beside the fitted model's. ``core``: the core written
    (:func:`core_for`, the default; :func:`declared_core` keeps the declared one; :func:`choose_core` picks).
    """
    text = plant_path.read_text(encoding="utf-8")
    src = f"workbench calibrate on {data_path.name}"
    stages = result.get("stages") or ([{"effect": result["effect"], "channel": result["channel"],
                                        "parameters": result["parameters"], "error_before": result["error_before"],
                                        "error_after": result["error_after"]}]
                                      if result.get("effect") not in (None, "none", "inconclusive") else [])
    eb, ea = result["error_before"], result["error_after"]
    core = core_for(plant, base, result) if core is None else core
    stages = written_stages(stages, result, core)
    omit = dict(omit or {})
    left_out = [st for st in stages if (st["effect"], st["channel"]) in omit]
    stages = [st for st in stages if (st["effect"], st["channel"]) not in omit]
    names = ", ".join(f"{s['effect']} on the {s['channel']}" for s in stages) or result.get("effect", "none")
    header = [f"# Calibrated {datetime.date.today().isoformat()} by {src}: {names};",
              f"# the fitted model (its base refitted on the record, every effect found on the first effect's "
              f"channel) leaves a test RMS {eb['rms']:.4g} -> {ea['rms']:.4g} {eb['units']} (max {eb['max']:.4g} -> "
              f"{ea['max']:.4g}).",
              *([f"# This file (the core and the sections below), the record's drive simulated through it, "
                 f"leaves a test RMS of {plant_error['rms']:.4g} {plant_error['units']} (max "
                 f"{plant_error['max']:.4g})."] if plant_error else
                ["# This file's own simulated error on the record was not measured."])]
    if core["hysteresis"] is not None:
        lo, hi = core["range_v"]
        header.append(f"# [hysteresis] (C_h) is the fitted model's core, refitted on the record's {core['channel']} over "
                      f"V_t {lo:.4g} .. {hi:.4g} V (beyond it: extrapolated at its last loading slope); C_p, T_em, "
                      f"k_p (so C_pp and k_q2x), the electrical limits, the modes and the gauge stay declared; the "
                      f"sections of the effects are new.")
    elif stages and result.get("core_fit") is not None:
        header.append(f"# The declared core is kept: the record's core is not written ({core['reason']}). The other "
                      f"declared values below are unchanged; the sections of the effects are new.")
    else:
        header.append("# The declared values below are unchanged; the sections of the effects are new.")
    for st in left_out:
        header.append(f"# The {st['effect']} found on the {st['channel']} is not written: "
                      f"{omit[(st['effect'], st['channel'])]}; its parameters are in the calibration JSON.")
    blocks = []
    if core["hysteresis"] is not None:
        h = core["hysteresis"]
        blocks.append(["[hysteresis]", f"# {core['how']}",
                       f"thresholds_v = [{', '.join(_fmt(x) for x in h.thresholds)}]   # V (of V_h); {src}",
                       f"weights_f = [{', '.join(_fmt(x) for x in h.weights)}]   # F; {src}",
                       f"initial_states_v = [{', '.join(_fmt(x) for x in h.initial_states)}]   # V; at rest"
                       + ("" if getattr(base, "starts_from_rest", False) else
                          f" (the record starts at {float(base.v_drive[0]):.4g} V, reached monotonically from 0 V as "
                          f"the base fit's plays are)")])
    sensor = {}
    struct = _declared_structure(text, plant)
    for st in stages:
        if struct is not None and st["effect"] == "resonance" and st["channel"] in ("displacement", "gauge"):
            # a [structure] plant: its M(.) is the whole mechanics, so the mode is one more mode of it (the loader
            # refuses [[mechanics.modes]] beside [structure]; s22_outsider B2: the run stopped on its own file)
            why = _add_structure_mode(struct, st["parameters"], src)
            if why:
                header.append(f"# The resonance found on the {st['channel']} ({float(st['parameters']['f_n_hz']):.4g} "
                              f"Hz) is not written: {why}; its parameters are in the calibration JSON.")
            continue
        block = _block(st["effect"], st["channel"], st["parameters"], base, src, sensor, st.get("note"), plant,
                       core if core["hysteresis"] is not None and core["channel"] == st["channel"] else None,
                       result.get("core_fit"))
        if block:
            blocks.append(block)
        elif st["effect"] == "creep" and st["channel"] == "displacement":
            header.append(f"# The creep found on the displacement is not written: {sensor.pop('creep_note', '')}")
        elif st["effect"] not in ("delay", "drift") or st["channel"] != "displacement":
            header.append(f"# The {st['effect']} found on the {st['channel']} channel has no plant-file form; its "
                          f"parameters are in the calibration JSON.")
    if sensor:
        blocks.append(["[displacement_sensor]",
                       sensor.get("delay", "delay_s = 0.0   # s; none found"),
                       *sensor.get("drift", ["drift_rate_m_per_s = 0.0   # m/s; none found",
                                             "drift_curvature_m_per_s2 = 0.0   # m/s^2; none found"])])
    if struct is not None and struct["added"]:
        blocks.append(_structure_block(struct))
    names = {b[0].strip("[]") for b in blocks}
    body = _drop_sections(text, tuple(n for n in names if n in _REPLACED))
    out = "\n".join(header) + "\n" + body
    for block in blocks:
        out += "\n" + "\n".join(block) + "\n"
    return out


def _declared_structure(text, plant):
    """The declared ``[structure]`` of a plant file's ``text`` (None without one): ``{"section", "k_static",
    "residual_share", "added"}``; ``residual_share`` the share of the static compliance no declared mode holds
    (the static correction), None for a ``state_space_file`` structure (no modal keys to add a mode to)."""
    import tomllib
    if getattr(plant, "structure", None) is None:
        return None
    sec = tomllib.loads(text).get("structure")
    if sec is None:
        return None
    st = plant.structure
    k = 1.0 / float(st.static_compliance_m_per_n()[0, 0])
    share = None if "state_space_file" in sec else float(np.ravel(st.residual_compliance_m_per_n)[0]) * k
    return {"section": sec, "k_static": k, "residual_share": share, "added": []}


def _add_structure_mode(struct, p, src):
    """Add a found resonance to a modal ``[structure]`` (:func:`_declared_structure`); the reason when it cannot be.

    The tracing's resonance is ``x (1 + g (H - 1))``: a share ``g`` of the quasi-static motion ``x`` through a
    unit-DC-gain mode ``H``. In a modal M(.) a mode of modal mass ``m`` and elongation participation 1 holds
    ``1 / (m w^2)`` of the compliance; taking that share from the residual (static-correction) compliance keeps
    the static stiffness, the quasi-static motion the core carries, and gives the same response: the mode is
    written with ``m = k_static / (g w^2)``, so it needs ``0 < g <=`` the residual share left."""
    f, zeta, g = float(p["f_n_hz"]), min(max(float(p["zeta"]), 1e-6), 1.0), float(p.get("gain", 1.0))
    if struct["residual_share"] is None:
        return "the declared [structure] is a state-space file (no modal keys to add a mode to)"
    left = struct["residual_share"] - sum(a[3] for a in struct["added"])
    if not g > 0:
        return (f"its gain {g:.4g} (a share of the static compliance) is not positive, which no mode of a "
                f"structure holds")
    if g > left:
        return (f"its share of the static compliance, the gain {g:.4g}, is above the {left:.4g} the declared "
                f"[structure]'s modes leave to the residual compliance (the record's mode does not fit the declared "
                f"structure: check its modal masses and static stiffness)")
    w = 2 * np.pi * f
    struct["added"].append((f, zeta, struct["k_static"] / (g * w * w), g, src))
    return None


def _structure_block(struct):
    """The ``[structure]`` section: the declared modal keys with the added modes (:func:`_add_structure_mode`)."""
    sec = struct["section"]
    add = struct["added"]

    def arr(key, new):
        return "[" + ", ".join(_fmt(x) for x in [*map(float, sec[key]), *new]) + "]"
    said = "; ".join(f"{f:.6g} Hz, zeta {z:.4g}, share {g:.4g} of the static compliance (resonance fit, {src})"
                     for f, z, _, g, src in add)
    return ["[structure]",
            f"# the declared modal model with {len(add)} mode(s) added at the end: {said}; each added mode's modal "
            f"mass k_static / (share (2 pi f)^2), its share taken from the residual compliance (the static "
            f"stiffness is the declared one), participation 0 at end a, 1 at end b",
            f"freqs_hz = {arr('freqs_hz', [a[0] for a in add])}",
            f"damping_ratios = {arr('damping_ratios', [a[1] for a in add])}",
            f"modal_masses_kg = {arr('modal_masses_kg', [a[2] for a in add])}",
            f"participation_end_a = {arr('participation_end_a', [0.0] * len(add))}",
            f"participation_end_b = {arr('participation_end_b', [1.0] * len(add))}",
            f"static_stiffness_n_per_m = {_fmt(sec['static_stiffness_n_per_m'])}"]


def declared_core(reason):
    """A :func:`core_for` result that keeps the declared core, for ``reason``."""
    return {"hysteresis": None, "reason": reason, "channel": None, "range_v": None, "instant": None,
            "how": None, "creep_scale": 1.0, "capped": 0.0}


def choose_core(plant_path, plant, base, result, data_path, rows, test=None, replays=None):
    """The refitted core or the declared one: whichever file replays the development ``rows`` closer.

    Both files are written and loaded back, and the record's drive replayed through each
    (:func:`updated_plant_error` on ``rows``, the constant taken out there); the test rows take no part.
    The refitted core makes the file the fitted model wherever the effects' forms can copy it; where they
    cannot (a mode's gain other than 1, creep beyond what branches across C_h carry) the declared core,
    which made the record in the simulator, can be closer (measured: seeds 24-25, two drift+resonance
    records at 14x and 19x with fitted mode gains ~2: 2.46x and 2.60x error_after with the refitted core,
    1.99x and 0.86x with the declared).

    Returns
    -------
    core : dict
        :func:`core_for`'s, or :func:`declared_core`'s with the reason.
    dev : dict
        The development rows' replay RMS of each file: ``{"refitted": x, "declared": y}`` (None when only
        one file could be replayed).
    test_error : dict or None
        With ``test``: the chosen file's :func:`updated_plant_error` on ``test`` (from the same replay);
        None when the choice replayed nothing.

    ``replays``: the run's memo of replays (:func:`replayed`), filled here and read by :func:`carried_stages` and
    the file's test error, so a file is replayed once a run.
    """
    import tempfile
    from pathlib import Path
    core = core_for(plant, base, result)
    ch = result.get("channel")
    reason = updated_plant_error_reason("pzt", result, base, ch)
    if reason is not None:
        # no file can be replayed: the mode refit cannot run either, and the JSON and the gaps say so
        return {**core, "mode_refit_skipped": reason}, None, None
    if core["hysteresis"] is None:
        # the declared core alone: the mode is still refitted through its file (review of s15_rt: it was skipped)
        with tempfile.TemporaryDirectory() as tmp:
            return _refit_mode(plant_path, plant, base, result, data_path, core, rows, Path(tmp)), None, None
    errs, tests = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        cores = {}
        for name, c in (("refitted", core), ("declared", declared_core("declared"))):
            c = cores[name] = _refit_mode(plant_path, plant, base, result, data_path, c, rows, Path(tmp))
            sim = replayed(updated_plant_text(plant_path, plant, base, result, data_path, core=c), base, ch,
                           Path(tmp) / f"{name}.toml", replays)
            errs[name] = _replay_error(sim, base, ch, rows, rows)["rms"]
            tests[name] = None if test is None else _replay_error(sim, base, ch, test, rows)
    if errs["declared"] < errs["refitted"]:
        u = base.channels[ch].units
        kept = declared_core(f"the declared core replays the development rows closer: {errs['declared']:.4g} against "
                             f"{errs['refitted']:.4g} {u} with the refitted core")
        if "mode" in cores["declared"]:
            kept["mode"] = cores["declared"]["mode"]
        return kept, errs, tests["declared"]
    return cores["refitted"], errs, tests["refitted"]


def _file_lines(text):
    """The lines of a plant file's text that set something (comment lines and blank ones dropped)."""
    return [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def unplaced_modes(stages):
    """``{(effect, channel): reason}``: the held drive's modes the record cannot place (``alias_family`` not
    resolved), and those of a record with no series resistor alike (tested through every path its drive may take
    between samples, :func:`~workbench.calibrate.tracing.direct_drives`).

    A mode named through the held drive's path (100 Hz on the P-888.51) is written to the plant file only where its
    folds place it (:func:`~workbench.calibrate.tracing.alias_family`): the named frequency resolved beyond every
    other member of its alias family, named again by the folds' own searches within its half-power band, and its
    gain consistent with a stack mode's share of the motion. A servo designer reads a file's mode as measured, and at
    100 Hz a record may leave it at one of several frequencies (100.4, 200.4 or 300.4 Hz), or fit the column to
    something else (the review of s32_alias: a 490 Hz mode named 285.6 Hz, gain 0.35). The JSON carries the family,
    the file's gaps (``omit``'s reason) say what is missing and why, and its ``error_after`` is that of the file
    without it."""
    out = {}
    for st in stages:
        fam = st.get("alias_family")
        if fam and not fam.get("resolved", True):
            out[(st["effect"], st["channel"])] = f"its frequency is not placed: {fam['note']}"
    return out


def carried_stages(plant_path, plant, base, result, data_path, core, rows, replays=None):
    """Which stages the updated plant file carries: each written only where it replays the development rows closer.

    The file with every stage written (as :func:`updated_plant_text` writes them with ``core``) and the file
    without one stage are loaded back and the record's drive replayed through each (:func:`_replay`), on the
    stage's own channel (the charge's for a leakage, the gauge's for a bow), the constant taken out on the
    development ``rows``; the stage is left out when the file without it replays those rows as close or closer.
    The stages are judged last to first, each against the file with every stage not left out so far, so the
    named (first) effect is judged last, against the file the later stages left: where two written forms
    overlap, the later one goes first (review of s23_replay: judged first to last, a mode leaving 1 % of a misfit
    was dropped beside a delay leaving 5 %, both together 6 %, and the file kept the delay). A file without the
    stage that cannot be replayed (not finite) keeps it. The test rows take no part. ``replays``: the run's memo
    (:func:`replayed`; :func:`choose_core` replayed the file with every stage already), None: this call's own.

    Why (s22_outsider C1): the file's forms are approximations of the tracing's (a mode of unit gain, branches
    across a hysteretic C_h, a bow about rest); the tracing's model can be right while its written form replays
    worse than no section at all, and the file's ``error_after`` was then above ``error_before`` with the effect
    reported found.

    Returns
    -------
    omit : dict
        ``{(effect, channel): reason}`` of the stages left out (``updated_plant_text``'s ``omit``).
    carried : list of dict
        Per stage of :func:`written_stages`: ``effect``, ``channel``, ``written`` (bool), ``reason`` (why not,
        or why it was not measured, else None) and ``development_rms`` (``{"with", "without", "units",
        "channel"}``, the two files' replay RMS on the development rows, None when not replayed).
    """
    import tempfile
    from pathlib import Path

    stages = written_stages(result.get("stages") or [], result, core)
    carried = [{"effect": st["effect"], "channel": st["channel"], "written": True, "reason": None,
                "development_rms": None} for st in stages]
    omit = unplaced_modes(stages)
    for c, st in zip(carried, stages):
        if (st["effect"], st["channel"]) in omit:
            c.update(written=False, reason=omit[(st["effect"], st["channel"])])
    why_not = updated_plant_error_reason("pzt", result, base, result.get("channel"))
    if why_not is not None:
        for c in carried:
            if c["written"]:
                c["reason"] = f"not replayed ({why_not})"
        return omit, carried
    replays = {} if replays is None else replays
    with tempfile.TemporaryDirectory() as tmp:
        texts = {}

        def text_of(om):
            # each file's text built once (the omitted stages' reasons are in its comments alone)
            key = tuple(sorted(om.items()))
            if key not in texts:
                texts[key] = updated_plant_text(plant_path, plant, base, result, data_path, core=core, omit=om)
            return texts[key]

        def dev(om, ch):
            sim = replayed(text_of(om), base, ch, Path(tmp) / f"carried{len(texts)}.toml", replays)
            return _replay_error(sim, base, ch, rows, rows)["rms"]
        for c, st in reversed(list(zip(carried, stages))):
            key = (st["effect"], st["channel"])
            if key in omit:
                continue
            ch = st["channel"]
            trial = {**omit, key: "trial"}
            body_without = "\n".join(_file_lines(text_of(trial)))
            body_with = "\n".join(_file_lines(text_of(omit)))
            if ch not in _SIM_KEY or ch not in base.channels:
                if body_without != body_with:
                    c["reason"] = f"written, not measured (the simulator does not log the {ch})"
                else:
                    c.update(written=False, reason="no plant-file form")
                continue
            if body_without == body_with:
                own = [g for g in plant_file_gaps([st], base, plant, core=core)
                       if not g.startswith("the record's core")]
                c.update(written=False, reason="; ".join(own) or "no plant-file form")
                continue
            e_with = dev(omit, ch)
            e_without = dev(trial, ch)
            u = base.channels[ch].units
            c["development_rms"] = {"with": e_with, "without": e_without, "units": u, "channel": ch}
            if np.isfinite(e_without) and not e_with < e_without:
                reason = (f"its written form replays the development rows no closer than the file without it "
                          f"({e_with:.4g} against {e_without:.4g} {u} on the {ch})")
                omit[key] = reason
                c.update(written=False, reason=reason)
    return omit, carried


#: The found mode's frequency and damping are refitted by replay within these factors of the tracing's
#: (:func:`_refit_mode`).
MODE_REFIT_FREQ_FACTOR = 1.5
MODE_REFIT_DAMPING_FACTOR = 10.0


def _refit_mode(plant_path, plant, base, result, data_path, core, rows, tmp):
    """``core`` with ``mode``: the found resonance's ``(f_n_hz, zeta, f_named_hz, zeta_named)`` refitted to the
    record's development ``rows`` through the file (unchanged when no resonance is written on the displacement
    or the refit does not replay the rows closer).

    Why (session 15): the tracing's resonance is a filtered copy of the base's output with its gain free; the file's
    mode has unit gain (the simulator's modes filter the quasi-static motion, unit DC gain). Where the tracing's
    gain came out off 1 its frequency and damping compensate (seed 24 #55, 10 kHz sine: gain 0.85, 45.06 Hz,
    zeta 0.0072; drawn 44.84 Hz, 0.0068): the file replayed 1.9x the tracing model's error, with the drawn
    frequency and damping 0.06x. The file's modes do not feed back (``plant.kernels``: the quasi-static
    displacement drives them), so the file is replayed once without the found mode and the mode (a unit-gain
    second-order filter, first-order hold as the simulator's; along the held drive's path where the replay takes it,
    :func:`~.effects.held_mode_column`) applied to that replay; its frequency and damping
    are fitted there (least squares on the rows, the constant free), within :data:`MODE_REFIT_FREQ_FACTOR` and
    :data:`MODE_REFIT_DAMPING_FACTOR` of the tracing's.
    """
    import dataclasses

    from scipy import signal
    from scipy.optimize import least_squares

    from ..plant import load_plant
    from .effects import held_mode_column
    from .tracing import held_drive
    if result.get("channel") != "displacement" or base.input_kind != "terminal" or "displacement" not in base.channels:
        return core
    stages = written_stages(result.get("stages") or [], result, core)
    found = [st for st in stages if st["effect"] == "resonance" and st["channel"] in ("displacement", "gauge")]
    if len(found) != 1:
        return core
    p0 = found[0]["parameters"]
    f0, z0 = float(p0["f_n_hz"]), min(max(float(p0["zeta"]), 1e-6), 1.0)
    f = tmp / "mode_refit.toml"
    f.write_text(updated_plant_text(plant_path, plant, base, result, data_path, core=core), encoding="utf-8")
    again = load_plant(f)
    modes = tuple(again.pzt.modes)
    if not modes:
        return core
    k = int(np.argmin([abs(float(md.freq_hz) - f0) for md in modes]))      # the found one (written at f0)
    without = dataclasses.replace(again, pzt=dataclasses.replace(again.pzt, modes=modes[:k] + modes[k + 1:]))
    y0 = np.asarray(_replay(without, base, "displacement"), float)
    _, drift = _sensor_terms(stages, base)
    x1 = y0 - (0.0 if drift is None else drift)
    m = base.channels["displacement"]
    t = np.asarray(base.t, float)
    dt = float(np.mean(np.diff(t)))
    ok = np.asarray(rows, bool) & np.asarray(m.valid, bool) & np.isfinite(m.y)
    if not np.any(ok) or not dt > 0:
        return core
    y = np.asarray(m.y, float) - (0.0 if drift is None else drift)
    held = held_drive(base)

    def moded(z):
        w = 2 * np.pi * float(np.exp(z[0]))
        zeta = float(np.exp(z[1]))
        if held is not None:          # the replay's own path between samples (:func:`_replay`)
            return x1 + held_mode_column(x1, held, float(np.exp(z[0])), zeta)
        b, a, _ = signal.cont2discrete(([w * w], [1.0, 2 * zeta * w, w * w]), dt, method="foh")
        b = np.ravel(b)
        zi = signal.lfilter_zi(b, a) * x1[0]
        return signal.lfilter(b, a, x1, zi=zi)[0]

    scale = float(np.std(y[ok])) or 1.0     # in units of the record's spread (the solver's tolerances are relative)

    def resid(z):
        e = (moded(z) - y)[ok]
        return (e - e.mean()) / scale
    start = np.log([f0, z0])
    lo = np.log([f0 / MODE_REFIT_FREQ_FACTOR, max(z0 / MODE_REFIT_DAMPING_FACTOR, 1e-6)])
    hi = np.log([f0 * MODE_REFIT_FREQ_FACTOR, min(z0 * MODE_REFIT_DAMPING_FACTOR, 1.0)])
    if not np.all(hi > lo):
        return core
    r0 = resid(start)
    sol = least_squares(resid, np.clip(start, lo + 1e-12, hi - 1e-12), bounds=(lo, hi), x_scale=1.0, max_nfev=60)
    if not float(np.mean(sol.fun ** 2)) < float(np.mean(r0 ** 2)):
        return core
    return {**core, "mode": (float(np.exp(sol.x[0])), float(np.exp(sol.x[1])), f0, z0)}


#: The shares of a creep's branches tried, largest first, when branches across the refitted C_h cannot carry
#: them all (:func:`core_for`); 0: no [creep], the core the fitted model's settled response.
CREEP_SHARES = (1.0, 0.8, 0.6, 0.4, 0.2, 0.0)


def core_for(plant, base, result):
    """:func:`~workbench.calibrate.core_refit.refitted_core` of a calibration's result (its ``core_fit``).

    With a creep on the core's channel (the displacement) the core and the creep's branches are fitted
    together to the record (:func:`_core_with_branches`, :data:`JOINT_CORE`); failing that (or with
    ``JOINT_CORE`` off), the largest share of its branches (of :data:`CREEP_SHARES`) that branches across
    the refitted instant C_h can carry (below the ceiling ``1 + C_pp / C_h``, :func:`creep_branches`): the
    core is the fitted model's response less that share's instant part, so its settled response is the
    fitted model's whatever the share.
    """
    from .core_refit import refitted_core
    cf = result.get("core_fit")
    creep = [st for st in (cf or {}).get("stages", ()) if st["effect"] == "creep" and st["channel"] == "displacement"]
    if not cf or cf["channel"] != "displacement" or not creep:
        return refitted_core(plant, base, cf)
    for share in CREEP_SHARES:
        core = refitted_core(plant, base, cf, creep_scale=share)
        if core["hysteresis"] is None:
            # only where the instant core was tried on the record's terminal volts and did not invert (its
            # ``range_v`` set): an amplifier-command record (its volts are not V_t), a channel without a charge
            # scale or no joint weights give no V_h for the joint fit either (s22_outsider B1: the real record as a
            # command against SN637, a creep named, stopped here with a TypeError on the missing range)
            if share == 1.0 and JOINT_CORE and core.get("range_v") is not None:
                # the fitted model's instant core has no C_h (session 15: a drawn 100 kHz creep + delay record at
                # 29x, the core fit's reversal slope 1268 F, above C_pp, at every share; the declared core then
                # dropped the creep and the file replayed 37.9x the tracing model): the joint fit needs no instant
                # core, only thresholds, the base's scaled to V_h's span (choose_core still keeps the declared core
                # when it replays the development rows closer)
                joint = _core_with_branches(plant, base, result, core)
                if joint is not None:
                    joint.pop("reason", None)
                    return joint
            return core
        if share == 1.0 and JOINT_CORE:
            joint = _core_with_branches(plant, base, result, core)
            if joint is not None:
                return joint
        if share == 0.0 or _creep_write_out(creep[0]["parameters"], base, plant, core)["capacitances_f"] is not None:
            return core
    return core


#: Fit the written core and the creep's branches across it together to the record (session 14,
#: :func:`~workbench.calibrate.core_refit.direct_core_and_branches`); False: the fitted model's instant core
#: with branches refitted to the spectrum's creep (session 13), 3.9-6.6x error_after on seeds 24-25.
JOINT_CORE = True


#: The record's offset the joint fit takes off (:func:`_core_with_branches`): "model" (the fitted model's,
#: :func:`_fitted_motion`: fitted with creep, where the base's is biased by it) or "search" (on the development
#: rows' residual, :func:`~workbench.calibrate.core_refit.direct_core_and_branches`). Tuning seeds 24-25,
#: creep+delay (main 7 / 15 / 16 within 10 % / at most +10 % / records, worst 2.04x): search 9 / 16 / 16, worst
#: 1.06x; model 8 / 16 / 16, worst 1.06x (>= 3x: 1 and 2 of 5 within 10 %). A tie; "model" taken: one fit, and
#: the search trades a model's misfit into the offset (R in, V - R i, declared zero offset: 0.12 -> 0.22 of the
#: creep's RMS held out).
OFFSET_FROM = "model"


def _sensor_terms(stages, base):
    """(delay_s, drift) the file's ``[displacement_sensor]`` adds to the displacement: the delay, s, and the
    drift, m at every sample (None without), from the stages written (as :func:`_block` writes them)."""
    delay, drift = 0.0, None
    t = np.asarray(base.t, float)
    for st in stages:
        if st["channel"] != "displacement":
            continue
        p = st["parameters"]
        if st["effect"] == "delay":
            delay = float(p["delay_s"])
        elif st["effect"] == "drift":
            from ..plant.additions import drift as drift_of
            c = np.asarray(p["coefficients"], float)
            span = p["t_end_s"] - p["t0_s"]
            drift = drift_of(t, c[1] / span if c.size > 1 else 0.0, c[2] / span ** 2 if c.size > 2 else 0.0)
    return delay, drift


#: The sensor delay written beside jointly fitted core and branches is searched within this factor of the
#: named delay stage's (:func:`_delay_with_branches`).
DELAY_SEARCH_FACTOR = 2.0

#: Log-spaced points of the delay's bracket scanned before the bounded search (:func:`_delay_with_branches`).
DELAY_SCAN_POINTS = 9


def _delay_with_branches(plant, base, rows, delay_s, drift, thresholds_v=None, model=None, gain=1.0, offset_m=None,
                         fastest_branch_s=None):
    """The sensor delay, s, at which C_h and the branches fitted together
    (:func:`~workbench.calibrate.core_refit.direct_core_and_branches`) leave the least residual on the
    development ``rows``, searched between ``min(|d|, |g d|)`` over and ``max(|d|, |g d|)`` times
    :data:`DELAY_SEARCH_FACTOR`, with ``d``'s sign (a lead is bracketed as a lag is; a zero ``d`` is kept) (a scan of :data:`DELAY_SCAN_POINTS` log-spaced points and ``d``, ``g d``, then a
    bounded golden section between the best one's neighbours) (``d`` the named delay stage's ``delay_s``, ``g`` its gain ``scale``),
    at the record's offset ``offset_m`` (m; None: the direct fit searches it at every trial).

    Why: the delay stage's term is ``g (u0(t - d) - u0(t))`` with its gain ``g`` free (``scale``), a delay of
    about ``g d`` where ``u0`` is smooth; the file's ``[displacement_sensor]`` delays the whole motion by one
    ``delay_s`` (measured, seed 24 #31, 1 kHz steps: stage 0.34 ms at scale 0.79, drawn 0.24 ms; the file with
    the stage's 0.34 ms left 1.5x error_after, the error on the fast transitions).
    """
    from scipy.optimize import minimize_scalar

    from .core_refit import direct_core_and_branches
    dt = float(np.mean(np.diff(np.asarray(base.t, float))))
    # the stage's term g (u0(t - d) - u0) acts as a whole-motion shift of about g d (29 #75: g 15.3)
    ends = (delay_s, abs(float(gain)) * delay_s)
    # bracketed by magnitude, the sign put back: sorted((min/2, max*2)) of negative ends gave d -1 ms, g 3:
    # [-2, -1.5] ms instead of [-6, -0.5] (review of s15_rt); a zero end (delay 0 or gain 0) has no log bracket
    mags = np.abs(np.asarray(ends, float))
    mags = mags[np.isfinite(mags) & (mags > 0)]
    if mags.size == 0:
        return float(delay_s)
    sign = -1.0 if delay_s < 0 else 1.0
    lo, hi = float(mags.min()) / DELAY_SEARCH_FACTOR, float(mags.max()) * DELAY_SEARCH_FACTOR

    m = base.channels["displacement"]
    ok = np.asarray(rows, bool) & np.asarray(m.valid, bool) & np.isfinite(m.y)
    # a trial with no fit (or a non-finite one) costs more than any fit on the rows, but finitely: an infinite
    # cost turned the golden section's parabolic steps into NaN and the search escaped (session 14's 25 #75)
    worst = 1e3 * (float(np.ptp(np.asarray(m.y, float)[ok])) if np.any(ok) else 1.0)

    def cost(d):
        j = direct_core_and_branches(plant, base, rows, delay_s=d, sensor_offset=drift, thresholds_v=thresholds_v,
                                     model=model, offset_m=offset_m, fastest_branch_s=fastest_branch_s)
        r = float("nan") if j is None else float(j["residual_m"])
        return r if np.isfinite(r) else worst
    # a scan of the bracket first (the stage's delay, g d and a log grid between the ends), then the bounded search
    # between the best point's neighbours: a golden section over the whole bracket took its first point at 38 % of
    # it, and where no fit exists there (a drawn 100 kHz record, g 3.75: 18-274 ms, the delay 36.6 ms) it walked
    # to the far end on flat costs and never saw the stage's delay (session 15)
    grid = np.unique(np.r_[sign * np.geomspace(lo, hi, DELAY_SCAN_POINTS), ends])
    costs = np.array([cost(d) for d in grid])
    k = int(np.argmin(costs))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
    best_d, best_c = float(grid[k]), float(costs[k])
    if b > a:
        sol = minimize_scalar(cost, bounds=(a, b), method="bounded", options={"xatol": 0.02 * dt, "maxiter": 16})
        if sol.fun < best_c:
            best_d, best_c = float(sol.x), float(sol.fun)
    stage = float(costs[np.argmin(np.abs(grid - delay_s))])
    return best_d if best_c < stage else float(delay_s)


def creep_driver(core_fit, params, u0):
    """What a creep stage's branches were driven by: ``core_fit["creep_drive"]`` (V_h in the model's units,
    :mod:`.creep_across`) when its parameters say ``driver: v_h``, or the drive model refitted at the found delay
    (``driver: refit``, :func:`~workbench.calibrate.creep_beside_delay.creep_beside_delay`), else the base model's
    prediction ``u0``."""
    drive = (core_fit or {}).get("creep_drive")
    return np.asarray(drive, float) if params.get("driver") in ("v_h", "refit") and drive is not None else u0


def _fitted_motion(base, core_fit, rows, terms=None):
    """A model of the displacement fitted on the development ``rows``, m, every sample: what stands in for the
    record off those rows in :func:`~workbench.calibrate.core_refit.direct_core_and_branches`.

    The fitted model's joint fit (``core_fit``: plays and creep spectrum on the base's ``u0``) with its delay
    as a gain on the shifted ``u0`` (the stage's term is the REFITTED model shifted, not at hand here) or as
    a shift of the whole motion, or the base alone (``u0``): whichever is closest to the record on ``rows``
    (each with its offset fitted there). Measured, seed 29 #75 (100 kHz, a 130-sample delay whose joint gain
    came out 15.3): the gain form alone stood in 10x worse and the written file left 21x error_after.
    Returns (the model, m; the record's offset, m; "model" or "base": which form's offset that is)."""
    from .base_fit import plays_basis
    from .effects import lowpass
    m = base.channels["displacement"]
    t = np.asarray(base.t, float)
    dt = float(np.mean(np.diff(t)))
    u0 = np.asarray(m.yhat, float)
    x = np.asarray(plays_basis(base, "displacement"), float)[:, :-1] @ np.asarray(core_fit["weights"], float)
    gain, shift = np.zeros(t.size), 0.0
    for st in core_fit.get("stages", ()):
        p = st["parameters"]
        if st["effect"] == "creep":
            u = creep_driver(core_fit, p, u0)
            for c, tau in zip(p["gains"], p["taus_s"]):
                if c > 0:
                    x = x + c * (lowpass(u, tau, dt) - u)
        elif st["effect"] == "delay":
            shift = float(p["delay_s"])
            gain = float(p.get("scale", 1.0)) * (np.interp(t - shift, t, u0) - u0)
    ok = np.asarray(rows, bool) & np.asarray(m.valid, bool) & np.isfinite(m.y)
    y = np.asarray(m.y, float)
    best = None
    # the record's offset by the candidate: the fitted model's plays and creep carry none (x: no constant
    # column; the creep's lowpass at rest at u0's start), u0 (the base's yhat) carries the base fit's
    for cand, own, name in ((x + gain, 0.0, "model"), (np.interp(t - shift, t, x), 0.0, "model"),
                            (u0, float(m.offset), "base")):
        off = float(np.mean(y[ok] - cand[ok]))
        err = float(np.sqrt(np.mean((y[ok] - cand[ok] - off) ** 2)))
        if best is None or err < best[0]:
            best = (err, cand + off, off + own, name)
    if terms is not None and terms.get("channel") == "displacement" and terms.get("base") is not None:
        # the first stage's own fitted model (the tracing's prediction, its base refitted with the stage, its offset
        # in it) stands in where it is closer; the record's offset stays the forms' above (session 15: a drawn
        # 100 kHz creep+delay record at 29x, delay gain 3.75: the forms above stood in at 5.6e-7 m on the rows,
        # this at 2.2e-8 m)
        first = np.asarray(terms["base"], float) + np.asarray(terms["term"], float)
        off = float(np.mean(y[ok] - first[ok]))
        if float(np.sqrt(np.mean((y[ok] - first[ok] - off) ** 2))) < best[0]:
            best = (None, first + off, best[2], best[3])
    return best[1], best[2], best[3]


def _core_with_branches(plant, base, result, core):
    """``core`` (:func:`~workbench.calibrate.core_refit.refitted_core`'s) with C_h and the creep's branches
    fitted together to the record's development rows through the file's sensor delay and drift
    (:func:`~workbench.calibrate.core_refit.direct_core_and_branches`); None when that fit has no C_h."""
    from .core_refit import FASTEST_BRANCH_OF_RC, direct_core_and_branches
    stages = written_stages(result.get("stages") or [], result, core)
    delay, drift = _sensor_terms(stages, base)
    rows = np.asarray(base.train, bool)
    named = [st for st in stages if st["effect"] == "delay" and st["channel"] == "displacement"]
    gain = float(named[0]["parameters"].get("scale", 1.0)) if named else 1.0
    stage_delay = delay
    # C_h's thresholds: the refitted instant core's, the base's plays inverted in closed form into V_h (Kuhnen):
    # measured against the base's V_t thresholds scaled to V_h's span, seeds 24 #31, 25 #20, 24 #64: 1.37x,
    # 1.15x, 1.05x -> 0.45x, 0.85x, 0.85x error_after
    th = core["hysteresis"].thresholds if core.get("hysteresis") is not None else None
    model, model_offset, stand_in = _fitted_motion(base, result.get("core_fit"), rows, result.get("terms"))
    # the resistor in and the drive the recorded V (not V - R i): V_h = V - q / C_pp carries the R C lag, which
    # a branch near R C copies (R = 80 ohm: 0.12 -> 0.40 of the creep's RMS held out); the grid starts above it
    fastest = None
    r_ohm, c_pp = float(plant.pzt.series_resistance_ohm), float(plant.pzt.c_pp_f)
    if r_ohm > 0 and "V - R i" not in str(getattr(base, "voltage_source", "")):
        fastest = FASTEST_BRANCH_OF_RC * r_ohm * c_pp
    # the fitted model's offset when a fitted model's form is closest; when the base alone is (the fitted model's
    # forms worse), its offset is the base fit's, fitted without creep and biased by it: searched (session 15,
    # a drawn 100 kHz creep+delay record at 29x, delay gain 3.75: the base's offset left the fit's residual 5.1e-8
    # m, the searched one 2.0e-8 m)
    fixed = model_offset if OFFSET_FROM == "model" and stand_in == "model" else None
    if named and delay:
        # the record's offset searched at the stage's delay, held through the delay's search, searched again after
        j0 = direct_core_and_branches(plant, base, rows, delay_s=delay, sensor_offset=drift, thresholds_v=th,
                                      model=model, offset_m=fixed, fastest_branch_s=fastest)
        delay = _delay_with_branches(plant, base, rows, delay, drift, th, model, gain=gain,
                                     offset_m=None if j0 is None else j0["offset_m"], fastest_branch_s=fastest)
    j = direct_core_and_branches(plant, base, rows, delay_s=delay, sensor_offset=drift, thresholds_v=th, model=model,
                                 offset_m=fixed, fastest_branch_s=fastest)
    if j is None or not len(j["caps_f"]) or not (np.all(np.isfinite(j["hysteresis"].weights))
                                                  and np.all(np.isfinite(j["caps_f"]))):
        return None
    lo, hi = core["range_v"]
    out = dict(core)
    out.update(hysteresis=j["hysteresis"], joint=True, refined_branches=(j["caps_f"], j["taus_s"], j["residual_m"]),
               offset_m=j["offset_m"], sensor_delay_s=float(delay), fastest_branch_s=fastest)
    if named and delay != stage_delay:
        out["delay_s"] = (delay, stage_delay)
    out["how"] = (f"C_h and the creep's Kelvin-Voigt branches across it fitted together to the record's displacement "
                  f"over V_t {lo:.4g} .. {hi:.4g} V (development rows; the sensor's delay {1e3 * delay:.4g} ms"
                  + (" and drift" if drift is not None else "") + f" undone, the record's offset {j['offset_m']:.6g} m "
                  + ("out, the fitted model's" if fixed is not None else
                     "out, searched on the development rows' residual")
                  + f"; the base fit's {float(base.channels['displacement'].offset):.6g} m): the record's "
                  "charge q = x / k_q2x (k_q2x declared) gives V_h = V_t - q / C_pp, and q = C_h(V_h) + sum C_j "
                  "lowpass_j(V_h) is linear in C_h's weights and the C_j (non-negative least squares; time constants "
                  "half a decade apart up to the record's length"
                  + (f", from {FASTEST_BRANCH_OF_RC:g} R C_pp = {1e3 * fastest:.4g} ms: the resistor is in and the "
                     "drive is the recorded V, not V - R i, so V_h carries the R C lag" if fastest else "")
                  + f"); residual {j['residual_m']:.4g} m RMS; thresholds "
                  "in V_h; beyond that range it continues at its last loading slope (extrapolated, every play moving)")
    return out


def written_stages(stages, result, core):
    """The stages as the file writes them: the first channel's joint parameters (:func:`_joint_stages`: the
    fitted model's, each stage's gains refitted with every later one), whichever core is written.

    Session 15: with the declared core the stages' own parameters were written, an earlier stage's fitted
    before the later ones were found (seed 24 #55, 10 kHz sine, drift then a 45 Hz resonance: the drift's
    rate as fitted alone, -1.94 um/s, against the joint fit's -1.87 um/s, drawn -1.87 um/s; the file left
    1.99x error_after)."""
    out = _joint_stages(stages, result.get("core_fit"))
    if core.get("mode"):            # refitted by replay through the file (_refit_mode)
        f, z, fn, zn = core["mode"]
        out = [{**st, "parameters": {**st["parameters"], "f_n_hz": f, "zeta": z, "f_named_hz": fn, "zeta_named": zn}}
               if st["effect"] == "resonance" and st["channel"] in ("displacement", "gauge") else st for st in out]
    if core.get("hysteresis") is None:
        return out
    if core.get("delay_s"):         # searched with the core and branches fitted together (_delay_with_branches)
        d, named = core["delay_s"]
        out = [{**st, "parameters": {**st["parameters"], "delay_s": d, "delay_named_s": named}}
               if st["effect"] == "delay" and st["channel"] == "displacement" else st for st in out]
    return out


def _joint_stages(stages, core_fit):
    """The stages with the parameters of the first channel's last joint fit (``core_fit["stages"]``, in order)."""
    if not core_fit:
        return stages
    joint = list(core_fit.get("stages", ()))
    out = []
    for st in stages:
        if joint and (st["effect"], st["channel"]) == (joint[0]["effect"], joint[0]["channel"]):
            st = {**st, "parameters": joint.pop(0)["parameters"]}
        out.append(st)
    return out


def _block(effect, ch, p, base, src, sensor, note=None, plant=None, core=None, core_fit=None):
    """The plant-file lines of one effect (a displacement sensor's go into ``sensor``).

    ``note``: the stage's note (a named leakage's: the absorption time constant the record cannot
    identify, :func:`~workbench.calibrate.absorption_or_leakage.leakage_note`), written as a
    comment line in the effect's section.
    """
    block = []
    if effect == "leakage" and p.get("gain_per_s", 0) > 0:
        block = ["[leakage]", *([f"# {' '.join(note.split())}"] if note else []),
                 f"resistance_ohm = {_fmt(1.0 / p['gain_per_s'])}   # ohm; {src} (leakage fit)"]
    elif effect == "dielectric_absorption" and p.get("gain", 0) > 0:
        block = ["[dielectric_absorption]", f"gain_f = {_fmt(p['gain'])}   # F (k_s); {src}",
                 f"time_constant_s = {_fmt(p['tau_s'])}   # s; {src}"]
    elif effect == "creep" and ch == "displacement":
        w = _creep_write_out(p, base, plant, core, refine=True, core_fit=core_fit)
        if w["capacitances_f"] is None:
            sensor["creep_note"] = w["reason"]
        else:
            block = ["[creep]", f"# {w['how']}",
                     f"time_constants_s = [{', '.join(_fmt(x) for x in w['time_constants_s'])}]   # s; {src}",
                     f"capacitances_f = [{', '.join(_fmt(x) for x in w['capacitances_f'])}]   # F; {src}"]
    elif effect == "resonance" and ch in ("displacement", "gauge"):
        # the stack's mode: the gauge reads the stack's own strain (eq. 27), so a mode named on the gauge
        # (where a drift of the displacement sensor hid it) is the same mechanical mode, written once
        seen = " on the gauge, which reads the stack's motion" if ch == "gauge" else ""
        again = (f"; refitted by replay through this file on the development rows, the tracing named "
                 f"{p['f_named_hz']:.6g} Hz, zeta {p['zeta_named']:.4g} with its gain free" if "f_named_hz" in p else "")
        block = ["[[mechanics.modes]]", f"freq_hz = {_fmt(p['f_n_hz'])}   # Hz; {src} (resonance fit{seen}{again})",
                 f"damping_ratio = {_fmt(min(max(p['zeta'], 1e-6), 1.0))}   # {src}"]
    elif effect == "delay" and ch == "displacement":
        # signed: > 0 the sensor lags the drive, < 0 it leads (an acquisition timing offset)
        lead = " (negative: the sensor leads the drive)" if p["delay_s"] < 0 else ""
        if "delay_named_s" in p:
            lead += (f" (searched with the core and the creep's branches fitted together; the delay stage named "
                     f"{p['delay_named_s']:.6g} s with its gain free)")
        sensor["delay"] = f"delay_s = {_fmt(p['delay_s'])}   # s; {src}{lead}"
    elif effect == "drift" and ch == "displacement":
        c = np.asarray(p["coefficients"], float)
        span = p["t_end_s"] - p["t0_s"]
        rate = c[1] / span if c.size > 1 else 0.0
        curv = c[2] / span ** 2 if c.size > 2 else 0.0
        sensor["drift"] = [f"drift_rate_m_per_s = {_fmt(rate)}   # m/s; {src} (from the record's start)",
                           f"drift_curvature_m_per_s2 = {_fmt(curv)}   # m/s^2; {src}"
                           + ("; its slow periodic term has no plant-file form (JSON)" if p.get("period_s") else "")]
    elif effect == "gauge_nonlinearity":
        b0, why = bow_about_rest(p, base)
        if why is None:
            block = ["[gauge_nonlinearity]",
                     f"# the tracing's bow {float(p['coefficient_per_m']):.6g} /m about the record's mean displacement "
                     f"(x_ref {1e6 * float(p.get('x_ref', 0.0)):.4g} um, {1e6 * _bow_x0(p, base):.4g} um from rest) "
                     f"taken to rest, where the file's bow is written (b / (1 - b x_ref))",
                     f"coefficient_per_m = {_fmt(b0)}   # 1/m; {src}"]
    return block


def _bow_field():
    from ..plant.files import PLANT_FIELDS
    return PLANT_FIELDS["gauge_nonlinearity"]["coefficient_per_m"]


def _bow_x0(p, base):
    """The bow's reference from rest, m: the tracing's ``x_ref`` (the record's mean displacement on the development
    rows) less the displacement's zero, the base fit's offset (the plays are 0 at rest)."""
    off = 0.0
    if base is not None and "displacement" in getattr(base, "channels", {}):
        off = float(base.channels["displacement"].offset)
    return float(p.get("x_ref", 0.0)) - off


def bow_about_rest(p, base):
    """The gauge bow as the plant file carries it: ``(coefficient_per_m about rest, None)``, or ``(b, reason)`` when
    the file cannot carry it.

    The tracing's bow (:class:`~workbench.calibrate.effects.GaugeNonlinearity`) is ``d / (1 + b' d)`` about the
    record's mean displacement ``x_ref`` (its gain taken by the refitted gauge line); the file's (and the
    simulator's, :func:`workbench.plant.additions.gauge_bow`) is ``x / (1 + b x)`` about rest. The two are one
    map: ``f(x) - f(x0) = d / ((1 + b x0)^2 (1 + b' d))`` with ``b' = b / (1 + b x0)``, so ``b = b' / (1 - b' x0)``
    (``x0`` the reference from rest, :func:`_bow_x0`) and the gain ``1 / (1 + b x0)^2`` is the declared gauge's.
    Written as the tracing's ``b'`` the file bowed about the wrong point (session 23: 12 % off the drawn
    coefficient at a 3 um mean; the drawn -1.45e5 /m came back -2.26e5).

    Not carried (the reason): ``b' x0 >= 1`` (no bow about rest has that shape), a map whose pole ``x = -1/b``
    lies within the record's motion from rest (``1 + b x`` not positive there: the gauge would fold over; the
    tracing's quadratic is then no bow the file's form can hold), or ``b`` beyond the plant file's
    ``coefficient_per_m`` range (a file that would not load is never written).
    """
    bp = float(p.get("coefficient_per_m", np.nan))
    x0 = _bow_x0(p, base)
    f = _bow_field()
    if not np.isfinite(bp):
        return bp, "the fitted bow is not finite"
    den = 1.0 - bp * x0
    if not den > 0:
        return bp, (f"the bow {bp:.4g} /m about the record's mean displacement ({1e6 * x0:.4g} um from rest) has no "
                    f"bow about rest of that shape (1 - b x_ref = {den:.3g})")
    b = bp / den
    lo = hi = None
    if base is not None and "displacement" in getattr(base, "channels", {}):
        m = base.channels["displacement"]
        y = np.asarray(m.y, float)[np.asarray(m.valid, bool) & np.isfinite(m.y)] - float(m.offset)
        if y.size:
            lo, hi = float(y.min()), float(y.max())
    if lo is not None and not min(1.0 + b * lo, 1.0 + b * hi) > 0:
        return b, (f"the gauge bow {b:.4g} /m (about rest; {bp:.4g} /m about the record's mean) has its pole "
                   f"1 + b x = 0 at {1e6 * (-1.0 / b):.4g} um from rest, within the record's motion {1e6 * lo:.4g} .. "
                   f"{1e6 * hi:.4g} um: beyond the plant file's bow x / (1 + b x), which folds over at its pole (the "
                   f"fit is a quadratic no file bow holds): not written (JSON only)")
    if not f.lo <= b <= f.hi:
        return b, (f"the gauge bow {b:.4g} /m (about rest; {bp:.4g} /m about the record's mean) is beyond the plant "
                   f"file's coefficient_per_m range [{f.lo:g}, {f.hi:g}] /m: not written (JSON only)")
    return b, None


def _bow_fits_the_file(p, base=None):
    """Does the plant file carry the fitted bow (:func:`bow_about_rest`)? A bow it cannot is not written and is a
    gap (:func:`plant_file_gaps`), as a creep branch beyond the file's 1 mF: a file that would not load is never
    written."""
    return bow_about_rest(p, base)[1] is None


def _terminal_secant(base, plant):
    """(C_s, C_pp, where, C_r): the declared core's terminal secant over the record's voltage span, F.

    ``C_s`` = span of ``G^-1[V]`` over span of ``V`` (``G`` the core's terminal operator, the record's drive
    ``base.v_drive`` from rest): the series of C_h and C_pp the file's core gives the written branches. The
    declared core's, not the base fit's charge: the file carries the declared core, and the simulated
    settled/instant ratio is set by its C_h; it needs no charge channel. ``C_r``: C_h's reversal slope
    (the threshold-0 play's weight), F.
    """
    v = np.asarray(base.v_drive, float)
    q = plant.pzt.terminal_operator().inverse()(v)
    span = float(np.ptp(v))
    c_s = float(np.ptp(q)) / span if span > 0 else float("nan")
    where = f"the declared core's terminal secant over the record's {span:.4g} V span"
    return c_s, float(plant.pzt.c_pp_f), where, float(plant.pzt.hysteresis.weights[0])


#: Creep branches slower than the record (tau > its duration T) are identified only by their rate c/tau
#: (their settled share is nearly collinear with the plays): "rate" writes them at tau = T with c T/tau (the
#: same initial rate), "out" leaves them out of the [creep] section (their instant share stays in the core).
SLOW_BRANCHES = "rate"


def _creep_fractions(p, base, core, slow=None):
    """A creep stage's spectrum as fractions of the refitted core's instant response (:mod:`.core_refit`).

    The spectrum's columns are ``c_j (lowpass_j(u0) - u0)``, ``u0`` the base-alone prediction; the file's core
    is the instant response ``I`` (less the branches within the record): branch j adds ``c_j u0`` when settled,
    ``a_j = c_j span(u0) / span(I)`` of it (spans over the development rows). Branches slower than the record
    as :data:`SLOW_BRANCHES` says (their ``-c_j u0`` is in the core; their rate ``c_j / tau_j`` is written or not).

    Returns
    -------
    gains, taus_s : ndarray
        Fractions of the instant response and time constants, s (slow ones merged at the record's length).
    note : str
        What was done with the slow branches.
    """
    slow = SLOW_BRANCHES if slow is None else slow
    m = base.channels[core["channel"]]
    rows = np.asarray(base.train, bool)
    from .base_fit import plays_basis
    inst = np.asarray(plays_basis(base, core["channel"]), float)[:, :-1] @ core["instant"]
    span_i = float(np.ptp(inst[rows]))
    ratio = float(np.ptp(np.asarray(m.yhat, float)[rows])) / span_i if span_i > 0 else float("inf")
    g = np.maximum(np.asarray(p["gains"], float), 0.0) * ratio * float(core.get("creep_scale", 1.0))
    tau = np.asarray(p["taus_s"], float).copy()
    dur = float(base.t[-1] - base.t[0])
    late = (tau > dur) & (g > 0)
    note = "no branch slower than the record"
    if late.any():
        if slow == "rate":
            note = (f"{int(late.sum())} branches slower than the record ({dur:.4g} s) written as one at tau = {dur:.4g} s "
                    f"with a = sum a_j T/tau_j (the same initial rate; their settled share is not identified)")
            rate_sum = float(np.sum(g[late] * dur / tau[late]))
            g, tau = np.r_[g[~late], rate_sum], np.r_[tau[~late], dur]
        else:
            note = (f"{int(late.sum())} branches slower than the record ({dur:.4g} s) left out (their rate is not "
                    f"carried; their instant share is in the core)")
            g, tau = g[~late], tau[~late]
    return g, tau, note


def _creep_write_out(p, base, plant, core=None, refine=False, core_fit=None):
    """:func:`creep_branches` of a creep stage's spectrum.

    With a refitted core (``core["hysteresis"]``, :func:`~workbench.calibrate.core_refit.refitted_core`): the
    branches across the refitted C_h, as fractions of its instant response (:func:`_creep_fractions`).
    Without: C_h from the declared core over the record's terminal voltage. None for an amplifier-command
    record (its drive is in command volts, not the stack's: a secant over it would be meaningless)."""
    if getattr(base, "input_kind", "terminal") != "terminal":
        return {"capacitances_f": None, "time_constants_s": None, "c_h_f": None, "how": None,
                "reason": "the record's input is an amplifier command: the declared core's C_h is not "
                          "read over command volts"}
    if core is not None and core.get("hysteresis") is not None:
        import dataclasses
        if core.get("creep_scale", 1.0) == 0.0:
            return {"capacitances_f": None, "time_constants_s": None, "c_h_f": None, "how": None,
                    "reason": "branches across the refitted C_h cannot carry even a fifth of its share (at or above the "
                              "ceiling 1 + C_pp/C_h): the core is the fitted model's settled response, no branches"}
        if core.get("joint"):          # C_h and the branches fitted together (core_for): nothing to size
            caps, taus, resid = core["refined_branches"]
            return {"capacitances_f": np.asarray(caps, float), "time_constants_s": np.asarray(taus, float),
                    "c_h_f": None, "reason": None, "ratio": None,
                    "how": (f"C_j and tau_j fitted together with C_h (see [hysteresis]) to the record's displacement ("
                            f"residual {resid:.4g} m RMS on the development rows; the branches uncharged at the "
                            f"record's start" + ("" if getattr(base, "starts_from_rest", True) else
                                                 " (it does NOT start from rest: charged branches there bend the C_j)")
                            + ")")}
        refit = dataclasses.replace(plant, pzt=dataclasses.replace(plant.pzt, hysteresis=core["hysteresis"]))
        sec = _terminal_secant(base, refit)
        g, tau, note = _creep_fractions(p, base, core)
        out = creep_branches(g, tau, sec[0], sec[1], "the refitted core's terminal secant over the record's span",
                             c_rev_f=sec[3], of_instant=True)
        if refine and out["capacitances_f"] is not None and core_fit is not None:
            from .core_refit import creep_target, refine_branches
            if "refined_branches" not in core:       # once per core (the file is written more than once)
                target = creep_target(base, core_fit, core, p)
                core["refined_branches"] = refine_branches(refit, base, target, out["capacitances_f"],
                                                           out["time_constants_s"], base.train)
            caps, taus, before, after = core["refined_branches"]
            out["capacitances_f"], out["time_constants_s"] = caps, taus
            if _beyond_the_loader(out):
                return out
            out["how"] += (f"; then C_j and tau_j refitted by simulating this core with the branches on the record's "
                           f"development rows against the fitted model's creep: misfit {100 * before:.3g} % -> "
                           f"{100 * after:.3g} % of its RMS")
        if out["how"]:
            share = core.get("creep_scale", 1.0)
            out["how"] += f"; {note}" + ("" if share == 1.0 else
                                         f"; {share:.0%} of the fitted branches (all of them: above the ceiling)")
        return out
    sec = _terminal_secant(base, plant)
    return creep_branches(p["gains"], p["taus_s"], *sec[:3], c_rev_f=sec[3])


def _beyond_the_loader(out):
    """Does a branch exceed the plant file's limit on a branch's capacitance? (bool; then ``out`` says why, no branches)

    Near the ceiling ``A C_h -> C_pp`` the map to ``C_S`` diverges and a branch may come out above the 1 mF the
    plant loader takes (``[creep] capacitances_f``; :data:`~.core_refit.BRANCH_CAP_F`): a file with it would not
    load (session 15: 25 #78's declared core wrote 3.5 mF and the round trip stopped). No ``[creep]`` section is
    written then, and the reason is the file's gap, as for the other spectra no section can represent."""
    from .core_refit import BRANCH_CAP_F
    caps = out.get("capacitances_f")
    if caps is None or not np.size(caps) or float(np.max(caps)) <= BRANCH_CAP_F:
        return False
    out["reason"] = (f"a branch of {float(np.max(caps)):.4g} F, above the plant file's {BRANCH_CAP_F:g} F per branch (the "
                     f"spectrum's settled/instant ratio near the ceiling 1 + C_pp/C_h that branches across C_h can give)")
    out["capacitances_f"] = out["time_constants_s"] = None
    return True


def creep_branches(gains, taus_s, c_s_f, c_pp_f, where="the terminal secant", c_rev_f=None, of_instant=False):
    """Kelvin-Voigt branches across C_h whose step response is the fitted creep spectrum's.

    The displacement is proportional to the terminal charge ``q = q_h + sum Q_j`` (``V_t = V_h + q/C_pp``,
    the branches across C_h, :mod:`workbench.plant.creep`). With ``V_t`` held and C_h linear, the instant
    charge is ``C_h C_pp / (C_h + C_pp) V``, the settled one ``(C_h + C_S) C_pp / (C_h + C_S + C_pp) V``
    (``C_S = sum C_j``). The spectrum ``u (1 - sum c) + sum c_j lowpass_j(u)`` has settled over instant
    ``1 / (1 - sum c) = 1 + A``, hence ``C_S = A C_h (C_h + C_pp) / (C_pp - A C_h)``; ``C_h = (1/C_s - 1/C_pp)^-1``
    from the terminal secant ``C_s``. The map is not linear (it diverges at the ceiling ``A C_h = C_pp``), so
    ``C_S`` is not shared in proportion to ``c_j``: in order of time constant, when branch k settles the faster
    ones have (each across C_h, adding to its capacitance) and the slower have not moved, and the spectrum
    reads ``1 + A_k``, ``A_k = sum_{j<=k} c_j / (1 - sum c)``: ``C_k = C_S(A_k) - C_S(A_{k-1})``, and branch k
    relaxes with ``tau_k (C_h' + C_pp) / (C_k + C_h' + C_pp)``, ``C_h' = C_h + C_S(A_{k-1})``. A branch alone relaxes at a held
    ``V_t`` with ``tau_j (C_h + C_pp) / (C_j + C_h + C_pp)`` (``tau_j = R_j C_j`` the file's), so the file's
    ``tau_k`` is the fitted one times ``(C_k + C_h' + C_pp) / (C_h' + C_pp)``. C_h is not linear: the
    branches, charging, pull ``V_h`` back (a reversal), where C_h's slope is its reversal slope ``C_r``
    (the threshold-0 play's weight), not the secant that set the instant response; with ``C_r`` the
    settled charge gives ``C_S(A) = A C_h (C_r + C_pp) / (C_pp - A C_h)`` and the factor
    ``(C_k + C_r' + C_pp) / (C_r' + C_pp)``, ``C_r' = C_r + C_S(A_{k-1})`` (``C_r = C_h``: the linear forms).

    Parameters
    ----------
    gains, taus_s : array_like of float
        The fitted spectrum's ``c_j`` (fractions of the settled displacement) and time constants, s.
    c_s_f, c_pp_f : float
        Terminal secant ``C_s`` and ``C_pp``, F.
    c_rev_f : float, optional
        C_h's reversal slope ``C_r``, F (default: C_h, linear).
    where : str
        Where ``C_s`` came from (said in the file).
    of_instant : bool
        ``gains`` are fractions of the INSTANT response (the refitted core's, :mod:`.core_refit`): the
        settled/instant ratio is ``1 + sum gains`` and branch k reads ``A_k = sum_{j<=k} gains_j``.

    Returns
    -------
    dict
        ``capacitances_f``, ``time_constants_s`` (ndarrays; None when no ``[creep]`` section can represent
        the spectrum: ``sum c >= 1``, ``C_s >= C_pp`` or above the ceiling ``A C_h >= C_pp``), ``c_h_f``,
        ``ratio`` (settled / instant), ``how`` (the file's comment) and ``reason`` (why none).
    """
    g, tau = np.asarray(gains, float), np.asarray(taus_s, float)
    keep = g > 0
    total = float(g[keep].sum())
    share = 1.0 if of_instant else 1.0 - total       # the instant response over the settled one's scale
    out = {"capacitances_f": None, "time_constants_s": None, "c_h_f": None, "reason": None, "how": None,
           "ratio": (1.0 + total) if of_instant else (1.0 / (1.0 - total) if total < 1.0 else float("inf"))}
    if not keep.any():
        out["reason"] = "the spectrum has no positive gain"
        return out
    if total >= 1.0 and not of_instant:
        out["reason"] = (f"sum c = {total:.4g} >= 1 (branches slower than the record standing in for a gain): no "
                         f"settled/instant ratio a [creep] section can carry")
        return out
    if not (np.isfinite(c_s_f) and 0 < c_s_f < c_pp_f):
        out["reason"] = f"the terminal secant {c_s_f:.4g} F is not below C_pp {c_pp_f:.4g} F: no C_h to put branches across"
        return out
    c_h = 1.0 / (1.0 / c_s_f - 1.0 / c_pp_f)
    a = total / share
    out["c_h_f"] = c_h
    if a * c_h >= c_pp_f:
        ceil = 1.0 + c_pp_f / c_h
        out["reason"] = (f"settled/instant {1 + a:.4g} is at or above the ceiling 1 + C_pp/C_h = {ceil:.4g} that branches "
                         f"across C_h can give (C_h {c_h:.4g} F, C_pp {c_pp_f:.4g} F)")
        return out
    c_r = c_h if c_rev_f is None else float(c_rev_f)

    def settled(a_k):      # the branches' summed capacitance giving settled/instant 1 + a_k
        return a_k * c_h * (c_r + c_pp_f) / (c_pp_f - a_k * c_h)
    # in order of time constant: when branch k settles the faster ones have (across C_h, adding to its
    # capacitance) and the slower ones have not moved; the spectrum there reads 1 + sum_{j<=k} c_j / (1 - sum c)
    order = np.argsort(tau[keep])
    gk, tk = g[keep][order], tau[keep][order]
    cum = np.cumsum(gk) / share
    c_cum = np.array([settled(x) for x in cum])
    before = np.concatenate([[0.0], c_cum[:-1]])
    c_j = c_cum - before
    ok = c_j > 1e-9 * c_cum[-1]        # a gain lost in the rounding of the sums (1e-19 of a fit) is no branch
    out["capacitances_f"] = c_j[ok]
    out["time_constants_s"] = (tk * (c_j + c_r + before + c_pp_f) / (c_r + before + c_pp_f))[ok]
    if _beyond_the_loader(out):
        return out
    out["how"] = ("C_j from settled/instant " + ("1 + sum a" if of_instant else "1/(1 - sum c)")
                  + f" = {1 + a:.4g} (sum {'a' if of_instant else 'c'} = {total:.4g}) across C_h = {c_h:.4g} F "
                  f"(C_h = (1/C_s - 1/C_pp)^-1, C_s = {c_s_f:.4g} F {where}, C_pp = {c_pp_f:.4g} F, C_h's reversal slope "
                  f"C_r = {c_r:.4g} F); in order of time constant C_k = C_S(A_k) - C_S(A_(k-1)), tau_k the fitted one x "
                  f"(C_k + C_r' + C_pp)/(C_r' + C_pp), C_r' = C_r + C_S(A_(k-1)): each branch settles with the faster "
                  f"ones settled and the slower unmoved (an approximation: time constants a decade apart)")
    return out


#: The recorded drive is replayed interpolated linearly onto up to this many points per sample
#: (:func:`~workbench.calibrate.synthetic.simulate_record`'s ``upsample``): the tracing's models take the
#: drive linear between samples (``calibrate/effects.py``), the simulator holds each command; a mode near
#: the sample rate tells the two apart (:func:`replay_upsample`).
REPLAY_UPSAMPLE = 8

#: The fine steps per period of the plant's highest mode the replay asks for (:func:`replay_upsample`).
REPLAY_STEPS_PER_MODE_PERIOD = 8

#: The longest fine step of the replay, s: a command held over a step lags the linear drive by half of it;
#: 12.5 us is 8 points a sample at 10 kHz, where the plant that made the record leaves the sensor's noise
#: (``tests/calibrate/test_round_trip.py``). Derived from the modes alone, a plant whose only mode is a
#: 200 Hz one was replayed at 1-2 points a sample at 1-10 kHz, and the plant that made the record left up
#: to 2.8x more (seeds 24-25, measured 2026-11-26).
REPLAY_FINE_STEP_S = 12.5e-6


def replay_upsample(plant, rate_hz):
    """Points per sample of the replay, at most :data:`REPLAY_UPSAMPLE`.

    The larger of ``ceil(1 / (rate REPLAY_FINE_STEP_S))`` (the held command's half-step lag) and
    ``ceil(8 f_max / rate)`` (8 fine steps a period of the highest ``[[mechanics.modes]]`` frequency
    ``f_max``, Hz), clipped to ``1..REPLAY_UPSAMPLE``: 8 at 1-10 kHz, 6 at 100 kHz with the 70 kHz mode of
    ``p888_51_sn637``, none at 1 MHz (the record's own step is 1 us).
    """
    if not rate_hz > 0:
        return REPLAY_UPSAMPLE
    modes = getattr(plant.pzt, "modes", ()) or ()
    f_max = max((float(m.freq_hz) for m in modes), default=0.0)
    need = max(np.ceil(1.0 / (rate_hz * REPLAY_FINE_STEP_S) - 1e-9),
               np.ceil(REPLAY_STEPS_PER_MODE_PERIOD * f_max / rate_hz - 1e-9))
    return int(min(REPLAY_UPSAMPLE, max(1, need)))


_SIM_KEY = {"displacement": "displacement_m", "gauge": "gauge_v", "charge": "q_true_c"}


def updated_plant_error(plant, base, channel, test, train=None, current="averaged", replay=None):
    """Held-out error of the record's drive simulated through ``plant`` (the updated plant file).

    The drive is the base fit's, the terminal voltage ``V_t = V - R i`` (``base.v_drive``), applied
    to the plant with its series resistor taken out (the quasi-static electrical form,
    :meth:`~workbench.plant.pzt.PZTParams.terminal_driven`): the fitted model and the plant file then see one
    input, and the amplifier (its current limit, the monitor's averaging, which a recorded ``V`` cannot give
    back as a command) is left out. The simulation is
    noise-free (no sensor noise, no gauge-chain noise), in chunks (memory bounded whatever the record's
    length), at :func:`replay_upsample` points per sample: the error is the record's noise plus what the
    plant file gets wrong, on the rows of the fitted model's ``error_after``.

    Parameters
    ----------
    plant : workbench.plant.files.Plant
        The updated plant, loaded back from its file.
    base : workbench.calibrate.base_fit.BaseFit
        The base fit: its times ``t``, drive ``v_drive`` (V) and the channel's recorded ``y`` and
        ``valid`` rows.
    channel : {"displacement", "gauge", "charge"}
        The channel compared (the first effect's); the charge is the simulated terminal charge.
    test : ndarray of bool
        The held-out (test) rows.
    train : ndarray of bool, optional
        The development rows: the constant the plant file cannot carry (a sensor's zero, the
        charge's start) is the mean difference over these rows, as the fitted model's offset is
        fitted there; None: no constant is taken out.
    current : {"averaged", "sampled"}
        The record's current convention: unused (the record's charge is the base's, integrated under
        it; the replay's is the simulated charge itself), kept for the callers.
    replay : ndarray, optional
        The channel's replay through this plant, already made (:func:`replayed`): not simulated again.

    Returns
    -------
    dict or None
        ``{rms, max, units}`` on ``test & valid`` (channel units: m, C or V); None for a channel
        the simulator does not log or a drive that is an amplifier command (unknown gain and lag).
    """
    if channel not in _SIM_KEY or channel not in base.channels or base.input_kind != "terminal":
        return None
    return _replay_error(_replay(plant, base, channel) if replay is None else replay, base, channel, test, train)


def replay_key(text, channel):
    """The key of a plant file's replay on ``channel`` in a run's memo (:func:`replayed`): the file's setting lines
    (:func:`_file_lines`; a comment line changes nothing loaded back) and the channel."""
    return "\n".join(_file_lines(text)), channel


def replayed(text, base, channel, path, replays=None):
    """The record's drive replayed through the plant file ``text`` (written to ``path`` and loaded back): the
    ``channel``'s column (:func:`_replay`).

    ``replays``: a run's memo, ``{replay_key: column}``, filled here: a file replayed before on the channel (the
    same setting lines: the same plant loaded back, the same noise-free simulation) is taken from it, not
    simulated again (session 24: ``choose_core``, ``carried_stages`` and the file's test error replayed the file
    with every stage up to three times, ~0.75 s each on a 355,000-row record).
    """
    from pathlib import Path

    from ..plant import load_plant
    key = replay_key(text, channel)
    if replays is not None and key in replays:
        return replays[key]
    path = Path(path)
    path.write_text(text, encoding="utf-8")
    sim = _replay(load_plant(path), base, channel)
    if replays is not None:
        replays[key] = sim
    return sim


#: The fine steps per settle time constant ``RC`` of the held drive's replay (:func:`held_replay_upsample`).
REPLAY_HELD_STEPS_PER_RC = 8

#: The most fine steps a sample of the held drive's replay takes (:func:`held_replay_upsample`).
REPLAY_HELD_UPSAMPLE_MAX = 256


def held_replay_upsample(plant, held):
    """Points per sample of a replay along the held drive's path (:class:`~.effects.HeldDrive`).

    The larger of ``ceil(REPLAY_HELD_STEPS_PER_RC dt / RC)`` (the settle resolved: ``RC`` the path's, s) and
    ``ceil(REPLAY_STEPS_PER_MODE_PERIOD f dt)`` over the ``[[mechanics.modes]]`` below ``1 / (2 pi RC)`` (the
    settle's corner; a mode above it is not driven through the path's shape), clipped to
    ``1..REPLAY_HELD_UPSAMPLE_MAX``: 174 at 100 Hz on the P-888.51's 80 ohm and ~5.7 uF.
    """
    dt, rc = float(held.dt), float(held.rc)
    corner = 1.0 / (2.0 * np.pi * rc)
    modes = [float(m.freq_hz) for m in (getattr(plant.pzt, "modes", ()) or ()) if float(m.freq_hz) <= corner]
    need = max(np.ceil(REPLAY_HELD_STEPS_PER_RC * dt / rc - 1e-9),
               np.ceil(REPLAY_STEPS_PER_MODE_PERIOD * max(modes, default=0.0) * dt - 1e-9))
    return int(min(REPLAY_HELD_UPSAMPLE_MAX, max(1, need)))


def _replay(plant, base, channel):
    """The record's drive simulated through ``plant`` (see :func:`updated_plant_error`): the channel's column."""
    import dataclasses

    from .synthetic import SensorNoise, simulate_record
    from .tracing import held_drive
    t = np.asarray(base.t, float)
    quasi = dataclasses.replace(plant, pzt=plant.pzt.terminal_driven())     # V_t in, no amplifier (its limit) between
    held = held_drive(base)
    if held is None:
        rate = (t.size - 1) / (t[-1] - t[0]) if t.size > 1 and t[-1] > t[0] else 0.0
        up = replay_upsample(quasi, rate)
    else:
        up = held_replay_upsample(quasi, held)
    sim = simulate_record(quasi, t, np.asarray(base.v_drive, float), noise=SensorNoise(0.0, 0.0, 0.0),
                          gauge=channel == "gauge", gauge_noise=False, upsample=up, held=held)
    return sim[_SIM_KEY[channel]]


def _replay_error(sim, base, channel, test, train):
    """``{rms, max, units}`` of a replay on ``test & valid``, the constant over ``train & valid`` taken out."""
    m = base.channels[channel]
    # the charge: the simulated one itself (the simulator's current is a per-sample mean, whatever the
    # record's convention; integrating it as "sampled" lagged half a sample); its start is the offset
    e = sim - m.y
    if train is not None and np.any(train & m.valid):
        e = e - float(np.mean(e[train & m.valid]))
    e = e[test & m.valid]
    return {"rms": float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan"),
            "max": float(np.max(np.abs(e))) if e.size else float("nan"), "units": m.units}


def plant_file_gaps(stages, base, plant, core=None):
    """What of the calibration the updated plant file cannot carry, one phrase a gap.

    Parameters
    ----------
    stages : list of dict
        The calibration's stages (effect, channel, parameters).
    base : workbench.calibrate.base_fit.BaseFit
        The base fit (its drive sets the creep write-out's C_h, :func:`creep_branches`).
    plant : workbench.plant.files.Plant
        The declared plant.
    core : dict, optional
        :func:`core_for` (the refitted core): its reason when it is not written is a gap; with it the
        creep is sized against it.

    Returns
    -------
    list of str
        The refitted core not written (the declared core kept), a stage not written (no plant-file form, or creep beyond what branches across C_h carry), a
        resonance's gain other than 1 (the file's modes have unit DC gain), a drift's slow periodic term.
    """
    from .core_refit import CAP_OF_C_PP, CAPPED_GAP
    gaps = []
    struct = None
    written = core is not None and core.get("hysteresis") is not None
    if core is not None and not written and stages:
        gaps.append(f"the record's core is not written, the declared core is kept ({core['reason']})")
    if written and float(core.get("capped", 0.0)) > CAPPED_GAP:
        gaps.append(f"the record's loading slope is beyond any C_h in series with the declared C_pp: "
                    f"{100 * core['capped']:.3g} % of the core's weights capped at {CAP_OF_C_PP:g} C_pp (the declared "
                    f"C_pp or k_q2x do not fit the record: check the stack's capacitance and stroke)")
    for st in stages:
        eff, ch, p = st["effect"], st["channel"], st.get("parameters") or {}
        if eff == "creep" and ch == "displacement":
            w = _creep_write_out(p, base, plant, core if written and core["channel"] == ch else None)
            if w["capacitances_f"] is None:
                gaps.append(f"the creep was not written ({w['reason']})")
            elif written and core.get("joint") and not getattr(base, "starts_from_rest", True):
                # review of s14: the branches start uncharged in the fit and in the file; a record that does not
                # start from rest has charged branches at its start, which the fit's C_j bend to copy
                gaps.append("the record does not start from rest: the creep's branches were fitted, and are "
                            "replayed, uncharged at its start (charged branches there bend the fitted C_j)")
            elif written and core["channel"] == ch and core.get("creep_scale", 1.0) < 1.0:
                gaps.append(f"only {core['creep_scale']:.0%} of the creep's branches within the record were written "
                            f"(branches across C_h cannot carry them all: the ceiling 1 + C_pp/C_h)")
        elif eff == "resonance" and ch in ("displacement", "gauge") and getattr(plant, "structure", None) is not None:
            # a [structure] plant: the mode is added to its modal model with the tracing's share (no unit-gain gap)
            if struct is None:
                from pathlib import Path
                struct = _declared_structure(Path(plant.source).read_text(encoding="utf-8"), plant)
            why = ("the plant file's [structure] could not be read" if struct is None else
                   _add_structure_mode(struct, p, ""))
            if why:
                gaps.append(f"the resonance at {float(p['f_n_hz']):.4g} Hz was not written ({why})")
        elif eff == "resonance" and ch in ("displacement", "gauge"):
            g = float(p.get("gain", 1.0))
            # the mode refit (_refit_mode) compensated the gain by the file's frequency and damping: no gap
            # (review of s15_rt); where it could not run the gap says why
            if abs(g - 1.0) > 0.01 and not (core or {}).get("mode"):
                skipped = (core or {}).get("mode_refit_skipped")
                gaps.append(f"the resonance's gain {g:.4g} (the file's modes have unit gain"
                            + (f"; the mode refit did not run: {skipped})" if skipped else ")"))
        elif eff == "drift" and ch == "displacement":
            if p.get("period_s"):
                gaps.append("the drift's slow periodic term (JSON only)")
        elif eff == "gauge_nonlinearity" and not _bow_fits_the_file(p, base):
            gaps.append(bow_about_rest(p, base)[1])
        elif eff in ("delay", "drift", "creep") and ch != "displacement":
            gaps.append(f"the {eff} on the {ch} (no plant-file form, JSON only)")
    return gaps


def round_trip_warning(error_after, plant_error, stages, tolerance=None, gaps=(), core_written=False):
    """The warning when the plant file's simulated test error exceeds the fitted model's.

    Parameters
    ----------
    error_after, plant_error : dict
        ``{rms, max, units}``: the fitted model's ``error_after`` and :func:`updated_plant_error`.
    stages : list of dict
        The calibration's stages (effect, channel, parameters).
    tolerance : float, optional
        Relative difference allowed (default :data:`ROUND_TRIP_TOLERANCE`).
    gaps : sequence of str
        :func:`plant_file_gaps`: the causes that apply, named beside the declared core.
    core_written : bool
        The file carries the refitted core (:func:`core_for`): the last cause named is then what the
        file's forms cannot copy of the fitted model, not the declared core.

    Returns
    -------
    str or None
        One line naming both errors and the causes that apply; None within the tolerance, and None
        when the file does better (:func:`round_trip_note` says that).
    """
    tol = ROUND_TRIP_TOLERANCE if tolerance is None else float(tolerance)
    if not plant_error or not error_after or not error_after["rms"] > 0:
        return None
    a, b, u = error_after["rms"], plant_error["rms"], error_after["units"]
    if b <= (1.0 + tol) * a:
        return None
    found = ", ".join(f"{s['effect']} ({s['channel']})" for s in stages) or "no effect"
    last = ("the fitted model's effects act on its base-alone prediction, the file's on the refitted core's "
            "charge (and its stages' forms are approximations: creep branches across a hysteretic C_h)"
            if core_written else
            "the file keeps the declared core (its PI weights and gains) while the fitted model's "
            "base was refitted on the record, taking up what no stage named")
    why = "; ".join([*gaps, last])
    return (f"the updated plant, the record's drive simulated through it, leaves a test RMS of {b:.4g} {u} against "
            f"the fitted model's {a:.4g} {u} ({b / a:.2f}x; found: {found}): {why}")


def replay_above_before_warning(error_before, error_after, source, carried=(), gaps=(), no_replay=None):
    """The top-level warning when the written file's replay is above ``error_before`` (s22_outsider C1).

    ``error_before`` is the base model refitted on the record (its plays, gains and offsets free), not the
    declared file; the file hands the user the declared plant with the core and sections its header names. When
    its replay on the test rows is above ``error_before`` the effect reported found does not make the user's file
    better than that base: said at the top of the printed summary and of the report, with what the file carries
    and what it does not.

    Parameters
    ----------
    error_before, error_after : dict
        ``{rms, max, units}``: the JSON's (``error_after`` the reported one, :func:`reported_error_after`).
    source : str
        ``error_after``'s source: only "updated plant" is the file's replay.
    carried : sequence of dict
        :func:`carried_stages`' list.
    gaps : sequence of str
        :func:`plant_file_gaps`.
    no_replay : str, optional
        Why no file was replayed (:func:`updated_plant_error_reason`): with ``source`` "tracing model" the
        reported ``error_after`` is the tracing model's, and its being above ``error_before`` is said the same way
        (s22_outsider A4: a generic stack's drift extrapolated over the predicted cycles, 654x).

    Returns
    -------
    str or None
    """
    if not error_before or not error_after:
        return None
    a, b, u = float(error_before["rms"]), float(error_after["rms"]), error_before["units"]
    if not (np.isfinite(a) and np.isfinite(b)) or not b > a:
        return None
    if source != "updated plant":
        return (f"the reported error after, the tracing model's (no plant file replayed: {no_replay or 'none'}), is "
                f"{b:.4g} {u} RMS on the test rows, {b / a:.2f}x the error before ({a:.4g} {u}): the effect found "
                f"does not predict this record's held-out rows closer than the base alone")
    kept = [f"{c['effect']} on the {c['channel']}" for c in carried if c.get("written")]
    left = [f"{c['effect']} on the {c['channel']} ({c['reason']})" for c in carried if not c.get("written")]
    said = " ".join(left)
    gaps = [g for g in gaps if g not in said]
    return (f"the updated plant file replays the test rows at {b:.4g} {u} RMS, {b / a:.2f}x the error before "
            f"({a:.4g} {u}, the declared model's base refitted on the record): the effect found does not make the "
            f"file closer to this record than that refit. The file carries "
            + (", ".join(kept) if kept else "no section of an effect found") + "; "
            + ("found but not carried: " + "; ".join(left) + ". " if left else "")
            + ("Gaps: " + "; ".join(gaps) + "." if gaps else "").rstrip())


def reported_error_after(error_after_model, plant_error):
    """The ``error_after`` ``workbench calibrate`` reports: the error of what the user gets (session 15).

    Parameters
    ----------
    error_after_model : dict
        ``{rms, max, units}``: the tracing model's own test error (``trace_effect``'s ``error_after``).
    plant_error : dict or None
        :func:`updated_plant_error` of the written file (its replay on the test rows), None when no file was
        replayed.

    Returns
    -------
    error_after : dict
        ``plant_error`` when it was measured (finite), else ``error_after_model``.
    source : {"updated plant", "tracing model"}
        Which of the two it is.
    """
    if plant_error is not None and np.isfinite(float(plant_error.get("rms", float("nan")))):
        return dict(plant_error), "updated plant"
    return error_after_model, "tracing model"


def round_trip_note(error_after, plant_error, tolerance=None):
    """The note when the plant file's simulated test error is below the fitted model's beyond the tolerance.

    Returns
    -------
    str or None
        One line (a note, not a warning: the file is the better model of this record); None otherwise.
    """
    tol = ROUND_TRIP_TOLERANCE if tolerance is None else float(tolerance)
    if not plant_error or not error_after or not error_after["rms"] > 0:
        return None
    a, b, u = error_after["rms"], plant_error["rms"], error_after["units"]
    if b >= (1.0 - tol) * a:
        return None
    return (f"the updated plant, the record's drive simulated through it, leaves a test RMS of {b:.4g} {u}, below "
            f"the fitted model's {a:.4g} {u} ({b / a:.2f}x): the file (its core as its header says) fits this record "
            f"better than the fitted model")


def updated_plant_error_reason(kind, result, base, channel):
    """Why ``updated_plant_error`` is null (None when it is measured).

    Parameters
    ----------
    kind : {"pzt", "generic_stack"}
        The plant file's kind.
    result : dict
        The calibration's result (its ``stages``).
    base : workbench.calibrate.base_fit.BaseFit
        The base fit (its ``input_kind`` and channels).
    channel : str or None
        The first effect's channel.
    """
    if kind != "pzt":
        return "a generic stack's plant file has no simulator: no replay"
    if not result.get("stages"):
        return "no effect found: the file is the declared plant"
    if base.input_kind != "terminal":
        return ("the voltage is an amplifier command (unknown gain and lag): the record's terminal voltage, which "
                "the replay drives, is not recorded")
    if channel not in _SIM_KEY or channel not in base.channels:
        return f"the {channel} channel is not one the simulator logs"
    return None
