"""Peak memory of a long closed-loop hold: it must not grow with the run's length.

Runs the mid-stroke hold of ``workbench bench`` (full creep plant, gauge noise on, the
exported controller) for ``--periods`` servo periods (default 10^8 = 10^4 s at 10 kHz,
~30 s) with ``--decimate`` (default 10000) in this process, and prints the peak RSS
(``ru_maxrss``) and the run time. Exit status 1 if the peak RSS is 500 MB or more.

    .venv/bin/python benchmarks/closed_loop_memory.py [--periods N] [--decimate D] [--json]

:func:`peak_rss_mb` runs it in a child process (a fresh peak), for ``workbench bench``
and the tests.
"""

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if __name__ == "__main__" and str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))       # measure this checkout's workbench, not whichever one is installed
PLANT = ROOT / "plants" / "p888_51_sn637_creep.toml"
CONTROLLER = ROOT / "controllers" / "sn637_loopshape.json"
LIMIT_MB = 500.0


def _peak_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0     # KB on Linux


def _hwm_mb():
    """VmHWM, this process image's own peak (Linux), as a cross-check of ru_maxrss; None elsewhere."""
    try:
        with open("/proc/self/status") as f:
            return next(int(l.split()[1]) / 1024.0 for l in f if l.startswith("VmHWM:"))
    except (OSError, StopIteration):
        return None


def hold(periods, decimate, plant_path=PLANT, controller_path=CONTROLLER):
    """Run the hold in this process; return (peak RSS MB before the hold, after it, run seconds)."""
    from workbench.bench import _hold

    cl, ref = _hold(plant_path, controller_path)
    cl.run(ref, periods=1000)                     # compile / load the cache outside the measured run
    before = _peak_mb()
    cl, ref = _hold(plant_path, controller_path)
    t0 = time.perf_counter()
    cl.run(ref, decimate=decimate, periods=periods)
    return before, _peak_mb(), time.perf_counter() - t0


def peak_rss_mb(periods, decimate, plant_path=PLANT, controller_path=CONTROLLER):
    """Run the hold in a child process; return (its peak RSS in MB, the run's seconds) (:func:`child_figures`)."""
    data = child_figures(periods, decimate, plant_path, controller_path)
    return data["peak_rss_mb"], data["seconds"]


def child_figures(periods, decimate, plant_path=PLANT, controller_path=CONTROLLER):
    """Run the hold in a child process; return its figures (``main --json``: peak RSS before and after, MB).

    Linux charges the memory image an ``exec`` replaces to the new program's ru_maxrss:
    spawned directly from a large process (python's subprocess uses vfork) the child
    would report the parent's peak. A forking /bin/sh in between makes that image sh's.
    """
    cmd = [sys.executable, __file__, "--periods", str(int(periods)), "--decimate", str(int(decimate)),
           "--plant", str(plant_path), "--controller", str(controller_path), "--json"]
    # '; exit $?' keeps sh from exec'ing the command in place (it must fork)
    done = subprocess.run(["/bin/sh", "-c", '"$0" "$@"; exit $?', *cmd], capture_output=True, text=True,
                          check=False)
    if done.returncode not in (0, 1):             # 1 = over the limit, still a measurement
        raise RuntimeError(f"closed_loop_memory.py failed:\n{done.stderr}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--periods", type=int, default=10**8)
    p.add_argument("--decimate", type=int, default=10_000)
    p.add_argument("--plant", type=Path, default=PLANT)
    p.add_argument("--controller", type=Path, default=CONTROLLER)
    p.add_argument("--json", action="store_true", help="print the figures as one JSON line")
    args = p.parse_args(argv)
    before, peak, sec = hold(args.periods, args.decimate, args.plant, args.controller)
    ok = peak < LIMIT_MB
    if args.json:
        print(json.dumps({"periods": args.periods, "decimate": args.decimate, "peak_rss_mb": peak,
                          "peak_rss_before_mb": before, "vm_hwm_mb": _hwm_mb(), "seconds": sec,
                          "limit_mb": LIMIT_MB}))
    else:
        print(f"{args.periods:.0e} periods, decimate {args.decimate}: {sec:.1f} s; peak RSS {peak:.1f} MB "
              f"({before:.1f} MB before the hold; limit {LIMIT_MB:g} MB: {'ok' if ok else 'EXCEEDED'})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
