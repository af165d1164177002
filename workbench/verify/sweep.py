"""Parallel verification sweeps: one function over a grid of cases, one table of metrics.

A sweep calls ``fn(case.payload)`` for every :class:`Case`; ``fn`` returns a flat dict of
metrics and the sweep returns one row per case (the case key, the metrics, ``ok`` and
``error``), in case order. Cases run in local processes (default), on a dask.distributed
cluster (``scheduler="tcp://host:port"``) or in this process (``scheduler="inline"``).
A case that raises becomes a row with ``ok=False`` and the reason; it never stops the sweep.
"""

import concurrent.futures
import importlib
import io
import itertools
import math
import multiprocessing
import os
import pickle
import re
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SweepError
from ..report.output import write_bytes, write_text

__all__ = ["Case", "SweepError", "TABLE_SUFFIXES", "check_table_path", "grid", "run_cases", "worst", "write_table"]

_RESERVED = ("ok", "error")
_ADDRESS = re.compile(r"tcp://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})")
#: The table's formats, by suffix (the one home: write_table and the CLI check read it).
TABLE_SUFFIXES = (".csv", ".parquet")
_TABLE_SUFFIXES = TABLE_SUFFIXES


def check_table_path(path, name="table"):
    """Refuse a table path whose suffix is not a format :func:`write_table` writes, before any case runs.

    Parameters
    ----------
    path : path-like
    name : str
        The argument's name in the message (the CLI passes ``--table``).

    Raises
    ------
    FileArgumentError
        Naming the argument, the path and the suffixes.
    """
    from ..paths import FileArgumentError
    path = Path(path)
    if path.suffix.lower() not in TABLE_SUFFIXES:
        raise FileArgumentError(f"{name} {path}: the suffix must be one of {', '.join(TABLE_SUFFIXES)} (the table's "
                                f"format); e.g. {path.with_suffix('.csv')}")


@dataclass(frozen=True)
class Case:
    """One point of a sweep.

    Parameters
    ----------
    key : dict of str to str, float or int
        The grid coordinates (``{"serial": "sn637", "amplitude_v": 20.0}``); they become the
        first columns of the case's row.
    payload : object
        Whatever ``fn`` needs for this case; must pickle unless the sweep runs inline.

    Raises
    ------
    TypeError
        If ``key`` is not a dict or a coordinate is not a str, int or float.
    ValueError
        If a coordinate name is not a string or is ``"ok"`` or ``"error"`` (the status columns).
    """

    key: dict
    payload: Any

    def __post_init__(self):
        if not isinstance(self.key, dict):
            raise TypeError(f"Case.key must be a dict of grid coordinates, got {type(self.key).__name__}")
        for name, value in self.key.items():
            if not isinstance(name, str) or name in _RESERVED:
                raise ValueError(f"Case.key names must be strings other than {_RESERVED}, got {name!r}")
            if not isinstance(value, (str, int, float)):
                raise TypeError(f"Case.key[{name!r}] must be a str, int or float, got {type(value).__name__}")


def grid(**axes):
    """Cartesian product of named axes, the first axis varying slowest.

    Parameters
    ----------
    **axes : sequence
        One non-empty sequence of values per axis name; numpy scalars become Python numbers.

    Returns
    -------
    list of dict
        One ``{axis: value}`` dict per grid point, in ``itertools.product`` order.

    Raises
    ------
    ValueError
        If no axis is given or an axis is empty.
    TypeError
        If an axis is a string or a scalar rather than a sequence of values.

    Examples
    --------
    >>> grid(serial=["sn637", "sn629"], amplitude_v=[1.0, 2.0])  # doctest: +NORMALIZE_WHITESPACE
    [{'serial': 'sn637', 'amplitude_v': 1.0}, {'serial': 'sn637', 'amplitude_v': 2.0},
     {'serial': 'sn629', 'amplitude_v': 1.0}, {'serial': 'sn629', 'amplitude_v': 2.0}]
    """
    if not axes:
        raise ValueError("grid needs at least one axis, e.g. grid(amplitude_v=[1.0, 10.0])")
    values = []
    for name, axis in axes.items():
        if isinstance(axis, (str, bytes)) or not hasattr(axis, "__iter__"):
            raise TypeError(f"grid axis {name!r} must be a sequence of values, got {axis!r}; wrap a single "
                            f"value in a list")
        # numpy scalars (np.linspace axes) would otherwise reach Case.key and the table as np.float64
        axis = [v.item() if isinstance(v, np.generic) else v for v in axis]
        if not axis:
            raise ValueError(f"grid axis {name!r} is empty, so the grid would have no points")
        values.append(axis)
    return [dict(zip(axes, point)) for point in itertools.product(*values)]


