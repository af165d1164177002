"""The Python API: ``import workbench as wb``, and the README's example script."""

import importlib
import subprocess
import sys

import workbench as wb

from .conftest import ROOT


def test_every_public_name_resolves_and_verify_is_the_function():
    for name in wb.__all__:
        assert getattr(wb, name) is not None, name
    import workbench.verify.sweep_job as job            # the subpackage's modules import as usual
    assert callable(wb.verify) and job.__name__ == "workbench.verify.sweep_job"
    try:                                                # and wb.verify(...) is verify.run.verify
        wb.verify("plants/none.toml", "controllers/sn637_loopshape.json", ["small_step"])
    except wb.WorkbenchError as err:
        assert "none.toml" in str(err)
    else:
        raise AssertionError("a missing plant file must raise")
    importlib.import_module("workbench.calibrate.record")   # importing the subpackage must not shadow the API name
    assert wb.calibrate_record.__name__ == "run_calibrate"


def test_the_api_does_not_import_the_cli():
    # library first: importing every public name loads no part of the command line
    code = ("import sys, workbench as wb\n"
            "[getattr(wb, n) for n in wb.__all__]\n"
            "print('workbench.cli' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_no_library_module_imports_the_cli():
    """Library first: no module of the package but the command line itself (``cli.py``, ``__main__.py``) imports
    ``workbench.cli``, at module level or inside a function (``from .cli``, ``from ..cli``, ``from . import cli``,
    ``import workbench.cli``): the research entries and the preflight take what they share from
    ``workbench.arguments``."""
    import ast
    offenders = []
    for path in sorted((ROOT / "workbench").rglob("*.py")):
        if path.relative_to(ROOT / "workbench").as_posix() in ("cli.py", "__main__.py"):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""] + ([a.name for a in node.names] if not node.module else [])
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            if any(n == "cli" or n.endswith(".cli") for n in names):
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not offenders, offenders


def test_pi_example_runs_under_20_lines():
    # examples/pi_from_python_control.py: a PI from python-control to firmware form and verified
    script = ROOT / "examples" / "pi_from_python_control.py"
    assert len(script.read_text().splitlines()) <= 20
    out = subprocess.run([sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("32-bit fixed-point cascade, 1 section at 10000 Hz")
    assert "current-limit window +0.16/-1.12 V" in lines[0]
    # the PI crosses over where it was designed to, and the verify result has no preflight mismatch
    assert "crossover_hz=99.99" in lines[1] or "crossover_hz=100.0" in lines[1]
    assert "0 preflight mismatches" in lines[2] and "pi_example on SN637" in lines[2]
    assert "nan" not in out.stdout
