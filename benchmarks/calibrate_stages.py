"""CPU time per stage of one `workbench calibrate` run (issue 13's speed floor; session 16).

Runs the command in this process as ``python -m workbench calibrate`` does (``cli.main()`` with no
argv, so the command process's allocator settings apply), with ``time.process_time()`` and
``os.times()`` (user vs system) around the stages: reading, base fit, tracing (and its later stages),
hold fits, core choice (the file's replays), plant text, figures, report. Prints to stderr.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python benchmarks/calibrate_stages.py calibrate RECORD.csv \
        --plant plants/p888_51_sn637.toml --out OUT_DIR

(The speed benchmark's creep record: ``benchmarks/calibrate_speed.py``'s effect ``creep`` at seed 101.)
"""
import functools
import importlib
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
t_start = time.process_time(); os_start = os.times()
acc = {}
def wrap(modname, fname, label=None):
    m = importlib.import_module(modname)
    f = getattr(m, fname)
    label = label or f"{modname.split('.')[-1]}.{fname}"
    @functools.wraps(f)
    def g(*a, **k):
        t0 = time.process_time(); o0 = os.times()
        try:
            return f(*a, **k)
        finally:
            o1 = os.times()
            s = acc.setdefault(label, [0.0, 0.0, 0.0, 0])
            s[0] += time.process_time() - t0; s[1] += o1.user - o0.user; s[2] += o1.system - o0.system; s[3] += 1
    setattr(m, fname, g)
    return m
import workbench.cli
t_imp = time.process_time()
targets = [("workbench.calibrate.run", n) for n in ("read_record", "fit_base", "trace_effect", "fit_holds", "choose_core",
            "updated_plant_text", "_check_plant_text", "updated_plant_error", "plant_file_gaps")]
for mod, n in targets: wrap(mod, n)
wrap("workbench.calibrate.stages", "run_stages")
wrap("workbench.preflight", "preflight")
import workbench.report.calibrate_figures; wrap("workbench.report.calibrate_figures", "calibration_figures")
import workbench.report.calibrate_report; wrap("workbench.report.calibrate_report", "calibration_markdown")
import workbench.report.html; wrap("workbench.report.html", "write_html_report")
sys.argv = ["workbench"] + sys.argv[1:]
rc = workbench.cli.main()
end = os.times()
print(f"imports before main {t_imp - t_start:.2f} s CPU", file=sys.stderr)
for k, (c, u, s_, n) in acc.items():
    print(f"{k:32s} {n:3d} calls {c:6.2f} s CPU (user {u:5.2f} sys {s_:5.2f})", file=sys.stderr)
print(f"TOTAL {time.process_time():.2f} s CPU user {end.user:.2f} sys {end.system:.2f}", file=sys.stderr)
