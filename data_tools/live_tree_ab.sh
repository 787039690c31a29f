#!/bin/bash
# Interleaved A/B of `vtrack --threads 1 bench live` (default variant, the bench's 3 cases) between two source trees,
# 4 rounds in the order A B, B A, A B, B A; results in OUT/live_<A|B>_<round>/live.csv.
# Usage: data_tools/live_tree_ab.sh TREE_A TREE_B OUT   (VTRACK_SHARED must point at the shared data)
set -u
TA=$(cd "$1" && pwd); TB=$(cd "$2" && pwd); OUT=$3; mkdir -p "$OUT"; OUT=$(cd "$OUT" && pwd)
export VTRACK_BENCH_LIVE_VARIANTS='default (touch process, frames process, reader process)'
for spec in "1 A" "1 B" "2 B" "2 A" "3 A" "3 B" "4 B" "4 A"; do
  set -- $spec; r=$1; v=$2
  if [ "$v" = A ]; then T=$TA; else T=$TB; fi
  (cd /tmp && PYTHONPATH=$T:$T/apps python -c "from vtrack_apps.cli import main; main()" --threads 1 bench live \
    --out "$OUT/live_${v}_$r" > "$OUT/live_${v}_$r.log" 2>&1)
  echo "$r $v done $(date +%T)"
done
