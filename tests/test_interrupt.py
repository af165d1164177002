"""A run ended by Ctrl-C (SIGINT) or a plain ``kill`` (SIGTERM) after it has started writing leaves nothing
behind and says so in one line (issue 17, session 32's outside pass: SIGTERM left 3 PNGs in --out; SIGINT
printed a 50-line traceback from inside matplotlib).

The child is a real process running ``workbench.cli.main``; its command writes a first output and then
works on until it is signalled. The parent waits for that output to appear (no fixed sleep) and signals.
"""

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# A shell starts a background job (`make test &` in a script, some CI runners) with SIGINT ignored, and a Python
# started so keeps it ignored (by convention: that job must not die of the terminal's Ctrl-C); the child restores
# the default SIGINT handler to stand for a run typed at a terminal, where Ctrl-C reaches it. (Session 32's fresh
# clone once saw the SIGINT case time out in make test; not reproduced since: the child's disposition is now set
# here, and a timeout reports the child's stderr.)
CHILD = """
import signal, sys, time
from pathlib import Path
signal.signal(signal.SIGINT, signal.default_int_handler)
import workbench.cli as cli
from workbench.report.output import write_text

def writes_then_works(args):
    write_text(Path(args.out) / "freefree.png", "a first figure")
    while True:                      # the rest of the run
        time.sleep(0.01)

cli.cmd_freefree = writes_then_works
sys.exit(cli.main(["freefree", sys.argv[1], "--out", sys.argv[2], "--json", sys.argv[3]]))
"""


# each case is a child process (~3 s): a plain kill into a new folder, Ctrl-C into a folder that had a file
@pytest.mark.parametrize("sig, code, word, existing", [(signal.SIGTERM, 143, "terminated", False),
                                                       (signal.SIGINT, 130, "interrupted", True)])
def test_a_signalled_run_writes_nothing_and_says_so_in_one_line(sig, code, word, existing, tmp_path):
    out = tmp_path / "out"
    if existing:
        out.mkdir()
        (out / "earlier.txt").write_text("a previous run's file\n", encoding="utf-8")
    first = out / "freefree.png"
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(ROOT / "plants/p888_51_sn637.toml"), str(out),
                              str(tmp_path / "ff.json")], cwd=tmp_path, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    try:
        while not first.exists():                    # the run has started writing
            assert child.poll() is None, child.communicate()
            time.sleep(0.01)
        child.send_signal(sig)
        try:
            _, err = child.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            child.kill()
            _, err = child.communicate()
            pytest.fail(f"the child did not end within 60 s of signal {sig!r}; its stderr: {err!r}")
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == code, err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and word in lines[0] and "nothing written" in lines[0], err
    assert not (tmp_path / "ff.json").exists()
    if existing:
        assert [p.name for p in out.iterdir()] == ["earlier.txt"]
    else:
        assert not out.exists()
