"""Write outputs whole or not at all: temp file in the target folder, then rename; never onto an input."""

import contextlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from ..errors import OutputOntoInputError

__all__ = ["write_json", "write_text", "write_bytes", "save_figure", "to_jsonable", "protect_inputs",
           "OutputOntoInputError"]

# input files of the running command (set by :func:`protect_inputs`): no writer may replace one
_PROTECTED = []


@contextlib.contextmanager
def protect_inputs(paths):
    """Within the block, every writer of this module refuses to replace one of ``paths``.

    Parameters
    ----------
    paths : iterable of (name, path-like)
        The run's input files with the argument that named them, e.g. ``("plant", "plants/a.toml")``.
    """
    added = [(name, Path(p)) for name, p in paths if p is not None]
    _PROTECTED.extend(added)
    try:
        yield
    finally:
        for item in added:
            _PROTECTED.remove(item)


def _refuse_inputs(path):
    from ..paths import same_path
    for name, src in _PROTECTED:
        if same_path(path, src):
            raise OutputOntoInputError(f"{path}: is the input {name} {src}; an output never overwrites an input: "
                                       f"give another output path")


def to_jsonable(obj):
    """Convert numpy scalars/arrays and tuples recursively into JSON-ready values."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def _atomic(path, write):
    path = Path(path)
    _refuse_inputs(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    except OSError as err:
        from ..paths import FileArgumentError
        raise FileArgumentError(f"{path}: cannot be written ({err.strerror or err}); give a path in a writable "
                                f"folder") from None
    os.close(fd)
    try:
        write(tmp)
        # mkstemp creates the file 0600; give it the mode a plain open() would have
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def write_json(path, data):
    """Write ``data`` as indented JSON to ``path`` atomically."""
    text = json.dumps(to_jsonable(data), indent=2, allow_nan=False)
    return _atomic(path, lambda tmp: Path(tmp).write_text(text + "\n", encoding="utf-8"))


def write_text(path, text):
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return _atomic(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


def write_bytes(path, data):
    """Write ``data`` to ``path`` atomically."""
    return _atomic(path, lambda tmp: Path(tmp).write_bytes(data))


def save_figure(fig, path, dpi=120, *, png_compress_level=None):
    """Save a matplotlib figure atomically and close it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure (closed after saving).
    path : path-like
        The file; its suffix names the format (PNG when it has none).
    dpi : float, default 120
        Dots per inch of the image.
    png_compress_level : int, optional
        zlib level of a PNG's compression, 0-9 (None: Pillow's default, 6). It changes the file's
        size and the time to write it, never its pixels; ignored for other formats.
    """
    import matplotlib.pyplot as plt
    fmt = Path(path).suffix[1:] or "png"
    extra = {"pil_kwargs": {"compress_level": int(png_compress_level)}} \
        if fmt.lower() == "png" and png_compress_level is not None else {}
    try:
        return _atomic(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format=fmt, **extra))
    finally:
        plt.close(fig)
