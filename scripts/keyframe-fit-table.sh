#!/usr/bin/env bash
# The keyframe-fit comparison of README ("Keyframe fits"): the same model, keyframes and seeds
# evaluated with each fit (track, warp, paste, none), with and without root keyframes.
#   scripts/keyframe-fit-table.sh RUN EVALUATOR DATA OUT [extra eval flags...]
set -euo pipefail
usage="usage: scripts/keyframe-fit-table.sh RUN EVALUATOR DATA OUT [extra eval flags]"
source "$(dirname "$0")/args.sh"
need_args $# 4
run=$1 evaluator=$2 data=$3 out=$4
shift 4
need_path RUN "$run"
need_path EVALUATOR "$evaluator"
need_data DATA "$data"
need_bin
for fit in track warp paste none; do
  for root in on off; do
    flags=()
    [ "$root" = off ] && flags+=(--no-root-keys)
    "$bin" eval --checkpoint "$run" --evaluator "$evaluator" --data "$data" --keyframe-fit "$fit" "${flags[@]}" \
      --out "$out/$fit-root-$root" "$@" >/dev/null
    echo "done: $fit, root keyframes $root" >&2
  done
done
python3 - "$out" <<'PY'
import json, sys, os
out = sys.argv[1]
print("| fit | root keyframes | K-Err global (m) | K-Err root-relative (m) | K-TranS | real K-TranS | foot skating | real foot skating | FID |")
print("|---|---|---|---|---|---|---|---|---|")
for fit in ["track", "warp", "paste", "none"]:
    for root in ["on", "off"]:
        r = json.load(open(os.path.join(out, f"{fit}-root-{root}", "report.json")))
        rows = r["rows"]
        gen = next(x for x in rows if not x["real"])
        real = next(x for x in rows if x["real"])
        m = lambda row, k: row["metrics"].get(k, {}).get("mean")
        f = lambda v: "-" if v is None else f"{v:.4f}"
        print(f"| {fit} | {root} | {f(m(gen,'k_err'))} | {f(m(gen,'k_err_local'))} | {f(m(gen,'k_trans'))} | {f(m(gen,'k_trans_real'))} | {f(m(gen,'foot_skate'))} | {f(m(real,'foot_skate'))} | {f(m(gen,'fid'))} |")
PY