def run_cases(fn, cases, *, scheduler=None, workers=None, progress=None, timeout_s=None,
              connect_timeout_s=10.0):
    """Run ``fn(case.payload)`` for every case and return one row per case, in case order.

    Parameters
    ----------
    fn : callable
        ``fn(payload) -> dict`` of metrics (str to bool, int, float or str). Outside inline runs
        it is pickled by reference, so define it at module level in an importable module.
    cases : sequence of Case
    scheduler : str, optional
        None (default): local processes (``ProcessPoolExecutor``, "spawn" start method).
        ``"tcp://host:port"``: a running dask.distributed scheduler. ``"inline"``: this process,
        one case after another (for debugging: breakpoints and tracebacks work).
    workers : int, optional
        Local processes; default ``os.cpu_count()``, never more than the number of cases. Only
        for local runs: a cluster has its own workers.
    progress : callable, optional
        ``progress(done, total)``, called in this process after each row, in completion order.
    timeout_s : float, optional
        Wall-time limit of the whole sweep, s. Cases not finished by then get ``ok=False``;
        local processes still running are killed (a cluster keeps running its started tasks
        to their end, as dask cannot interrupt them; inline runs stop between cases).
    connect_timeout_s : float, optional
        How long to try to reach ``scheduler``, and then to wait for its first worker, s
        (default 10).

    Returns
    -------
    list of dict
        Per case: ``case.key``, the metrics, ``ok`` (bool) and ``error`` (str, ``""`` if ok;
        else the exception type, message and the line that raised).

    Raises
    ------
    ValueError
        If ``cases`` is empty, ``fn`` or ``progress`` is not callable, ``fn`` cannot be pickled
        (outside inline runs), ``scheduler`` is malformed, or ``workers`` or a time limit is not
        positive (or ``workers`` is given with a scheduler).
    TypeError
        If a case is not a :class:`Case`.
    SweepError
        If the scheduler cannot be reached within ``connect_timeout_s``, has no worker by then,
        or its workers cannot import this module.

    Notes
    -----
    ``fn`` and each payload are pickled here and unpickled inside the case, so a worker that
    cannot import ``fn``'s module (or a payload's classes) reports it in that case's row rather
    than killing the process pool or stalling a dask worker. A payload that cannot be pickled
    fails its own row. Local runs spawn fresh interpreters that import the calling script's
    ``__main__`` module: a script that calls this needs an ``if __name__ == "__main__":`` guard;
    dask workers cannot see a script's ``__main__`` at all.

    Examples
    --------
    >>> cases = [Case(key={"x": x}, payload=x) for x in (1, 0, 2)]
    >>> rows = run_cases(lambda x: {"inv": 1 / x}, cases, scheduler="inline")
    >>> [(row["x"], row["ok"], row.get("inv")) for row in rows]
    [(1, True, 1.0), (0, False, None), (2, True, 0.5)]
    >>> rows[1]["error"].split(" [")[0]
    'ZeroDivisionError: division by zero'
    """
    cases = list(cases)
    _check_run(fn, cases, scheduler, workers, progress, timeout_s, connect_timeout_s)
    payloads = [case.payload for case in cases]
    rows = [None] * len(cases)
    done = 0

    def record(index, outcome):
        nonlocal done
        rows[index] = _row(cases[index], *outcome)
        done += 1
        if progress is not None:
            progress(done, len(cases))

    if scheduler == "inline":
        _run_inline(fn, payloads, timeout_s, record)
    else:
        blobs = _pickle_cases(fn, payloads, record)
        if blobs and scheduler is None:
            _run_local(blobs, min(workers or os.cpu_count() or 1, len(blobs)), timeout_s, record)
        elif blobs:
            _run_dask(blobs, scheduler, timeout_s, connect_timeout_s, record)
    # only a timeout leaves cases without a row
    for index in [i for i, row in enumerate(rows) if row is None]:
        record(index, ({}, f"TimeoutError: not finished within timeout_s = {timeout_s:g} s"))
    return rows


