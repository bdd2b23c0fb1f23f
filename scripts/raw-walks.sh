#!/usr/bin/env bash
# The raw network on the design panel's six keyed walks (scripts/design-panel.sh), with several
# samples per walk: one sample per walk (the panel's, seed 2) moves by up to 0.3 of speed ratio
# from seed to seed on the slowest walk, too much to tell two checkpoints apart.
#   scripts/raw-walks.sh MODEL OUT [--data DIR] [--samples 4] [--seed 2] [-- SAMPLE FLAGS...]
# MODEL is an exported model or a run directory (its latest checkpoint). Each walk: its first
# caption, 5% keys with their places, `--keyframe-fit none --no-foot-lock --no-rigid`.
# Prints one Markdown table (also OUT/walks.md and OUT/walks.json): per walk the mean over the
# samples of the root-speed and stride-amplitude ratios to the source's, then the mean of the
# six (the panel's numbers) and the smallest walk mean. Flags after `--` go to every `sample`
# (e.g. `-- --sampler ddim --steps 1`, `-- --joints lower_body`).
set -euo pipefail
usage="usage: scripts/raw-walks.sh MODEL OUT [--data DIR] [--samples N] [--seed S] [-- SAMPLE FLAGS...]"
source "$(dirname "$0")/args.sh"
need_args $# 2
model=$1 out=$2
shift 2
data="${DIFFKFC_WORK:-work}/synth" samples=4 seed=2 extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --) shift; extra=("$@"); break ;;
    --data) data=$2; shift 2 ;;
    --samples) need_count --samples "${2-}"; samples=$2; shift 2 ;;
    --seed) need_uint --seed "${2-}"; seed=$2; shift 2 ;;
    *) unknown_arg "$1" ;;
  esac
done
need_path MODEL "$model"
need_data --data "$data"
need_bin
mkdir -p "$out"

mapfile -t walks < <("$bin" data clips "$data" --split test --action walk_forward --min-frames 120 --count 6)
for w in "${walks[@]}"; do
  text=$(head -n 1 "$data/texts/$w.txt" | cut -d'#' -f1)
  "$bin" sample --checkpoint "$model" --text "$text" --from "$data/new_joint_vecs/$w.npy" \
    --keyframe-rate 0.05 --seed "$seed" --num-samples "$samples" --out "$out/$w" --force \
    --keyframe-fit none --no-foot-lock --no-rigid "${extra[@]}" >/dev/null
done

python3 - "$out" "$model" "${walks[@]}" <<'PY' | tee "$out/walks.md"
import json, os, statistics, sys
out, model, walks = sys.argv[1], sys.argv[2], sys.argv[3:]
rows = []
for w in walks:
    r = json.load(open(os.path.join(out, w, "results.json")))
    src = r["real_gait"]
    speed = [s["gait"]["root_speed_mps"] / src["root_speed_mps"] for s in r["samples"]]
    stride = [s["gait"]["stride_amplitude_m"] / src["stride_amplitude_m"] for s in r["samples"]]
    rows.append({"walk": w, "speed_ratio": statistics.fmean(speed), "speed_ratios": speed,
                 "stride_ratio": statistics.fmean(stride), "stride_ratios": stride})
mean = lambda k: statistics.fmean(r[k] for r in rows)
summary = {"model": model, "samples": len(rows[0]["speed_ratios"]), "walks": rows,
           "speed_ratio": mean("speed_ratio"), "speed_ratio_min": min(r["speed_ratio"] for r in rows),
           "stride_ratio": mean("stride_ratio"),
           "first_sample_speed_ratio": statistics.fmean(r["speed_ratios"][0] for r in rows),
           "first_sample_stride_ratio": statistics.fmean(r["stride_ratios"][0] for r in rows)}
json.dump(summary, open(os.path.join(out, "walks.json"), "w"), indent=1)
print(f"{model}: {summary['samples']} samples per walk")
print()
print("| walk | speed ratio (samples) | stride ratio (samples) |")
print("|---|---|---|")
fmt = lambda v: ", ".join(f"{x:.2f}" for x in v)
for r in rows:
    print(f"| {r['walk']} | {r['speed_ratio']:.2f} ({fmt(r['speed_ratios'])}) | {r['stride_ratio']:.2f} ({fmt(r['stride_ratios'])}) |")
print(f"| **mean (smallest)** | **{summary['speed_ratio']:.2f} ({summary['speed_ratio_min']:.2f})** | **{summary['stride_ratio']:.2f}** |")
PY
