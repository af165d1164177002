"""CPU time (process_time) of the calibration's phases on one record, in-process: wraps the named functions
where the run looks them up.  python phase_probe.py RECORD PLANT OUTDIR"""
import sys, time, importlib
from collections import defaultdict
T0 = time.process_time()
acc = defaultdict(float); cnt = defaultdict(int)
def wrap(modname, fname, label=None):
    mod = importlib.import_module(modname); f = getattr(mod, fname); label = label or f"{modname.split('.')[-1]}.{fname}"
    def g(*a, **k):
        t = time.process_time()
        try: return f(*a, **k)
        finally: acc[label] += time.process_time() - t; cnt[label] += 1
    setattr(mod, fname, g)
from workbench.calibrate import run as R
t_imp = time.process_time() - T0
for m, f in [("workbench.calibrate.run", n) for n in ("fit_base", "trace_effect", "fit_holds", "choose_core",
             "carried_stages", "updated_plant_text", "updated_plant_error", "calibration_figures", "read_record",
             "load_plant", "_check_displacement_scale", "_check_time_scale", "make_split", "residual_reports",
             "write_report", "_check_plant_text")] + [
("workbench.calibrate.stages", "run_stages"),
             ("workbench.calibrate.tracing", "_score_stage")]:
    try: wrap(m, f)
    except AttributeError: pass
# per effect: the first stage's search (_candidate_columns) and the later stage's re-search (_research)
import workbench.calibrate.tracing as _T, workbench.calibrate.stages as _S
_cc, _rs = _T._candidate_columns, _S._research
def _cc_w(eff, *a, **k):
    t = time.process_time()
    try: return _cc(eff, *a, **k)
    finally: acc[f"  first stage {eff.name}"] += time.process_time() - t; cnt[f"  first stage {eff.name}"] += 1
def _rs_w(c, *a, **k):
    t = time.process_time()
    try: return _rs(c, *a, **k)
    finally: acc[f"  re-search {c['name']}"] += time.process_time() - t; cnt[f"  re-search {c['name']}"] += 1
_T._candidate_columns, _S._research = _cc_w, _rs_w
from workbench.cli import main
from workbench._malloc import keep_freed_memory, small_pages
import gc
# as the command-line process sets itself up (cli.cmd_calibrate with _whole_process): heap kept, 4 kB pages, frozen imports
keep_freed_memory(); small_pages()
from workbench.report import calibrate_figures, calibrate_report, html  # noqa: F401
gc.freeze()
t1 = time.process_time()
try: main(["calibrate", sys.argv[1], "--plant", sys.argv[2], "--out", sys.argv[3]])
except SystemExit: pass
tot = time.process_time() - T0
print(f"imports(run) {t_imp:.2f}  cli+rest {time.process_time()-t1:.2f}  total {tot:.2f}", file=sys.stderr)
for k, v in sorted(acc.items(), key=lambda kv: -kv[1]):
    print(f"  {k:40s} {v:6.2f} s  x{cnt[k]}", file=sys.stderr)
