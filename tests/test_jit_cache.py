"""The compiled kernels' cache follows the whole source: an edit to an inlined helper in another file
(plant/kernels.py into plant/coupled.py) must not reload the caller's stale machine code."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import workbench
from workbench._jit_cache import source_digest

PACKAGE = Path(workbench.__file__).resolve().parent


def test_an_edit_to_any_source_file_changes_the_cache_folder(tmp_path):
    copy = tmp_path / "workbench"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    before = source_digest(copy)
    assert before == source_digest(PACKAGE)                    # the bytes, not the place, name it
    kernels = copy / "plant" / "kernels.py"
    kernels.write_text(kernels.read_text() + "\n# an edit to a helper only\n")
    assert source_digest(copy) != before


def test_numba_caches_under_the_digest_or_where_the_user_said(tmp_path):
    code = "import workbench, numba; print(numba.config.CACHE_DIR)"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["WORKBENCH_CACHE_DIR"] = str(tmp_path)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert Path(out.stdout.strip()) == tmp_path / "numba" / source_digest()
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "mine")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert Path(out.stdout.strip()) == tmp_path / "mine"
