"""Defaults of the self-sensing study that the CLI's parser needs without importing the study
(:mod:`.run` imports python-control)."""

from pathlib import Path

__all__ = ["DEFAULT_CONTROLLER"]

DEFAULT_CONTROLLER = Path(__file__).resolve().parents[2] / "controllers" / "sn637_loopshape.json"
