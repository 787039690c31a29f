#!/bin/bash
# CPU of the live replay's reader process alone, interleaved between source trees: `vtrack --threads 1 live S
# --consumer null` (every field of every stream decoded, nothing else to share the cores with), ROUNDS rounds in
# the order given; prints tree, round, reader-process CPU s, main-process CPU s, replayed session s, frames skipped.
# Usage: data_tools/live_reader_ab.sh SESSION ROUNDS TREE...   (VTRACK_SHARED must point at the shared data)
set -u
S=$1; ROUNDS=$2; shift 2
OUT=$(mktemp -d)
for r in $(seq 1 "$ROUNDS"); do
  for T in "$@"; do
    T=$(cd "$T" && pwd)
    (cd /tmp && PYTHONPATH=$T:$T/apps python -c "from vtrack_apps.cli import main; main()" --threads 1 live "$S" \
      --consumer null --json "$OUT/null.json" > /dev/null 2>&1)
    python -c "
import json, sys
d = json.load(open('$OUT/null.json')); c = d['cpu']
print('$T', $r, c['children_s'], c['main_s'], c['session_s'], d['source']['skipped_late'])"
  done
done
rm -rf "$OUT"
