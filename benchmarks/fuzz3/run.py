"""The third outside pass (README "Bad input", fuzz3): every case in a fresh process, exit status, traceback, the
workspace's hashes and the output folder checked. Not a user-facing tool.

    python benchmarks/fuzz3/make_ws.py /tmp/fz3/base && python benchmarks/fuzz3/bad_files.py /tmp/fz3/base
    cp -a /tmp/fz3/base /tmp/fz3/pristine
    FZ_TIMEOUT=40 python benchmarks/fuzz3/run.py TAG [CASE_ID ...]    # results in /tmp/fz3/results_TAG.jsonl

FZ_CODE=DIR runs another checkout's package (e.g. `git archive 6828958 workbench plants controllers | tar -x -C DIR`),
FZ_PART=0/1 every other case (two runners), FZ_BASE another workspace copy.
"""
import hashlib, json, os, shutil, subprocess, sys, time
from pathlib import Path
WORK = Path(os.environ.get("FZ_WORK", "/tmp/fz3"))
sys.path.insert(0, str(Path(__file__).parent)); from cases import CASES
BASE = Path(os.environ.get("FZ_BASE", WORK / "base")); ROOT = Path(__file__).resolve().parents[2]; CODE = Path(os.environ.get("FZ_CODE", ROOT))
only = set(sys.argv[2:]); tag = sys.argv[1]
res_path = WORK / f"results_{tag}.jsonl"
def hashes(p):
    return {str(q): hashlib.sha256(q.read_bytes()).hexdigest() for q in sorted(p.rglob("*")) if q.is_file()}
root_before = hashes(ROOT / "plants") | hashes(ROOT / "controllers")
base_h = hashes(BASE)
with open(res_path, "w") as fh:
    for i, (cid, argv) in enumerate(CASES):
        if only and cid not in only:
            continue
        if os.environ.get('FZ_PART') and i % 2 != int(os.environ['FZ_PART']):
            continue
        out = WORK / "out" / tag / cid; shutil.rmtree(out, ignore_errors=True); out.mkdir(parents=True)
        argv = [a.replace("{out}", str(out / "o")).replace("@ROOT", str(ROOT)) for a in argv]
        env = {**os.environ, "PYTHONPATH": str(CODE), "OPENBLAS_NUM_THREADS": "1"}
        t0 = time.time()
        try:
            p = subprocess.run([sys.executable, "-m", "workbench", *argv], cwd=BASE, capture_output=True, text=True,
                               timeout=float(os.environ.get("FZ_TIMEOUT", 60)), env=env)
            rc, err, outp = p.returncode, p.stderr, p.stdout
        except subprocess.TimeoutExpired as e:
            rc, err, outp = "timeout", (e.stderr or b"").decode(errors="replace") if isinstance(e.stderr, bytes) else (e.stderr or ""), ""
        dt = time.time() - t0
        now = hashes(BASE)
        changed = [k for k in set(now) | set(base_h) if now.get(k) != base_h.get(k)]
        left = [str(q) for q in out.rglob("*")]
        rec = {"id": cid, "argv": argv, "rc": rc, "s": round(dt, 1), "tb": "Traceback" in err,
               "err_lines": [l for l in err.splitlines() if "error:" in l][:3], "tail": err[-600:], "stdout": outp[-400:],
               "changed": changed, "left": left[:5]}
        fh.write(json.dumps(rec) + "\n"); fh.flush()
        print(cid, rc, f"{dt:.0f}s", "TB" if rec["tb"] else "", "CHANGED" if changed else "", "LEFT" if left else "",
              (rec["err_lines"] or [err[-200:]])[0][:220], flush=True)
        if changed:   # restore the workspace
            for k in changed:
                rel = Path(k).relative_to(BASE); src = (WORK / "pristine") / rel
                if src.exists(): shutil.copy2(src, k)
                else: Path(k).unlink()
            base_h = hashes(BASE)
root_after = hashes(ROOT / "plants") | hashes(ROOT / "controllers")
print("ROOT CHANGED:", [k for k in root_after if root_after[k] != root_before.get(k)])
