"""Dielectric absorption or leakage: two readings of one charge relaxation (seed 002 eqs. 2.7, 2.9).

Both are charge terms driven by the stack's voltage. **Leakage** is a resistance across the
stack, ``g int V dt``. **Dielectric absorption** is a branch ``R_a`` in series with ``C_a``
across the stack, ``k lowpass_tau(V)`` with ``tau = R_a C_a``. For ``tau`` much longer than the
record (length ``T``),

    k lowpass_tau(V) = (k / tau) int V dt - (k / tau^2) int int V dt + ...

so leakage is the absorption with ``tau -> inf`` at fixed ``k / tau``: the **nested, simpler**
model. Over ``[0, T]`` what the absorption adds to leakage's line is its bend, of RMS
``sqrt(3/5) / 12 x T / tau`` of its term (``t^2`` less its best line on ``[0, T]``,
``T^2 / (6 sqrt 5)``, against ``t``'s ``T / sqrt 3``; 0.0643 exactly at ``tau = T``, 0.0645 by
the expansion).

The decision on one validation fold (:func:`absorption_or_leakage`), when one of the two wins it:

1. the absorption's fitted ``tau`` (searched up to a hundred record lengths) is under
   ``SETTLED_RECORDS`` (half) of the record: it has settled within the record and shows its own
   shape; the fold's ranking stands;
2. its **bend is seen**: what it explains beyond leakage stands above the channel's noise floor
   and is ``min_share`` of what leakage leaves, or above the noise floor on every fold alike
   (:func:`bend_on_every_fold`): absorption;
3. its ``tau`` search ran to its ceiling (:func:`at_ceiling`, ``tau_max_fraction`` = 100 record
   lengths: no finite time constant explains the charge better than leakage's limit; so also
   ``LEAKAGE_TAU_RECORDS`` record lengths or more, its bend under 0.65 % of its term) and the record
   would have shown the bend of every absorption that settles within it: the fastest
   absorption whose bend could hide in what leakage leaves (``tau_bound``, below) is at least
   ``SETTLED_RECORDS`` of the record, the line of step 1. Then the simpler reading, **leakage**,
   is named; an absorption slower than ``tau_bound`` would look the same over this record
   (:func:`leakage_note` says so in the result);
   The record's ruling-out is also *measured* (:func:`settled_ruled_out`, either suffices): an
   absorption of time constant the record's length (``SETTLED_TEST_RECORDS``), fitted on the
   fold in leakage's place, leaves more than leakage by the bar every candidate clears (noise
   floor, ``min_share``). The fitted ``tau`` must still reach ``LEAKAGE_TAU_RECORDS``: without
   that requirement (tried on branch s11_calleak) 1 kHz leakage records whose fit came out 3-9
   record lengths were named, but so was an 18x absorption of a 0.4 s record (seed 24 #80),
   whose slow relaxation the folds cannot tell from leakage;
4. otherwise the fold is undecided between the two (``UNDECIDED``).

Session 15 (branch s15_ends): step 3 asked ``tau >= LEAKAGE_TAU_RECORDS`` record lengths only, and
an absorption whose finite time constant the search found beyond the record (bend unseen) was named
leakage: seed 45 #69 (100 kHz, 0.4 s, a 17x absorption of 3.2 record lengths, fitted 52: leakage 5
of 5) and 31 #135 (1 MHz, 0.1 s, 30x, 12.4 records, fitted 11.1: leakage 4 of 5). Over such a
record the two readings are one (neither's fit leaves the other's bar beyond it on any validation
fold), so the fold is now undecided, and an ``inconclusive`` answer carries :func:`too_short_note`
(both lead; the record that would show the fitted absorption's shape, ``tau / SETTLED_RECORDS``).
Every leakage the confusion benchmark names at 1-100 kHz on seeds 41-42 had its absorption fit at the
ceiling (100 record lengths) and is still named; an absorption slower than the record whose fit
runs to the ceiling is still named leakage (the record prefers leakage's limit; the note says
what it leaves open).

Over the folds (:func:`nested_consensus`, after the plain consensus finds no answer): an
undecided fold is compatible with both readings, so one of the two is named when it wins at
least :func:`decided_needed` folds outright (2 of 5, whatever the agreement asked), the other
none, and it or undecided fills ``need`` folds; the absorption only when leakage does not leave
at most what it leaves held out on any undecided fold (:func:`leakage_no_worse`: with its time
constant fitted between half a record and ten, leakage cannot win a fold outright). The stage's
``resolved`` note, the ``reason`` and ``agreement_compatible`` say how many folds decided it.

Not separable, left ``inconclusive``: folds all undecided (at 100 kHz, 0.4 s, a leakage, an
absorption slower than the record and a pair of the two explain the charge alike, E/a ~ 4-7).
Naming the reading the folds' median prefers there (leakage, one parameter fewer) would name
slow absorptions leakage, and carrying the absorption (it contains leakage's limit) would name
undecided leakages absorption: on the confusion benchmark's seeds 26-28 (the leakage,
absorption and pair records, 81) the latter named 6 leakages absorption.

**Both** (:func:`leakage_beside_absorption`, session 13): a record with a leak *and* an
absorption. The absorption fitted alone takes a compromise time constant, longer than its own, its
``k / tau`` slope standing in for leakage's line, and leakage's column taken orthogonal to it then
found nothing left (the pair was answered with the absorption alone: 1 of 17 on seeds 33-38). Once
the absorption is found, the later stage's leakage candidate is the joint model: leakage's line
(``g >= 0``) with the absorption's time constant searched again beside it, in the found
absorption's place, scored against the absorption alone (its time constant free) on every fold by
the stage's bars and against a second absorption (the stage's rival). It is offered only when the
refitted absorption settles within the record's length (``SETTLED_TEST_RECORDS``): slower, the
absorption alone matches a pair's ``int V`` and ``int int V`` terms (``k' / tau' = k / tau + g``,
``k' / tau'^2 = k / tau^2``) and the two are one reading over the record; between half a record and
one the folds decide.

``tau_bound``: an absorption of time constant ``tau`` explaining ``E`` (what leakage explains)
leaves a bend of ``sqrt(3/5) / 12 x T / tau x E``; it hides in what leakage leaves, ``a``, when
that is below ``a``: ``tau >= tau_bound = sqrt(3/5) / 12 x T x E / a``.

Step 3 asked ``tau_bound >= T`` before (an absorption settling within the whole record ruled
out), stricter than step 1's own line: an absorption with ``T / 2 <= tau < T`` was never taken
as settled, yet had to be excluded. On the confusion benchmark it named one more leakage >= 3x on
seed 17's slice (1 of 3; chosen there) and on the held-out seed 21 (3 of 3), and no absorption
leakage; a leakage explaining only 3-8x what it leaves stays undecided (README, *Calibration*).
"""