def worst(rows, metric, larger_is_worse=True):
    """The ok row with the worst value of ``metric`` (infinities count; NaN and failed rows do not).

    Parameters
    ----------
    rows : list of dict
        Rows from :func:`run_cases`.
    metric : str
    larger_is_worse : bool, optional
        True (default) picks the largest value, False the smallest. Ties go to the earliest row.

    Returns
    -------
    dict
        The row itself.

    Raises
    ------
    ValueError
        If no ok row has a non-NaN value of ``metric``.

    Examples
    --------
    >>> rows = [{"a": 1.0, "ok": True}, {"a": float("nan"), "ok": True}, {"a": 9.0, "ok": False},
    ...         {"a": 3.0, "ok": True}]
    >>> worst(rows, "a"), worst(rows, "a", larger_is_worse=False)
    ({'a': 3.0, 'ok': True}, {'a': 1.0, 'ok': True})
    """
    candidates = [row for row in rows
                  if row.get("ok") and isinstance(row.get(metric), (int, float)) and not math.isnan(row[metric])]
    if not candidates:
        raise ValueError(f"no ok row has a numeric, non-NaN value of {metric!r} ({len(rows)} rows, "
                         f"{sum(bool(row.get('ok')) for row in rows)} ok); check the metric name and the "
                         f"rows' error column")
    sign = 1.0 if larger_is_worse else -1.0
    return max(candidates, key=lambda row: sign * row[metric])


def write_table(rows, path):
    """Write rows as a CSV or Parquet table (by the suffix of ``path``), whole or not at all.

    Parameters
    ----------
    rows : list of dict
        Columns are the keys in first-seen order; a row without a key leaves that cell empty.
    path : str or Path
        Ending in ``.csv`` or ``.parquet``.

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        If the suffix is neither ``.csv`` nor ``.parquet``, or ``rows`` is empty.
    """
    import pandas as pd     # slow to import, and only tables need it (not the worker processes)

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in _TABLE_SUFFIXES:
        raise ValueError(f"cannot write a table to {str(path)!r}: the suffix must be one of {_TABLE_SUFFIXES}, "
                         f"got {path.suffix!r}")
    if not rows:
        raise ValueError(f"no rows to write to {str(path)!r}")
    columns = list(dict.fromkeys(name for row in rows for name in row))
    frame = pd.DataFrame(rows, columns=columns)
    if suffix == ".csv":
        return write_text(path, frame.to_csv(index=False))
    buffer = io.BytesIO()
    frame.to_parquet(buffer, index=False)
    return write_bytes(path, buffer.getvalue())


def _check_run(fn, cases, scheduler, workers, progress, timeout_s, connect_timeout_s):
    if not callable(fn):
        raise ValueError(f"fn must be a function payload -> dict of metrics, got {type(fn).__name__}")
    if not cases:
        raise ValueError("the sweep has no cases; build them with grid(...), e.g. "
                         "[Case(key=k, payload=...) for k in grid(amplitude_v=[1.0, 10.0])]")
    bad = [type(case).__name__ for case in cases if not isinstance(case, Case)]
    if bad:
        raise TypeError(f"cases must be Case instances, got {bad[0]} ({len(bad)} of {len(cases)})")
    if progress is not None and not callable(progress):
        raise ValueError(f"progress must be callable as progress(done, total), got {type(progress).__name__}")
    address = _ADDRESS.fullmatch(str(scheduler))
    if scheduler not in (None, "inline") and not (address and 0 < int(address.group(2)) < 65536):
        raise ValueError(f"scheduler must be 'inline' or a dask scheduler address like 'tcp://127.0.0.1:8786', "
                         f"got {scheduler!r}; omit it to run in local processes")
    if workers is not None:
        if scheduler is not None:
            raise ValueError(f"workers={workers!r} applies to local processes only; with scheduler={scheduler!r} "
                             f"the cluster's own workers run the cases, so omit workers")
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ValueError(f"workers must be a positive integer, got {workers!r}")
    for name, value in (("timeout_s", timeout_s), ("connect_timeout_s", connect_timeout_s)):
        if value is not None and not value > 0:
            raise ValueError(f"{name} must be a positive number of seconds, got {value!r}")


