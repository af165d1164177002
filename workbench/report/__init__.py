"""Reports: atomic writers and figures."""

from .output import save_figure, to_jsonable, write_json

__all__ = ["save_figure", "to_jsonable", "write_json"]