import copy

import numpy as np

from .stacking import column_stack

__all__ = ["absorption_or_leakage", "bend_on_every_fold", "leakage_beside_absorption", "refitted_absorption_stage",
           "LEAKAGE", "ABSORPTION", "decided_needed", "leakage_no_worse", "leakage_note",
           "nested_consensus", "nested_note", "DEFAULT_AGREE",
           "settled_absorption_rms", "settled_ruled_out", "tau_bound_s", "SETTLED_TEST_RECORDS",
           "LEAKAGE_TAU_RECORDS", "SETTLED_RECORDS", "BEND_PER_RECORD", "UNDECIDED", "at_ceiling", "too_short_note",
           "CEILING_SHARE"]

#: An absorption fitted slower than this many record lengths is leakage's term within the record
#: (once leakage's line is taken it bends by under 1 % of itself over the record).
LEAKAGE_TAU_RECORDS = 10.0
#: An absorption faster than this share of the record has settled within it (its own shape).
SETTLED_RECORDS = 0.5
#: The absorption the record must rule out before leakage is named: time constant the record's length
#: (63 % settled at its end; any faster one bends more, see :func:`settled_ruled_out`).
SETTLED_TEST_RECORDS = 1.0
#: A fitted time constant at this share of the search's ceiling or above ran to it (:func:`at_ceiling`).
CEILING_SHARE = 0.99
#: The two candidates' tags, ``(name, channel)``.
LEAKAGE, ABSORPTION = ("leakage", "charge"), ("dielectric_absorption", "charge")
#: The fold label of a fold the two readings explain alike (:func:`absorption_or_leakage` returned ``None``).
UNDECIDED = ("undecided", "dielectric_absorption or leakage")
#: The default agreement's share of the folds (``ceil(0.8 n_folds)``, tracing's default ``agree``).
DEFAULT_AGREE = 0.8
#: The bend's RMS over a record ``T`` per unit ``T / tau``, relative to the term's line (small ``T / tau``).
BEND_PER_RECORD = np.sqrt(3.0 / 5.0) / 12.0