def _pickle_cases(fn, payloads, record):
    """{index: pickled (fn, payload)} of the cases that pickle; record the others as failed."""
    try:
        pickle.dumps(fn)
    except Exception as err:
        raise ValueError(f"fn {fn!r} cannot be sent to worker processes ({err}); define it at module level in an "
                         f"importable module, or run with scheduler='inline'") from err
    blobs = {}
    for index, payload in enumerate(payloads):
        try:
            blobs[index] = pickle.dumps((fn, payload), protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as err:
            record(index, ({}, f"{_describe(err)}; the payload cannot be pickled for a worker"))
    return blobs


def _call_pickled(blob):
    """Run one pickled case in a worker; unpickling here turns a missing module into a row."""
    try:
        fn, payload = pickle.loads(blob)
    except Exception as err:
        return {}, (f"{type(err).__name__}: {err}; the worker cannot unpickle fn and payload: define fn at "
                    f"module level in a module (and payload classes) the workers can import")
    return _call(fn, payload)


def _call(fn, payload):
    """Run one case where it is scheduled; return (metrics, error) and never raise, so one case
    cannot stop the sweep and no exception object (maybe unpicklable) has to travel back."""
    try:
        metrics = fn(payload)
        if not isinstance(metrics, dict):
            raise TypeError(f"fn must return a dict of metrics, got {type(metrics).__name__}")
        # numpy scalars would pickle fine but make rows compare and serialize as np types
        metrics = {name: value.item() if isinstance(value, np.generic) else value
                   for name, value in metrics.items()}
        for name, value in metrics.items():
            if not isinstance(name, str) or not isinstance(value, (bool, int, float, str)):
                raise TypeError(f"metric {name!r} must be named by a str and be a bool, int, float or str "
                                f"(a flat table cell), got {type(value).__name__}")
    except Exception as err:
        return {}, _describe(err)
    return metrics, ""


def _describe(err):
    """'Type: message [file.py:line]': the line that raised, since a table has no traceback."""
    frames = traceback.extract_tb(err.__traceback__)
    where = f" [{Path(frames[-1].filename).name}:{frames[-1].lineno}]" if frames else ""
    return f"{type(err).__name__}: {err}{where}"


def _row(case, metrics, error):
    clash = sorted(set(metrics) & (set(case.key) | set(_RESERVED)))
    if clash:
        metrics, error = {}, (f"ValueError: fn returned metrics named {clash}, which are key or status "
                              f"columns; rename them")
    return {**case.key, **metrics, "ok": not error, "error": error}


def _run_inline(fn, payloads, timeout_s, record):
    deadline = math.inf if timeout_s is None else time.monotonic() + timeout_s
    for index, payload in enumerate(payloads):
        if time.monotonic() > deadline:
            return
        record(index, _call(fn, payload))


def _run_local(blobs, workers, timeout_s, record):
    # "spawn": the parent may hold threads (BLAS, numba, dask) that a forked child would inherit locked
    pool = concurrent.futures.ProcessPoolExecutor(max_workers=workers,
                                                  mp_context=multiprocessing.get_context("spawn"))
    pending = {pool.submit(_call_pickled, blob): index for index, blob in blobs.items()}
    try:
        for future in concurrent.futures.as_completed(list(pending), timeout=timeout_s):
            record(pending.pop(future), _outcome(future))
    except TimeoutError:
        pass
    finally:
        if pending:
            # Python 3.11 has no public way to stop a running task (3.14 adds terminate_workers)
            for process in list((pool._processes or {}).values()):
                process.kill()
        pool.shutdown(wait=True, cancel_futures=True)


def _run_dask(blobs, address, timeout_s, connect_timeout_s, record):
    from distributed import Client, as_completed

    try:
        # set_as_default=False: do not make this client the process-wide dask scheduler
        client = Client(address, timeout=connect_timeout_s, set_as_default=False)
    except OSError as err:     # refused, unresolvable, or timed out (TimeoutError)
        raise SweepError(f"cannot reach the dask scheduler at {address} within {connect_timeout_s:g} s ({err}); "
                         f"start one with `dask scheduler` (and workers with `dask worker {address}`), "
                         f"check the address, or omit --scheduler to run in local processes") from err
    with client:
        _check_workers(client, address, connect_timeout_s)
        futures = client.map(_call_pickled, list(blobs.values()), pure=False)
        pending = {future.key: index for future, index in zip(futures, blobs)}
        try:
            # loop= because this client is not the default one as_completed would look up
            for future in as_completed(futures, loop=client.loop, timeout=timeout_s):
                record(pending.pop(future.key), _outcome(future))
        except TimeoutError:
            client.cancel([future for future in futures if future.key in pending])


def _check_workers(client, address, timeout_s):
    """Fail fast where a sweep would otherwise wait forever: no worker, or one that cannot unpickle
    a task naming this module (dask leaves such a task pending rather than failing it)."""
    try:
        client.wait_for_workers(1, timeout=timeout_s)
    except TimeoutError as err:
        raise SweepError(f"the dask scheduler at {address} has no worker after {timeout_s:g} s; start some with "
                         f"`dask worker {address}`, or omit --scheduler to run in local processes") from err
    try:
        client.run(importlib.import_module, __name__)
    except ImportError as err:
        raise SweepError(f"a dask worker of {address} cannot import {__name__} ({err}); install the workbench "
                         f"in every worker's environment (pip install -e .), or omit --scheduler") from err


def _outcome(future):
    """(metrics, error) of a finished future; errors here are the runner's (pickling, a dead worker)."""
    err = future.exception()
    return ({}, _describe(err)) if err is not None else future.result()
