"""Shared fixtures: the plant files and loaded plants; the hypothesis profiles.

Hypothesis runs derandomized by default (profile "ci": the examples follow from each
test's source, no example database, no deadline), so `make test` draws the same
examples on every run and machine. ``HYPOTHESIS_PROFILE=explore`` draws fresh random
examples (and keeps a local database) to hunt for new failures; a failure found that
way should become an ``@example`` on the test.
"""

import os
import re

# One BLAS thread per test process: `make test` runs one pytest-xdist worker per core, and
# OpenBLAS's own threads on top of those oversubscribe the cores (the calibration tests' Gram
# solves slowed several-fold). Set before numpy loads OpenBLAS, so child processes (CLI runs,
# dask workers) inherit it; threadpoolctl covers a numpy already loaded by a plugin.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

threadpool_limits(1)
import pytest
from hypothesis import settings

settings.register_profile("ci", derandomize=True, database=None, deadline=None, print_blob=True)
settings.register_profile("explore", derandomize=False, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

from workbench.plant import load_plant

ROOT = Path(__file__).resolve().parents[1]
PLANTS = ROOT / "plants"
SERIALS = ("sn637", "sn629", "sn618")
FULL = os.environ.get("WORKBENCH_FULL") == "1"
#: the mark of a draw or record that only the full form runs: ``make test`` skips it, ``WORKBENCH_FULL=1``
#: (``make test-full``) runs it; every id stays collected
FULL_ONLY = pytest.mark.skipif(not FULL, reason="reduced form: WORKBENCH_FULL=1 (make test-full) runs this draw")


def load_benchmark(name):
    """A script of ``benchmarks/`` loaded as a module (its functions, not its ``main``)."""
    import importlib.util
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def reduced_draws(draws, keep):
    """Parametrize ``draws`` (tuples or ``pytest.param``) so that ``make test`` runs those whose index is
    in ``keep`` and skips the rest, which ``WORKBENCH_FULL=1`` runs: every id stays collected (the skip
    says what the full form adds), and a draw's own marks (a strict xfail) are kept."""
    skip = FULL_ONLY
    out = []
    for k, d in enumerate(draws):
        param = hasattr(d, "values") and hasattr(d, "marks")
        values, marks, id_ = (tuple(d.values), list(d.marks), d.id) if param else (d, [], None)
        out.append(pytest.param(*values, marks=marks if k in keep else marks + [skip], id=id_))
    return out


def stratified_draws(rng_seed, n):
    """``n`` benchmark draws ``(protocol, size, seed)``, one size per log-band of the confusion benchmark's
    full range (``SIZE_RANGE`` cut in ``n`` equal log-bands), the protocol drawn among the three, from
    ``default_rng(rng_seed)``: what the drawn 1 kHz pair and creep tests share."""
    cc = load_benchmark("calibrate_confusion")
    rng = np.random.default_rng(rng_seed)
    edges = np.linspace(np.log(cc.SIZE_RANGE[0]), np.log(cc.SIZE_RANGE[1]), n + 1)
    return [(str(rng.choice(("calibration", "sine", "steps"))), float(np.exp(rng.uniform(lo, hi))),
             int(rng.integers(1 << 30))) for lo, hi in zip(edges[:-1], edges[1:])]


def leak_and_absorption_fits(sn637, tau_s, rate_hz=1e3, n_rows=10_000):
    """A steps record (10 s at 1 kHz) with a 20 Mohm leak and a 1.2 uF absorption of ``tau_s`` (s) and its
    effect-free twin (same noise), base-fitted as the confusion benchmark does: ``(base, base0, split)``."""
    import dataclasses

    from workbench.calibrate.base_fit import fit_base
    from workbench.calibrate.splits import make_split
    from workbench.calibrate.synthetic import benchmark_protocol, plant_with_effect, simulate_record
    cc = load_benchmark("calibrate_confusion")
    clean, _ = plant_with_effect(sn637, "none", 0)
    plant = dataclasses.replace(clean, additions=dataclasses.replace(
        clean.additions, leakage_resistance_ohm=2e7, absorption_gain_f=1.2e-6, absorption_time_constant_s=tau_s))
    t, v = benchmark_protocol("steps", rate_hz, n_rows)
    r = simulate_record(plant, t, v, seed=5)
    r0 = simulate_record(clean, t, v, seed=5)
    sp = make_split(t, r["voltage_v"], "blocks")
    kw = dict(train=sp.train, test=sp.test, pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
    R = sn637.pzt.series_resistance_ohm
    base = fit_base(cc._record(r, 1.0 / rate_hz), R, **kw)
    base0 = fit_base(cc._record(r0, 1.0 / rate_hz), R, **kw)
    return base, base0, sp


@pytest.fixture(scope="session")
def root():
    return ROOT


@pytest.fixture(scope="session")
def sn637():
    return load_plant(PLANTS / "p888_51_sn637.toml")


@pytest.fixture(scope="session")
def sn637_creep():
    return load_plant(PLANTS / "p888_51_sn637_creep.toml")


@pytest.fixture(scope="session", params=SERIALS)
def any_serial(request):
    return load_plant(PLANTS / f"p888_51_{request.param}.toml")


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)


@pytest.fixture
def stable_rss():
    """``stable_rss(seed, states, outputs, inputs, margin, **kw)``: a seeded, stable ``control.rss``.

    python-control 0.10's ``rss`` draws from numpy's global random state, so an unseeded test
    draws a new system on every run. This seeds the global state for the draw (redrawing until
    every pole's real part is below ``-margin``) and restores it afterwards.
    """
    import control

    def draw(seed, states, outputs, inputs, margin, **kw):
        saved = np.random.get_state()
        np.random.seed(seed)
        try:
            sys_ = control.rss(states, outputs, inputs, **kw)
            while np.any(sys_.poles().real > -margin):
                sys_ = control.rss(states, outputs, inputs, **kw)
        finally:
            np.random.set_state(saved)
        return sys_

    return draw


#: the ids ``make test`` leaves to the full form, and why (the file's header): coverage-checked, session 32
FULL_ONLY_LIST = Path(__file__).with_name("full_only.txt")
#: the listed ids no collection of their whole file found (a renamed test, a changed draw), per session
STALE_FULL_ONLY = pytest.StashKey[list]()
_FLOAT = re.compile(r"(?<![\w.])-?\d+\.\d+(?:e[+-]?\d+)?")


def stable_id(nodeid):
    """``nodeid`` with every decimal number in its parameters rounded to 6 significant digits.

    Drawn ids carry floats such as ``float(np.exp(u))``, whose last digit numpy's SIMD exp and libm's exp
    can disagree on from one CPU to another; the list must name the same test on every machine."""
    path, sep, rest = nodeid.partition("[")
    return path + sep + _FLOAT.sub(lambda m: f"{float(m.group()):.6g}", rest)


def read_full_only(path=FULL_ONLY_LIST):
    """The listed node ids of ``path`` (one a line, ``#`` comments), as a set of :func:`stable_id` keys."""
    ids = set()
    for line in path.read_text(encoding="utf-8").splitlines():
        nid = line.split("#", 1)[0].strip()
        if nid:
            ids.add(stable_id(nid))
    return ids


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Skip the ids of ``tests/full_only.txt`` unless ``WORKBENCH_FULL=1``; note a list gone stale.

    Runs before ``-k``/``-m`` deselect, so every id of a collected file is seen. A listed id whose file was
    collected whole (no ``file::name`` argument) but which no longer exists is kept in the config's stash:
    the run goes on (the test just runs: fail-safe), and ``tests/test_full_only_list.py`` fails on it."""
    listed = read_full_only()
    seen = {stable_id(item.nodeid) for item in items}
    files = {nid.split("::", 1)[0] for nid in seen}
    picked = any("::" in str(a) for a in config.args)
    stale = [] if picked else sorted(nid for nid in listed - seen if nid.split("::", 1)[0] in files)
    config.stash[STALE_FULL_ONLY] = stale
    if FULL:
        return
    mark = pytest.mark.skip(reason="full form: tests/full_only.txt (coverage-checked); WORKBENCH_FULL=1 "
                                   "(make test-full) runs it")
    for item in items:
        if stable_id(item.nodeid) in listed:
            item.add_marker(mark)