def raw_rms(row, f, befores, penalty):
    """A candidate's unpenalized validation RMS on fold ``f`` (channel units)."""
    return befores[row["key"]][f] * row["ratios"][f] / (1 + penalty * row["n_params"])


def explained(row, f, befores, penalty):
    """What a candidate explains on fold ``f``: ``sqrt(before^2 - after^2)``, channel units."""
    b = befores[row["key"]][f]
    a = raw_rms(row, f, befores, penalty)
    return float(np.sqrt(max(b * b - a * a, 0.0)))


def tau_bound_s(lk, f, befores, penalty, duration_s):
    """The fastest absorption whose bend could hide in what leakage leaves on fold ``f`` (s).

    ``sqrt(3/5) / 12 x T x E / a``: ``E`` what leakage explains, ``a`` what it leaves, ``T`` the
    record's duration (s).
    """
    a_lk = raw_rms(lk, f, befores, penalty)
    return float(duration_s * BEND_PER_RECORD * explained(lk, f, befores, penalty) / max(a_lk, 1e-300))


def absorption_or_leakage(best, tags, f, befores, infos, penalty, noise_factor, min_share):
    """Dielectric absorption, leakage or undecided on fold ``f`` (see the module notes).

    Parameters
    ----------
    best : dict
        The fold's best passing candidate (the absorption or leakage on the charge).
    tags : dict
        The fold's passing candidates by ``(name, channel)``.
    f : int
        The fold.
    befores : dict
        The base's validation RMS per problem and fold (channel units).
    infos : dict
        ``duration_s`` (the record's, s) and ``charge["noise_floor"]`` (C).
    penalty, noise_factor, min_share : float
        As in :func:`~workbench.calibrate.tracing.trace_effect`.

    Returns
    -------
    dict or None
        The candidate row named on the fold, or ``None`` when the record cannot tell them apart.
    """
    da = tags.get(("dielectric_absorption", "charge"))
    lk = tags.get(("leakage", "charge"))
    if da is None or lk is None:
        return best
    T = infos["duration_s"]
    tau = da["params"].get("tau_s", 0.0)
    if tau < SETTLED_RECORDS * T:
        return best
    a_lk, a_da = raw_rms(lk, f, befores, penalty), raw_rms(da, f, befores, penalty)
    beyond = a_lk * a_lk - a_da * a_da
    if beyond > (noise_factor * infos["charge"]["noise_floor"]) ** 2 and beyond > min_share * a_lk * a_lk:
        return da
    if bend_on_every_fold(da, lk, befores, infos, penalty, noise_factor):
        return da
    if tau >= LEAKAGE_TAU_RECORDS * T and at_ceiling(da, T):
        by_bound = tau_bound_s(lk, f, befores, penalty, T) >= SETTLED_RECORDS * T
        by_test = settled_ruled_out(da, lk, f, befores, infos, penalty, noise_factor, min_share)
        if by_bound or by_test:
            # which line ruled the settled absorption out on this fold (:func:`leakage_note` says it)
            lk.setdefault("leakage_folds", {})[f] = "measured" if by_test else "bound"
            return lk
    return None


