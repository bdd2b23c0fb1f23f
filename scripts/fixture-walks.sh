#!/usr/bin/env bash
# A model on real motion: the two HumanML3D clips of the shared fixtures (012314: a walk forward,
# a turn and back, then standing; 000021, through HumanML3D's own processing: a walk in a loop),
# keyed at 5%, sampled by the network alone and by the default pipeline; root speed and stride
# against the clip's own, foot skating, K-TranS and how far under the floor the body goes
# (docs/real-motion.md). The fixtures carry no captions: the ones below are ours,
# the same for every model.
#   scripts/fixture-walks.sh MODEL OUT [--fixtures DIR] [--samples N] [--seed S] [-- SAMPLE FLAGS...]
set -euo pipefail
usage="usage: scripts/fixture-walks.sh MODEL OUT [--fixtures DIR] [--samples N] [--seed S] [-- SAMPLE FLAGS...]"
source "$(dirname "$0")/args.sh"
need_args $# 2
model=$1 out=$2
shift 2
fixtures="${DIFFKFC_FIXTURES:-$(dirname "$0")/../../shared/fixtures}" samples=8 seed=3 extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --) shift; extra=("$@"); break ;;
    --fixtures) fixtures=$2; shift 2 ;;
    --samples) need_count --samples "${2-}"; samples=$2; shift 2 ;;
    --seed) need_uint --seed "${2-}"; seed=$2; shift 2 ;;
    *) unknown_arg "$1" ;;
  esac
done
need_path MODEL "$model"
h="$fixtures/humanml3d"
[ -f "$h/new_joint_vecs/012314.npy" ] || die "--fixtures $fixtures has no humanml3d/new_joint_vecs/012314.npy"
need_bin
mkdir -p "$out"

clips=("012314|$h/new_joint_vecs/012314.npy|a person walks forward, turns around and walks back."
       "000021|$h/000021_features_reference.npy|a person walks in a circle.")
for c in "${clips[@]}"; do
  IFS='|' read -r name src text <<< "$c"
  for mode in raw default; do
    flags=()
    [ "$mode" = raw ] && flags=(--keyframe-fit none --no-foot-lock --no-rigid)
    "$bin" sample --checkpoint "$model" --text "$text" --from "$src" --keyframe-rate 0.05 \
      --seed "$seed" --num-samples "$samples" --out "$out/$name-$mode" --force \
      "${flags[@]}" "${extra[@]}" >/dev/null
  done
done

python3 - "$out" "$model" <<'PY' | tee "$out/fixture-walks.md"
import json, os, statistics, sys
out, model = sys.argv[1], sys.argv[2]
print(f"{model}: the fixtures' real clips, 5% keys")
print()
print("| clip | sampled by | speed ratio | stride ratio | foot skating (clip's own) | K-TranS (clip's own) | under the floor, m (clip's own) |")
print("|---|---|---|---|---|---|---|")
rows = []
for clip in ["012314", "000021"]:
    for mode in ["raw", "default"]:
        r = json.load(open(os.path.join(out, f"{clip}-{mode}", "results.json")))
        src, s = r["real_gait"], r["samples"]
        mean = lambda f: statistics.fmean(f(x) for x in s)
        row = {"clip": clip, "mode": mode,
               "speed_ratio": mean(lambda x: x["gait"]["root_speed_mps"] / src["root_speed_mps"]),
               "stride_ratio": mean(lambda x: x["gait"]["stride_amplitude_m"] / src["stride_amplitude_m"]),
               "foot_skating": mean(lambda x: x["foot_skating"]), "real_foot_skating": r["real_foot_skating"],
               "k_trans": mean(lambda x: x["k_trans"]), "real_k_trans": r["real_k_trans"],
               "penetration_m": mean(lambda x: x["penetration_m"]), "real_penetration_m": r["real_penetration_m"]}
        rows.append(row)
        name = "the network alone" if mode == "raw" else "the default pipeline"
        print(f"| {clip} | {name} | {row['speed_ratio']:.2f} | {row['stride_ratio']:.2f} | "
              f"{row['foot_skating']:.3f} ({row['real_foot_skating']:.3f}) | {row['k_trans']:.4f} ({row['real_k_trans']:.4f}) | "
              f"{row['penetration_m']:.4f} ({row['real_penetration_m']:.4f}) |")
json.dump({"model": model, "samples": len(s), "rows": rows}, open(os.path.join(out, "fixture-walks.json"), "w"), indent=1)
PY
