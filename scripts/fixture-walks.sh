#!/usr/bin/env bash
# A model on real motion: the two HumanML3D clips of the shared fixtures (012314: a walk forward,
# a turn and back, then standing; 000021, through HumanML3D's own processing: a walk in a loop),
# keyed at 5%, sampled by the network alone and by the default pipeline; root speed and stride
# against the clip's own, foot skating, K-TranS and how far under the floor the body goes
# (docs/reference-model.md). The fixtures carry no captions: the ones below are ours,
# the same for every model. Each of K key sets (seeds S .. S+K-1: the seed draws the keys and
# the noise) gets N samples; one key set alone swings a clip's skating by half (docs/reference-model.md),
# so the table is the mean over all K x N samples with its standard error.
#   scripts/fixture-walks.sh MODEL OUT [--fixtures DIR] [--samples N] [--seed S] [--key-sets K] [-- SAMPLE FLAGS...]
set -euo pipefail
usage="usage: scripts/fixture-walks.sh MODEL OUT [--fixtures DIR] [--samples N] [--seed S] [--key-sets K] [-- SAMPLE FLAGS...]"
source "$(dirname "$0")/args.sh"
need_args $# 2
model=$1 out=$2
shift 2
fixtures="${DIFFKFC_FIXTURES:-$(dirname "$0")/../../shared/fixtures}" samples=8 seed=3 key_sets=4 extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --) shift; extra=("$@"); break ;;
    --fixtures) fixtures=$2; shift 2 ;;
    --samples) need_count --samples "${2-}"; samples=$2; shift 2 ;;
    --seed) need_uint --seed "${2-}"; seed=$2; shift 2 ;;
    --key-sets) need_count --key-sets "${2-}"; key_sets=$2; shift 2 ;;
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
    for ((s = seed; s < seed + key_sets; s++)); do
      "$bin" sample --checkpoint "$model" --text "$text" --from "$src" --keyframe-rate 0.05 \
        --seed "$s" --num-samples "$samples" --out "$out/$name-$mode-seed$s" --force \
        "${flags[@]}" "${extra[@]}" >/dev/null
    done
  done
done

python3 - "$out" "$model" "$seed" "$key_sets" <<'PY' | tee "$out/fixture-walks.md"
import json, math, os, statistics, sys
out, model = sys.argv[1], sys.argv[2]
seeds = range(int(sys.argv[3]), int(sys.argv[3]) + int(sys.argv[4]))
def mean_se(v):
    se = statistics.stdev(v) / math.sqrt(len(v)) if len(v) > 1 else float("nan")
    return statistics.fmean(v), se
def cell(m, se, digits):
    return f"{m:.{digits}f}" if math.isnan(se) else f"{m:.{digits}f} ± {se:.{digits}f}"
print(f"{model}: the fixtures' real clips, 5% keys, {len(seeds)} key set(s) (seeds {seeds[0]}-{seeds[-1]}), mean ± standard error over the samples")
print()
print("| clip | sampled by | speed ratio | stride ratio | foot skating (clip's own) | K-TranS (clip's own) | under the floor, m (clip's own) |")
print("|---|---|---|---|---|---|---|")
rows = []
for clip in ["012314", "000021"]:
    for mode in ["raw", "default"]:
        per = []
        for seed in seeds:
            r = json.load(open(os.path.join(out, f"{clip}-{mode}-seed{seed}", "results.json")))
            src = r["real_gait"]
            for x in r["samples"]:
                per.append({"speed_ratio": x["gait"]["root_speed_mps"] / src["root_speed_mps"],
                            "stride_ratio": x["gait"]["stride_amplitude_m"] / src["stride_amplitude_m"],
                            "foot_skating": x["foot_skating"], "real_foot_skating": r["real_foot_skating"],
                            "k_trans": x["k_trans"], "real_k_trans": r["real_k_trans"],
                            "penetration_m": x["penetration_m"], "real_penetration_m": r["real_penetration_m"]})
        row = {"clip": clip, "mode": mode, "samples": len(per)}
        for k in per[0]:
            row[k], row[k + "_se"] = mean_se([p[k] for p in per])
        rows.append(row)
        name = "the network alone" if mode == "raw" else "the default pipeline"
        print(f"| {clip} | {name} | {cell(row['speed_ratio'], row['speed_ratio_se'], 2)} | "
              f"{cell(row['stride_ratio'], row['stride_ratio_se'], 2)} | "
              f"{cell(row['foot_skating'], row['foot_skating_se'], 3)} ({row['real_foot_skating']:.3f}) | "
              f"{cell(row['k_trans'], row['k_trans_se'], 4)} ({row['real_k_trans']:.4f}) | "
              f"{cell(row['penetration_m'], row['penetration_m_se'], 4)} ({row['real_penetration_m']:.4f}) |")
json.dump({"model": model, "seeds": list(seeds), "rows": rows}, open(os.path.join(out, "fixture-walks.json"), "w"), indent=1)
PY