def at_ceiling(da, duration_s):
    """Did the absorption's time-constant search run to its ceiling (leakage's limit)? (bool)

    The search is bounded at ``tau_max_fraction`` record lengths (:class:`~.effects.DielectricAbsorption`);
    a fit stopped there wanted a slower relaxation still: over the record no finite time constant
    explains the charge better than leakage's line (``tau -> inf``), the reading the record itself
    prefers. A fit *inside* the range found a finite time constant beyond the record that its folds
    cannot confirm (its bend under the noise floor) nor rule out: the record cannot tell the two
    apart (:func:`too_short_note`). A row without its effect (constructed scores) has no ceiling.
    """
    ceiling = getattr(da.get("eff"), "tau_max_fraction", None)
    return ceiling is not None and da["params"].get("tau_s", 0.0) >= CEILING_SHARE * ceiling * duration_s


def too_short_note(by, winners, duration_s):
    """An ``inconclusive`` answer's note when the record is too short to tell absorption from leakage (str or None).

    Said when some first-stage fold was undecided between the two (:data:`UNDECIDED`) and the
    absorption's fitted time constant ``tau`` lies beyond the record (``SETTLED_RECORDS`` of it or
    slower): over the record the absorption's charge is leakage's ramp, and its bend beyond that
    line stayed under the bar on the validation folds. The record that would show its shape is one
    it settles within (step 1's line, ``tau / SETTLED_RECORDS``), derived from the fitted ``tau``: a
    rough figure, said so in the note (a fit beyond the record is poorly determined: the review found
    a fitted 52 record lengths for a drawn 3.2, and a genuine leakage gets a finite one by noise);
    a fit at the search's ceiling (:func:`at_ceiling`) gives no length, and the note says so.
    """
    da, lk = by.get(ABSORPTION), by.get(LEAKAGE)
    if da is None or lk is None or UNDECIDED not in [w if isinstance(w, str) else tuple(w) for w in winners]:
        return None
    tau = float(da["params"].get("tau_s", 0.0))
    if tau < SETTLED_RECORDS * duration_s:
        return None
    if at_ceiling(da, duration_s):
        return (f"the record is too short to tell a dielectric absorption from leakage (both lead): the "
                f"absorption's time-constant search ran to its ceiling, {tau:.3g} s ({tau / duration_s:.3g} "
                f"lengths of this {duration_s:.3g} s record), leakage's limit, yet the folds do not rule out an "
                f"absorption settling within half the record; no length follows from a fit at the ceiling")
    return (f"the record is too short to tell a dielectric absorption from leakage (both lead): the "
            f"absorption's fitted time constant, {tau:.3g} s, is {tau / duration_s:.2g} lengths of this "
            f"{duration_s:.3g} s record, over which its charge is close to leakage's ramp, and its bend beyond "
            f"leakage's line stays under the noise floor on the validation folds; a record of about "
            f"{tau / SETTLED_RECORDS:.3g} s (the fitted absorption settled within half of it) would show its shape "
            f"if that time constant holds, but a fit beyond the record is poorly determined (its bend is under the "
            f"noise floor): the true one may be shorter or longer, or the charge may be leakage's")


