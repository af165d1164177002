#!/bin/bash
# The set-up and suite from a fresh clone, timed (the developers' guide: "a fresh machine with Python 3.11 and pip,
# then make demo and make test"; README "Where the issues' floors stand", the make-test row).
#
#   benchmarks/fresh_clone.sh TAG [COMMIT] [demo]
#
# Clones this repository at COMMIT (default: HEAD of main) into ${TMPDIR:-/tmp}/wb_fresh_TAG (removed first), runs
# `make .venv/.installed` (a new virtualenv: pip installs the pinned requirements), `make test` under /usr/bin/time
# (the numba cache starts empty: it lives in the clone), and with `demo` also `make demo`. Prints (and writes to
# ${TMPDIR:-/tmp}/wb_fresh_TAG.log) the commit, the date, the load, each step's exit status and seconds, and
# pytest's summary line.
set -u
TAG=${1:?usage: benchmarks/fresh_clone.sh TAG [COMMIT] [demo]}; C=${2:-main}
SRC=$(cd "$(dirname "$0")/.." && pwd); D=${TMPDIR:-/tmp}/wb_fresh_$TAG; L=$D.log
rm -rf "$D"; git clone -q "$SRC" "$D" && cd "$D" && git checkout -q "$C" || exit 1
{ echo "commit $(git log --oneline -1)"; date -u; uptime
  s=$(date +%s); make .venv/.installed > /dev/null 2>&1; echo "install rc $? $(( $(date +%s)-s )) s"
  s=$(date +%s); /usr/bin/time -f "CPU user %U sys %S wall %e" make test 2>&1 | tail -4
  echo "make test rc ${PIPESTATUS[0]} $(( $(date +%s)-s )) s"; date -u; uptime
  if [ "${3:-}" = demo ]; then s=$(date +%s); make demo > "$D/demo.log" 2>&1; echo "demo rc $? $(( $(date +%s)-s )) s"; fi
} 2>&1 | tee "$L"
