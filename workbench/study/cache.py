"""The plant family cached on disk: a study with new targets reuses the family it computed before.

The key is a SHA-256 over the plant files' bytes, the ``--set`` plant overrides, the
family grid (:class:`~workbench.linearize.uncertainty.FamilySpec`) and the source of the
modules that compute the family (so a code change never serves a stale family). The
default folder is ``$WORKBENCH_CACHE_DIR``, else ``$XDG_CACHE_HOME/workbench``, else
``~/.cache/workbench``; one pickle per key, written whole or not at all. The cache
holds only what this machine computed: a pickle is code, never load one from elsewhere.
"""

import hashlib
import os
import pickle
from pathlib import Path

__all__ = ["default_cache_dir", "family_key", "cached_family"]


def default_cache_dir():
    """The user cache folder (see the module docstring)."""
    env = os.environ.get("WORKBENCH_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "workbench"


def _code_digest():
    import workbench
    root = Path(workbench.__file__).parent
    h = hashlib.sha256()
    # the family is computed by linearize/ and plant/, through design/margins.py's responses
    files = [p for sub in ("linearize", "plant") for p in sorted((root / sub).glob("*.py"))]
    for p in files + [root / "design" / "margins.py"]:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    import control
    import numpy
    import scipy
    h.update(f"numpy {numpy.__version__} scipy {scipy.__version__} control {control.__version__}".encode())
    return h.hexdigest()


def family_key(plant_paths, plant_overrides, fspec, extra=()):
    """Hex SHA-256 that names a family: plant files' bytes, overrides, grid, code."""
    h = hashlib.sha256(b"workbench.family/1\n")
    for p in plant_paths:
        h.update(Path(p).read_bytes())
        h.update(b"\0")
    h.update(repr(sorted((k, repr(v)) for k, v in (plant_overrides or {}).items())).encode())
    h.update(repr(fspec).encode())
    h.update(repr(tuple(extra)).encode())
    h.update(_code_digest().encode())
    return h.hexdigest()


def cached_family(key, cache_dir, compute, prefix="family"):
    """``(family, path, hit)``: the cached family under ``key`` in ``cache_dir`` or ``compute()``, then stored.

    ``cache_dir`` None: no cache (computed every time; path None). An unreadable or
    corrupt entry is recomputed and overwritten. ``prefix`` names the kind of entry (the
    study also caches its sensor records, ``prefix="sensor"``).
    """
    if cache_dir is None:
        return compute(), None, False
    from ..report.output import write_bytes
    path = Path(cache_dir) / f"{prefix}-{key[:24]}.pkl"
    if path.is_file():
        try:
            with path.open("rb") as fh:
                return pickle.load(fh), path, True
        except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError):
            pass
    family = compute()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes(path, pickle.dumps(family, protocol=pickle.HIGHEST_PROTOCOL))
    except OSError as err:       # a cache that cannot be written costs the next run time, never this run's work
        import warnings
        warnings.warn(f"family cache {path} not written ({err.strerror or err}); the next study recomputes it",
                      RuntimeWarning, stacklevel=2)
        return family, None, False
    return family, path, False
