#!/usr/bin/env bash
# Long motions from a timeline, measured: K-TranS at the window joins against K-TranS away from
# them, foot skating of the long motions against 196-frame motions of the same prompts, and
# seconds of compute per minute of motion.
#   scripts/timeline-table.sh MODEL OUT [--samples 8]
set -euo pipefail
usage="usage: scripts/timeline-table.sh MODEL OUT [--samples N]"
source "$(dirname "$0")/args.sh"
need_args $# 2
model=$1 out=$2; shift 2
samples=8
while [ $# -gt 0 ]; do case "$1" in --samples) need_count --samples "${2-}"; samples=$2; shift 2 ;; *) unknown_arg "$1" ;; esac; done
need_path MODEL "$model"
need_bin
timeline="0-8s: a person walks forward. | 8-11s: a person jumps forward. | 11-20s: a person walks in a circle. | 20-30s: a person runs forward."
t0=$(date +%s.%N)
"$bin" sample --checkpoint "$model" --timeline "$timeline" --num-samples "$samples" --out "$out/long" > "$out.long.log" 2>&1
t1=$(date +%s.%N)
i=0
IFS='|' read -ra segs <<< "$timeline"
for seg in "${segs[@]}"; do
  "$bin" sample --checkpoint "$model" --text "${seg#*: }" --length 196 --num-samples "$samples" --out "$out/short$i" > /dev/null 2>&1
  i=$((i + 1))
done
python3 - "$out" "$samples" "$t0" "$t1" <<'PY'
import json, sys, statistics as st
out, n, t0, t1 = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
r = json.load(open(f"{out}/long/results.json"))
joins = [v for v in r["k_trans_at_joins"] if v is not None]
away = [v for v in r["k_trans_away_from_joins"] if v is not None]
long_fs = [s["foot_skating"] for s in r["samples"]]
short_fs = [s["foot_skating"] for i in range(4) for s in json.load(open(f"{out}/short{i}/results.json"))["samples"]]
minutes = n * r["length"] / 20 / 60
print(f"{n} motions of {r['length']} frames ({len(r['windows'])} windows, joins at frames {r['joins']})")
print(f"K-TranS at joins {st.mean(joins):.4f} (per motion {min(joins):.4f}-{max(joins):.4f}); away from joins {st.mean(away):.4f}; ratio {st.mean(joins) / st.mean(away):.2f}")
print(f"foot skating: long {st.mean(long_fs):.3f}; 196-frame motions of the same four prompts {st.mean(short_fs):.3f}")
print(f"sampler {r['seconds']:.1f} s, whole command {t1 - t0:.1f} s for {minutes:.1f} min of motion: {(t1 - t0) / minutes:.1f} s per minute")
PY
