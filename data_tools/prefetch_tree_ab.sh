#!/bin/bash
# Interleaved A/B of offline prefetched SLAM between two source trees (same poses expected).
# Usage: data_tools/prefetch_tree_ab.sh TREE_A TREE_B ROUNDS SECONDS MODE_A MODE_B [OBJECTS...]
# e.g. git worktree add --detach /tmp/base 186ffe2; data_tools/prefetch_tree_ab.sh /tmp/base . 1 5.0 on on
# (run from the repository with its venv active; VTRACK_SHARED must point at the shared data for another tree)
set -u
HERE=$(cd "$(dirname "$0")" && pwd)
TA=$(cd "$1" && pwd); TB=$(cd "$2" && pwd); R=$3; S=$4; MA=$5; MB=$6; shift 6
OBJS=${*:-005_tomato_soup_can 006_mustard_bottle 010_potted_meat_can 011_banana 025_mug 055_baseball}
D=${VTRACK_AB_DIR:-/tmp/vtrack_ab}; mkdir -p "$D"
k=0
for r in $(seq "$R"); do for o in $OBJS; do
  if [ $((k % 2)) = 0 ]; then order="A B"; else order="B A"; fi; k=$((k + 1))
  for v in $order; do
    if [ "$v" = A ]; then T=$TA; M=$MA; else T=$TB; M=$MB; fi
    out=$(cd /tmp && PYTHONPATH=$T python "$HERE/prefetch_one.py" "$o" "$S" "$M" 2>/dev/null | tail -1)
    cp "$D/poses_${o}_$M.npy" "$D/tree_${v}_${o}.npy" 2>/dev/null
    echo "$r $o $v $M $out"
  done
  python -c "import numpy as np; a=np.load('$D/tree_A_${o}.npy'); b=np.load('$D/tree_B_${o}.npy'); print('   maxdiff', np.abs(a-b).max())"
done; done