def settled_ruled_out(da, lk, f, befores, infos, penalty, noise_factor, min_share):
    """Does fold ``f`` rule out an absorption settling within the record (then: leakage)?

    ``da["settled_rms"]`` (:func:`settled_absorption_rms`): the fold's held-out RMS with an
    absorption of time constant ``SETTLED_TEST_RECORDS`` record lengths in leakage's place,
    fitted on the fold's training rows like any candidate. It is ruled out when it leaves more
    than leakage by the bar every candidate must clear on a fold (the channel's noise floor
    times ``noise_factor``, squared, and ``min_share`` of what leakage leaves, in power): the
    mirror of step 2's "bend seen", measured rather than bounded. :func:`tau_bound_s` bounds
    the same thing by assuming a bend hides in *all* of what leakage leaves; where that is
    the base's own misfit, of another shape, the direct fit shows the bend would not hide (on
    1 kHz leakage records of 4-14x, ``tau_bound`` 0.4-1.2 record lengths, the record-length
    absorption left 1.3-3.8x leakage's power on two to four folds of five).

    Faster absorptions bend more over the record (:data:`BEND_PER_RECORD` x T / tau) and are
    ruled out a fortiori. :func:`absorption_or_leakage` asks it only when the fitted absorption
    came out ``LEAKAGE_TAU_RECORDS`` record lengths or slower (see the module notes).
    """
    a_set = da.get("settled_rms")
    if a_set is None:
        return False
    a_lk = raw_rms(lk, f, befores, penalty)
    loss = a_set[f] ** 2 - a_lk ** 2
    return bool(loss > (noise_factor * infos["charge"]["noise_floor"]) ** 2 and loss > min_share * a_lk * a_lk)


def settled_absorption_rms(by, probs, extra, split, infos):
    """Each fold's held-out RMS with the record-length absorption in leakage's place (C).

    Sets ``by[("dielectric_absorption", "charge")]["settled_rms"]`` when both the absorption and
    leakage are candidates: the absorption's column at ``tau = SETTLED_TEST_RECORDS x T`` (``T``
    the record's duration, s; gain >= 0), fitted jointly with the base and the found effects on
    each fold's training rows (:class:`~workbench.calibrate.tracing._Problem`). The column is
    computed once per trace (cached in ``infos``).
    """
    da, lk = by.get(("dielectric_absorption", "charge")), by.get(("leakage", "charge"))
    if da is None or lk is None:
        return
    col = infos.get("_settled_absorption_column")
    if col is None:
        C, lower = da["eff"].columns(infos["t"], da["u"],
                                     {"gain": 1.0, "tau_s": SETTLED_TEST_RECORDS * infos["duration_s"]})
        col = infos["_settled_absorption_column"] = (np.asarray(C, float), [float(x) for x in np.atleast_1d(lower)])
    key = da["key"]
    prob = probs[key]
    cols = [C for C, _ in extra[key]] + [col[0]]
    lows = [x for _, lo in extra[key] for x in lo] + col[1]
    g = prob.grams(column_stack(cols), lows)
    da["settled_rms"] = [float(prob.fold_rms(g, tr, va)) for tr, va in split.folds]


def bend_on_every_fold(da, lk, befores, infos, penalty, noise_factor):
    """The absorption's bend beyond leakage, seen on every validation fold alike.

    Where leakage leaves mostly the base model's own misfit (several times the noise floor), an
    absorption's bend is a small share of what is left, and ``min_share`` of it is out of reach
    though the bend is there. The bend is then taken as seen when, on *every* fold, the
    absorption leaves less than leakage by more than the channel's noise floor in quadrature
    (``a_lk^2 - a_da^2 > (noise_factor floor)^2``): an extra time constant fitting the base's
    misfit gains on some folds and loses on others (measured on leakage records of the
    confusion benchmark: differences of 0.1-0.5 % of either sign), a bend gains on all.
    """
    floor2 = (noise_factor * infos["charge"]["noise_floor"]) ** 2
    for f in range(len(da["ratios"])):
        a_lk, a_da = raw_rms(lk, f, befores, penalty), raw_rms(da, f, befores, penalty)
        if not a_lk * a_lk - a_da * a_da > floor2:
            return False
    return True


