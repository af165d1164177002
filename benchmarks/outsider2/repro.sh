#!/bin/bash
# s34_outsider: regenerate one batch case (gen.py, the independent simulator) and calibrate it with the CLI.
#   benchmarks/outsider2/repro.sh CASE_NAME [extra calibrate args]     (case names: batch.py --list)
# Writes /tmp/s34o_repro/CASE.csv and .json; prints the CLI's console answer.
set -e
cd "$(dirname "$0")/../.."
export OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD
PY=${PY:-/work/main/.venv/bin/python}
case=$1; shift
$PY - "$case" <<'PYEOF'
import sys; sys.path.insert(0, "benchmarks/outsider2")
from pathlib import Path
import batch, gen
c = [c for c in batch.cases() + batch.cases_extra() if c["name"] == sys.argv[1]][0]
rec, meta, plant, params, sizes = batch.build(c)
Path("/tmp/s34o_repro").mkdir(exist_ok=True)
gen.write_csv(f"/tmp/s34o_repro/{c['name']}.csv", rec, meta)
open(f"/tmp/s34o_repro/{c['name']}.plant", "w").write(c.get("plant", plant))
print("params", params, "sizes (x noise)", sizes)
PYEOF
plant=$(cat /tmp/s34o_repro/$case.plant)
echo "+ $PY -m workbench calibrate /tmp/s34o_repro/$case.csv --plant $plant --json /tmp/s34o_repro/$case.json $*"
$PY -m workbench calibrate /tmp/s34o_repro/$case.csv --plant $plant --json /tmp/s34o_repro/$case.json "$@" 2>&1 | grep -v '\[\.*#*\.*\]'
