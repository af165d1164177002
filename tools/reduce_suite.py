"""Choose the test ids ``make test`` leaves to the full form (``tests/full_only.txt``), keeping coverage whole.

The reduced form must run every line and every branch arc of ``workbench/`` that the reduced form before it
ran. The inputs are two measurements of ``make test`` (the reduced form, before the list):

- a coverage data file with per-test contexts::

      python -m pytest -n 2 --dist loadfile --cov=workbench --cov-branch \\
          --cov-context=test --cov-report= -p no:cacheprovider      # writes .coverage (~1 h on 2 cores)

  (``pip install pytest-cov``; the tool reads coverage 7's SQLite schema: tables ``context``, ``line_bits``,
  ``arc``). Coverage does not see numba-compiled bodies nor code run in child processes: tests of those are
  kept by pattern (``KEEP``), not by coverage;
- a junit XML of a quiet run (``--junitxml=junit.xml``): each id's time (setup included: a module fixture's
  cost is booked on its first user).

The choice is greedy: ids in decreasing junit time leave while every line and arc they run is still run by
another kept context (or at import), never an id matching a ``--keep`` pattern, until the kept ids sum to at
most ``--budget-s`` or the next id costs less than ``--min-s``. Ids skipped already (``WORKBENCH_FULL`` draws) are given by a skip map: ``nodeid<TAB>kept|
skipped`` per line, from a ``--collect-only`` run of the reduced form of the same tree as the coverage.

Session 32's list came from the coverage of main dbd743c's make test (/work/notes/s31/suite/cov.data in the
team's notes) and session 31's quiet fresh-clone junit; the one workbench/ change between dbd743c and the list's
base (s31_lagbar: a one-line bar in ``tracing._other_sensor_lags_alike``) was not re-measured.

usage: python tools/reduce_suite.py COVERAGE_DATA JUNIT_XML SKIPMAP --budget-s 820 [--keep REGEX ...] > list
"""
import argparse
import collections
import re
import sqlite3
import sys
import xml.etree.ElementTree as ET

#: never moved, as regular expressions: the acceptance tests the issues name (kept in make test whatever they
#: cost), the tests of compiled code (numba bodies are invisible to coverage, so coverage cannot show another test
#: runs them), and tests whose junit time is a module fixture's that a kept test shares (moving them saves nothing)
KEEP = [
    # issue 13's named tests: the fast confusion slice, rig records, the real record, the drift/creep cycle, the CLI
    r"tests/calibrate/test_rigs\.py::", r"tests/calibrate/test_confusion\.py::test_fast_slice",
    r"test_calibrate\.py::test_real_record", r"test_calibrate\.py::test_temperature_cycle",
    r"test_calibrate\.py::test_calibrate_command_writes", r"test_other_sensor_lag\.py::test_fresh_112",
    # issue 13 item 6: a negative delay carried by the written plant; a drawn mode written as the plant's mode;
    # a drift round trip through the written plant
    r"test_calibrate\.py::test_sensor_lead_is_found_signed_and_carried",
    r"test_round_trip\.py::test_the_written_mode_is_the_plants_mode\[effect3",
    r"test_round_trip\.py::test_two_effect_round_trip_reproduces_error_after\[effect0",
    # issue 16's fused-loop floors; every bit-for-bit firmware test; issue 17's fuzz suite, CLI and API
    r"meets_issue", r"bit_for_bit", r"tests/test_bad_input\.py::", r"tests/test_fuzz3_validators\.py::",
    r"tests/test_api\.py::", r"tests/test_cli\.py::",
    # compiled code: issue 17 item 5's reference-count checks, the compiled bounded solver against scipy's
    r"reference_count", r"a_plain_view_in_pzt_run", r"test_compiled_bvls_equals_scipys",
    # module fixtures shared with a kept test (session 32's review: their junit time is the fixture's)
    r"test_drawn_pairs_name_nothing_the_record_lacks", r"test_slow_absorptions_name_nothing_else",
    r"test_creep_at_1khz_is_named_over_the_size_range", r"test_drawn_creep_and_delay_records_name_nothing_else",
    r"test_stages\.py::test_two_effect_records_name_no_wrong_effect",
]


