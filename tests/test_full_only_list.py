"""The list of ids ``make test`` leaves to the full form (tests/full_only.txt) stays honest: every id names a
test that exists, and none is an acceptance test the issues require in ``make test``."""
import ast
import importlib.util
import re

from tests.conftest import FULL_ONLY_LIST, ROOT, read_full_only


def _keep_patterns():
    spec = importlib.util.spec_from_file_location("reduce_suite", ROOT / "tools" / "reduce_suite.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.KEEP


def test_every_listed_id_names_a_test_function_that_exists():
    listed = read_full_only()
    assert listed, FULL_ONLY_LIST
    defined = {}
    for nid in listed:
        path, name = nid.split("::", 1)
        func = name.split("[", 1)[0]
        if path not in defined:
            tree = ast.parse((ROOT / path).read_text(encoding="utf-8"))
            defined[path] = {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
        assert func in defined[path], f"{FULL_ONLY_LIST}: {nid}: no test function {func} in {path}"


def test_no_required_acceptance_test_is_left_to_the_full_form():
    keep = _keep_patterns()
    hits = [nid for nid in read_full_only() if any(re.search(p, nid) for p in keep)]
    assert not hits, hits
