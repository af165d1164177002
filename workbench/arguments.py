"""Argument helpers shared by the command-line entry points (``workbench.cli`` and the
``selfsense`` command's parser): one quantity type and one output convention.

Library modules never import :mod:`workbench.cli`; the selfsense command builds its own
parser, and both take their argparse types and output convention from here.
"""

import argparse

from .errors import WorkbenchError
from .units import parse_quantity

__all__ = ["quantity", "emit"]


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


def emit(args, data, lines):
    """The output convention: ``lines`` on stdout, ``data`` as JSON (written whole) when ``--json``."""
    from .report import write_json
    for line in lines:
        print(line)
    if getattr(args, "json", None):
        write_json(args.json, data)
        print(f"wrote {args.json}")