def leakage_note(by, befores, penalty, duration_s):
    """What a named leakage leaves open: a slower absorption would look the same (str or None).

    ``by``: the first stage's candidate rows by ``(name, channel)``. ``None`` when the absorption
    was not a candidate or came out settling within the record (``SETTLED_RECORDS``). The bound
    said is the folds' median :func:`tau_bound_s`, raised to the record length (the absorption
    :func:`settled_ruled_out` tests) only when that measured test held on a fold that decided
    leakage (``lk["leakage_folds"]``, set by :func:`absorption_or_leakage`); the absorption's
    time constant beyond it is the parameter the record cannot identify. A fitted time constant
    at the search's ceiling (the absorption's ``tau_max_fraction`` record lengths) is said to be
    the ceiling, not a fit.
    """
    da, lk = by.get(("dielectric_absorption", "charge")), by.get(("leakage", "charge"))
    if da is None or lk is None or da["params"].get("tau_s", 0.0) < SETTLED_RECORDS * duration_s:
        return None
    bound = float(np.median([tau_bound_s(lk, f, befores, penalty, duration_s) for f in range(len(lk["ratios"]))]))
    if "measured" in lk.get("leakage_folds", {}).values():
        bound = max(bound, SETTLED_TEST_RECORDS * duration_s)
    n_rec = f"{bound / duration_s:.2g}"
    tau = da["params"]["tau_s"]
    ceiling = getattr(da.get("eff"), "tau_max_fraction", None)
    if ceiling is not None and tau >= CEILING_SHARE * ceiling * duration_s:
        fitted = f"not a fit: the search ran to its ceiling, {tau:.3g} s = {ceiling:.3g} record lengths"
    else:
        fitted = f"fitted {tau:.3g} s"
    return (f"leakage is the simpler reading: a dielectric absorption slower than about {bound:.3g} s "
            f"({n_rec} record length{'' if n_rec == '1' else 's'}) would look the same over this "
            f"{duration_s:.3g} s record; its time constant is what the record cannot identify ({fitted})")


def leakage_no_worse(by, befores, penalty):
    """Per fold: does leakage leave at most what the absorption leaves on held-out rows? (list of bool)

    ``by``: the first stage's candidate rows by ``(name, channel)``; both must be candidates, else
    every entry is ``False``. Compared unpenalized (:func:`raw_rms`), which already favours the
    absorption's extra parameter, as does its time constant searched on all development rows
    (every fold's validation rows among them): a fold where the nested, simpler leakage still does
    at least as well held out gives the absorption's bend no support.
    """
    da, lk = by.get(("dielectric_absorption", "charge")), by.get(("leakage", "charge"))
    if da is None or lk is None:
        return [False] * len(next(iter(by.values()))["ratios"]) if by else []
    return [bool(raw_rms(lk, f, befores, penalty) <= raw_rms(da, f, befores, penalty))
            for f in range(len(lk["ratios"]))]


def decided_needed(n_folds):
    """The fewest decided folds :func:`nested_consensus` names from (int, >= 2).

    More than the dissent the default agreement (``ceil(0.8 n_folds)``, :data:`DEFAULT_AGREE`)
    tolerates, and never one fold: ``max(2, n_folds - ceil(0.8 n_folds) + 1)`` (2 of 3-5 folds,
    3 of 10). It does not depend on the agreement a user asks for: a stricter bar must not let
    fewer folds decide (review of s11_calleak, finding 2: ``n - need + 1`` named leakage from one
    decided fold at 5 of 5).
    """
    return max(2, n_folds - int(np.ceil(DEFAULT_AGREE * n_folds)) + 1)


