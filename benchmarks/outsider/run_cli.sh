#!/bin/bash
# run `workbench calibrate` on every CSV in $1; one line each: exit code, answer or last stderr line
cd "$(dirname "$0")/../.." || exit 1
export PYTHONPATH=$PWD OPENBLAS_NUM_THREADS=1
PY=${PY:-/work/main/.venv/bin/python}
for f in "$1"/*.csv; do
  n=$(basename "$f" .csv)
  $PY -m workbench calibrate "$f" --plant ${PLANT:-plants/p888_51_sn637.toml} --json "$1/$n.json" > "$1/$n.out" 2> "$1/$n.err"
  rc=$?
  if [ -s "$1/$n.json" ] && [ $rc -eq 0 ]; then
    ans=$($PY -c "import json,sys;d=json.load(open('$1/$n.json'));print(d['effect'],'+'.join(s['effect'] for s in d.get('stages',[])),d.get('agreement'),'warnings:',len(d['base_fit'].get('warnings',[])))")
  else ans=$(tail -1 "$1/$n.err" | cut -c1-250); fi
  tb=$(grep -c Traceback "$1/$n.err")
  echo "$n rc=$rc tb=$tb :: $ans"
done
