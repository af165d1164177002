"""Argument helpers shared by the command-line entry points (``workbench.cli`` and the
``selfsense`` command's parser): one quantity type and one output convention.

Library modules never import :mod:`workbench.cli`; the selfsense command builds its own
parser, and both take their argparse types and output convention from here.
"""

import argparse
from pathlib import Path

from .errors import WorkbenchError
from .units import parse_quantity

__all__ = ["quantity", "emit", "path", "refuse_empty_paths"]


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
