"""Where numba keeps the workbench's compiled kernels: a folder named by the source it compiled.

numba's ``cache=True`` checks only the decorated function's own file for changes. The workbench's
kernels inline jitted helpers from other files (``plant/kernels.py`` into ``plant/coupled.py``,
``verify/closed_loop.py``, ``verify/sensors.py``, ``verify/mirror.py``), so after an edit to a
helper numba would reload the caller's stale machine code and run the old physics. The cache
therefore lives in ``<cache>/numba/<digest>``, the digest taken over every source file of the
package: any change compiles afresh, in a folder of its own. ``<cache>`` is
``$WORKBENCH_CACHE_DIR`` or ``~/.cache/workbench`` (the family cache's folder), and a temporary
folder when that cannot be written. A ``NUMBA_CACHE_DIR`` set by the user is left alone.
"""

import hashlib
import os
import sys
import tempfile
from pathlib import Path

__all__ = ["source_digest", "configure"]

_PACKAGE = Path(__file__).resolve().parent


def source_digest(package=_PACKAGE):
    """SHA-256 (first 16 hex digits) over the relative paths and bytes of every ``.py`` file of ``package``."""
    h = hashlib.sha256()
    for path in sorted(Path(package).rglob("*.py")):
        h.update(path.relative_to(package).as_posix().encode())
        h.update(b"\0")
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()[:16]


def _writable(folder):
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
        return True
    except OSError:
        return False


def configure():
    """Point numba's cache at the folder of this source (call before any kernel module is imported).

    Returns
    -------
    Path or None
        The folder, or None when ``NUMBA_CACHE_DIR`` was set by the user.
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    base = Path(os.environ.get("WORKBENCH_CACHE_DIR") or Path.home() / ".cache" / "workbench")
    folder = base / "numba" / source_digest()
    if not _writable(folder):
        folder = Path(tempfile.gettempdir()) / f"workbench-numba-{source_digest()}"
        folder.mkdir(parents=True, exist_ok=True)
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    if "numba" in sys.modules:                  # numba read its config already: set it there too
        from numba.core import config
        config.CACHE_DIR = str(folder)
    return folder