def _test_of(context):
    return context.rsplit("|", 1)[0] if "|" in context else context        # "id|run" / "id|setup" -> id


def covered_by(db):
    """``{(file_id, line) or (file_id, from, to): set of test ids}``; ``""`` marks import-time coverage."""
    from coverage.numbits import numbits_to_nums
    con = sqlite3.connect(db)
    ctx = dict(con.execute("select id, context from context"))
    out = collections.defaultdict(set)
    for fid, cid, bits in con.execute("select file_id, context_id, numbits from line_bits"):
        for n in numbits_to_nums(bits):
            out[(fid, n)].add(_test_of(ctx[cid]))
    for fid, cid, a, b in con.execute("select file_id, context_id, fromno, tono from arc"):
        t = _test_of(ctx[cid])
        out[(fid, a, b)].add(t)
        for n in (a, b):                 # branch data stores arcs only: a line is run where an arc starts or ends
            if n > 0:
                out[(fid, n)].add(t)
    return out


def junit_times(path):
    times = collections.Counter()
    for tc in ET.parse(path).getroot().iter("testcase"):
        times["/".join(tc.get("classname").split(".")) + ".py::" + tc.get("name")] += float(tc.get("time", 0))
    return times


def choose(cover, times, state, budget_s, keep, min_s=2.0):
    """The ids to leave, greedy by cost; ``state``: ``{nodeid: "kept" | "skipped"}`` of the reduced form."""
    unknown = sorted({t for tests in cover.values() for t in tests if t and t not in state})
    if unknown:                     # a context the skip map does not know cannot be counted on to run
        raise SystemExit(f"{len(unknown)} coverage contexts are not in the skip map, e.g. {unknown[0]}: "
                         "make both from the same tree")

    def running(t):
        return t == "" or state[t] == "kept"
    count, owned = collections.Counter(), collections.defaultdict(list)
    for key, tests in cover.items():
        runs = [t for t in tests if running(t)]
        count[key] = len(runs) + (10 ** 6 if "" in tests else 0)
        for t in runs:
            if t:
                owned[t].append(key)
    kept_s = sum(times.get(t, 0.0) for t, s in state.items() if s == "kept")
    out = []
    for t in sorted((t for t, s in state.items() if s == "kept"), key=lambda t: -times.get(t, 0.0)):
        if kept_s <= budget_s or times.get(t, 0.0) < min_s:
            break
        if any(re.search(p, t) for p in keep) or not all(count[k] >= 2 for k in owned.get(t, ())):
            continue
        for k in owned.get(t, ()):
            count[k] -= 1
        out.append(t)
        kept_s -= times.get(t, 0.0)
    return out, kept_s


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("coverage_data")
    ap.add_argument("junit_xml")
    ap.add_argument("skipmap")
    ap.add_argument("--budget-s", type=float, required=True, help="single-core seconds the kept ids may sum to")
    ap.add_argument("--keep", nargs="*", default=KEEP, help="regular expressions of ids never to leave")
    ap.add_argument("--min-s", type=float, default=2.0,
                    help="ids cheaper than this stay (they are not what makes the suite slow)")
    a = ap.parse_args(argv)
    state = dict(line.rstrip("\n").split("\t")[:2] for line in open(a.skipmap, encoding="utf-8"))
    times = junit_times(a.junit_xml)
    out, kept_s = choose(covered_by(a.coverage_data), times, state, a.budget_s, a.keep, a.min_s)
    print(f"# {len(out)} ids leave make test ({sum(times[t] for t in out):.1f} s); kept {kept_s:.1f} s",
          file=sys.stderr)
    for t in sorted(out):
        print(f"{t}  # {times[t]:.1f} s")


if __name__ == "__main__":
    main()