def nested_consensus(winners, need, lk_no_worse):
    """One of the nested pair named from decided folds, the other folds undecided between the two.

    An undecided fold (``UNDECIDED``) is one the absorption and leakage explain alike: it votes
    for neither, and it is *compatible* with both (each of the two readings explains the fold as
    well as the other). The plain consensus (``need`` folds won outright) counts such a fold
    against either answer, so a record whose decided folds all name leakage (or all name the
    absorption) and whose other folds cannot tell the two apart was answered ``inconclusive``.

    Here ``X`` (leakage or the absorption, on the charge) is named when

    * ``X`` or undecided-between-the-two on at least ``need`` folds (a name's usual agreement);
    * the other reading wins no fold outright (the decided folds are unanimous), and, for the
      absorption, leakage leaves no more than the absorption held out on no undecided fold
      (``lk_no_worse``). Where the absorption's fitted time constant lies between
      ``SETTLED_RECORDS`` and ``LEAKAGE_TAU_RECORDS`` record lengths :func:`absorption_or_leakage`
      can return only the absorption or undecided, so "leakage wins no fold" would hold by
      construction; a fold where the simpler reading does at least as well is its dissent;
    * ``X`` wins at least :func:`decided_needed` folds outright (2 of 5), so one fold decided by
      chance (the base's misfit on that fold) does not name it.

    Parameters
    ----------
    winners : list
        The first stage's fold winners (``"none"`` or ``(name, channel)``, ``UNDECIDED``).
    need : int
        Folds a name must win (``ceil(0.8 n_folds)`` by default).
    lk_no_worse : sequence of bool
        Per fold, leakage's held-out RMS at most the absorption's (:func:`leakage_no_worse`).

    Returns
    -------
    tuple
        ``((name, "charge"), decided, undecided)`` or ``(None, 0, 0)`` when the rule does not apply;
        ``decided + undecided`` folds are compatible with the name.
    """
    n = len(winners)
    tags = [w if isinstance(w, str) else tuple(w) for w in winners]
    und = sum(1 for w in tags if w == UNDECIDED)
    if not und:
        return None, 0, 0
    lean_lk = sum(1 for w, no_worse in zip(tags, lk_no_worse) if w == UNDECIDED and no_worse)
    for x, other in (("leakage", "dielectric_absorption"), ("dielectric_absorption", "leakage")):
        won = sum(1 for w in tags if w == (x, "charge"))
        rival = sum(1 for w in tags if w == (other, "charge")) + (lean_lk if x == "dielectric_absorption" else 0)
        if rival == 0 and won + und >= need and won >= decided_needed(n):
            return (x, "charge"), won, und
    return None, 0, 0


def nested_note(answer, decided, undecided, n_folds):
    """What a name from :func:`nested_consensus` leaves open (str).

    Follows the stage's "wins k of n validation folds" (the decided folds): says how the other
    folds split, undecided between the two or naming neither.
    """
    other = "leakage" if answer[0] == "dielectric_absorption" else "a dielectric absorption"
    neither = n_folds - decided - undecided
    lean = ", nor leaves leakage at least as good held out" if answer[0] == "dielectric_absorption" else ""
    return (f"the {decided} folds it wins are the decided ones; no fold names {other}{lean}; "
            f"{undecided} fold{'' if undecided == 1 else 's'} cannot tell the two apart (nested: leakage is the "
            f"absorption with tau -> inf at fixed gain / tau)"
            + (f", {neither} name{'s' if neither == 1 else ''} neither" if neither else "")
            + f": {decided + undecided} of {n_folds} folds compatible with {answer[0]}, {decided} decided")


