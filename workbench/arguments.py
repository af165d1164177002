"""Argument helpers shared by the command-line entry points (``workbench.cli``, the ``selfsense``
command's parser and the ``python -m workbench.design.*`` research entries): one quantity type, one
output convention, one-line usage errors and the Ctrl-C / SIGTERM handling.

Library modules never import :mod:`workbench.cli`; the selfsense command builds its own
parser, and both take their argparse types and output convention from here.
"""

import argparse
import contextlib
import sys
from pathlib import Path

from .errors import WorkbenchError
from .units import parse_quantity

__all__ = ["quantity", "emit", "path", "refuse_empty_paths", "OneLineErrorParser", "Terminated", "sigterm_raises",
           "interrupted_status", "run_script", "DEFAULT_SCENARIOS"]

#: ``verify --scenario``'s default, compared by identity (``is``) to tell "not given" from ``--scenario all``:
#: the CLI's parser and the preflight read this one object
DEFAULT_SCENARIOS = ["all"]


def quantity(expected):
    """argparse type: a quantity in ``expected`` units ("1000s", "20min", "7.5um") through
    :func:`workbench.units.parse_quantity`; a bad value is an argparse error (usage, exit status 2)."""
    def parse(text):
        try:
            return parse_quantity(text, expected)
        except WorkbenchError as err:
            raise argparse.ArgumentTypeError(str(err)) from err
    parse.__name__ = f"quantity in {expected}"
    return parse


def path(text):
    """argparse type: a file or folder path, never empty. ``Path("")`` is the current folder, so
    ``--out "$OUT"`` with ``OUT`` unset would write into it (a study then replaces ./controllers/*.json)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"an empty path {text!r}; give a file or folder name (an unset shell "
                                         f"variable?)")
    return Path(text)


def refuse_empty_paths(parser):
    """Give every ``type=Path`` argument of ``parser`` and its subcommands the :func:`path` type; returns it."""
    for action in parser._actions:
        if action.type is Path:
            action.type = path
        for sub in (action.choices.values() if isinstance(action, argparse._SubParsersAction) else ()):
            refuse_empty_paths(sub)
    return parser


def emit(args, data, lines):
    """The output convention: ``lines`` on stdout, ``data`` as JSON (written whole) when ``--json``."""
    from .report import write_json
    for line in lines:
        print(line)
    if getattr(args, "json", None):
        write_json(args.json, data)
        print(f"wrote {args.json}")


class OneLineErrorParser(argparse.ArgumentParser):
    """argparse's parser whose usage errors are one line on stderr, exit status 2, as every other error of the
    workbench (argparse printed its usage first: 5-11 lines); ``--help`` prints the usage as before.
    The sub-commands' parsers are of this class too (``add_subparsers`` uses the parent's class)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


class Terminated(KeyboardInterrupt):
    """SIGTERM (a plain ``kill``) turned into an exception in the main thread, so that the run's cleanup
    (:func:`workbench.preflight.preflight`: no partial outputs) runs as it does for Ctrl-C."""


@contextlib.contextmanager
def sigterm_raises():
    """Within the block, SIGTERM raises :class:`Terminated` in the main thread (once: a second SIGTERM during
    the cleanup is ignored; SIGKILL still ends the process). Outside the main thread, nothing changes."""
    import signal
    import threading
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise Terminated()
    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def interrupted_status(prog, err, cleaned=True):
    """Print the one line of a run ended by Ctrl-C or a plain kill (no traceback) and return its exit status,
    128 + the signal's number, as a shell reports a process the signal ended. ``cleaned``: the run's outputs
    were removed (the ``workbench`` commands' preflight); the research entries say nothing of outputs."""
    terminated = isinstance(err, Terminated)
    said = "; nothing written (the outputs this run created are removed)" if cleaned else ""
    print(f"{chr(10) if sys.stderr.isatty() else ''}{prog}: {'terminated' if terminated else 'interrupted'}{said}",
          file=sys.stderr)
    return 143 if terminated else 130


def run_script(prog, func, argv=None):
    """Run a ``python -m workbench.X`` research entry ``func(argv)`` with the ``workbench`` command's conventions:
    a user error (WorkbenchError, ValueError, OSError) is one line on stderr and exit status 2; Ctrl-C (130) and
    a plain kill (SIGTERM, 143) one line and no traceback. Returns the exit status (for ``raise SystemExit``)."""
    try:
        with sigterm_raises():
            func(argv)
    except KeyboardInterrupt as err:
        return interrupted_status(prog, err, cleaned=False)
    except (WorkbenchError, ValueError, OSError) as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return 2
    return 0
