#!/bin/bash
# the real record (../shared/data/real) against plants/generic_stack.toml: training cycles 2-8 and the
# forward / blocks splits, through the CLI. One line each: exit code and answer (or the error's last line).
cd "$(dirname "$0")/../.." || exit 1
export PYTHONPATH=$PWD OPENBLAS_NUM_THREADS=1
PY=${PY:-/work/main/.venv/bin/python}
D=${1:-/tmp/s22o_real}; mkdir -p "$D"
H="index,time[s],displacement[um],voltage[V]"   # tests/calibrate/test_pi_fit.py REAL_HEADER
{ echo "# input: command"; echo "$H"; cat /work/shared/data/real/hysteresis_v_150_1hz.csv; } > "$D/real.csv"
run() {  # tag, args...
  tag=$1; shift
  $PY -m workbench calibrate "$D/real.csv" --plant plants/generic_stack.toml --json "$D/$tag.json" "$@" > "$D/$tag.out" 2> "$D/$tag.err"
  rc=$?
  if [ $rc -eq 0 ]; then
    $PY -c "import json;d=json.load(open('$D/$tag.json'));c=d['base_fit']['channels']['displacement'];print('$tag rc=0',d['effect'],'+'.join(s['effect'] for s in d['stages']),d['agreement'],'split',d['split'],'base %.4f um'%(c['rms']*1e6),'after %.4f um'%(d['error_after']['rms']*1e6),'warn',len(d['base_fit']['warnings']),'folds',d.get('fold_winners'))"
  else echo "$tag rc=$rc tb=$(grep -c Traceback $D/$tag.err) :: $(tail -1 $D/$tag.err | cut -c1-300)"; fi
}
for c in 2 3 4 5 6 7 8; do run cycles$c --train-cycles $c; done
run cycles1.5 --train-cycles 1.5
run forward --split forward
run blocks --split blocks