def leakage_beside_absorption(c, cands, probs, extra, t, base, research):
    """The later stage's leakage candidate once an absorption is found: the two fitted jointly.

    An absorption fitted alone to a record with both effects takes a compromise time constant
    (longer than its own: its ``k / tau`` slope stands in for leakage's line), and leakage's
    column, taken orthogonal to that absorption, then finds nothing left ("the absorption takes
    the leak"). Here the candidate is the **joint** model, leakage's column (``g >= 0``) with
    the absorption's time constant searched again beside it (:func:`~.stages._research`, the
    absorption's own search: against the base and the other found effects, over its whole range),
    which *replaces* the found absorption's columns (``replaces``; gains ``>= 0``). The stage's
    fold test then compares it with the found absorption alone (its time constant free, fitted
    on the development rows) by the bars every candidate clears (noise floor, null reference,
    ``min_share``, its agreement) and the stage's rival (a second absorption on what the first
    leaves): leakage is named where the joint model explains what the absorption alone cannot.

    Only an absorption that **settles within the record** shows a shape a line cannot give: when
    the refitted time constant comes out ``SETTLED_RECORDS`` of the record or slower, a slow
    absorption and a leak are one reading over the record (the module notes: the absorption's
    ``k / tau`` and ``k / tau^2`` terms absorb leakage's line), and ``None`` is returned (the
    caller searches leakage as any later candidate, orthogonal to the found absorption).

    Parameters
    ----------
    c : dict
        The first stage's leakage candidate (charge channel).
    cands : list of dict
        The first stage's candidates (the absorption's among them: its effect, driver and range).
    probs, extra : dict
        The linear problems and the found effects' columns per problem (:func:`~.tracing._absorb`).
    t : ndarray of float
        Sample times, s.
    base : BaseFit
        The base fit.
    research : callable
        :func:`~workbench.calibrate.stages._research` (the joint re-search).

    Returns
    -------
    dict or None
        The candidate row (``g``: leakage's and the refitted absorption's columns; ``n_params``
        2, leakage's gain and the moved time constant; ``refit``: the absorption's ``tau_s``),
        or ``None`` when no absorption was found on the charge or the refit does not settle.
    """
    key = c["key"]
    mine = [x for x in extra.get(key, ()) if getattr(x, "tag", None) == ABSORPTION]
    da = next((d for d in cands if (d["name"], d["channel"]) == ABSORPTION and d["key"] == key), None)
    if not mine or da is None:
        return None
    C_lk, lo_lk = c["eff"].columns(t, c["u"], c["params"])
    C_lk = np.asarray(C_lk, float).reshape(t.size, -1)
    rest = [x for x in extra[key] if getattr(x, "tag", None) != ABSORPTION]
    ex = {**extra, key: rest + [(C_lk, [float(x) for x in np.atleast_1d(lo_lk)])]}
    r = research(da, probs, ex, t, base)
    if r is None:
        return None
    tau = float(r["params"]["tau_s"])
    if not tau < SETTLED_TEST_RECORDS * float(t[-1] - t[0]):
        return None
    C_da, lo_da = r["eff"].columns(t, r["u"], r["params"])
    C = column_stack([C_lk, np.asarray(C_da, float).reshape(t.size, -1)])
    lower = [float(x) for x in np.atleast_1d(lo_lk)] + [float(x) for x in np.atleast_1d(lo_da)]
    g = probs[key].grams(C, lower)
    if g["C"].shape[1] != C.shape[1]:
        return None
    return {**c, "eff": copy.deepcopy(c["eff"]), "g": g, "n_params": 2, "researched": True, "fold_g": None,
            "replaces": ABSORPTION, "refit": {"tau_s": tau}}


def refitted_absorption_stage(stages):
    """The found absorption's stage after a leakage named beside it (:func:`leakage_beside_absorption`).

    The last stage is the leakage; its candidate's columns are leakage's and the absorption's at
    the refitted time constant, its gains (``_gains``) in that order. The absorption's stage then
    carries the refitted ``gain`` (F) and ``tau_s`` (s), what the calibrated model holds, and
    says so in ``refitted`` (the time constant it was named with alone).
    """
    lk = stages[-1]
    refit, gains = lk["_cand"].get("refit"), lk.get("_gains")
    if refit is None or gains is None or len(gains) < 2:
        return
    for st in stages[:-1]:
        if (st["effect"], st["channel"]) == ABSORPTION:
            alone = st["parameters"].get("tau_s")
            st["parameters"] = {**st["parameters"], "gain": float(gains[1]), "tau_s": refit["tau_s"]}
            st["refitted"] = (f"refitted beside the leakage: tau {refit['tau_s']:.3g} s "
                              f"(alone {alone:.3g} s, its k / tau standing in for leakage's line)")
