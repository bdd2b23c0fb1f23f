#!/usr/bin/env bash
# How a model's root moves from text alone (docs/reference-model.md): the first N
# test clips, each sampled from its first caption with no keys (`--keyframe-rate 0`, the source
# only sets the length), against the clip itself. The evaluator's FID says how far the
# text-only samples are from real motion, not where; these two root numbers say where.
#   scripts/text-only-root.sh MODEL OUT [--data DIR] [--count 64] [--seed 1] [-- SAMPLE FLAGS...]
# Prints one line: mean root speed (m/s) of the samples and of the sources, the ratio of means
# over the clips whose source moves faster than 0.3 m/s, the correlation of the two speeds
# over the clips, and the mean |yaw rate| (rad/s) of both. Flags after `--` go to every
# `sample` (e.g. `-- --text-guidance 1.5`).
set -euo pipefail
usage="usage: scripts/text-only-root.sh MODEL OUT [--data DIR] [--count N] [--seed S] [-- SAMPLE FLAGS...]"
source "$(dirname "$0")/args.sh"
need_args $# 2
model=$1 out=$2
shift 2
data="${DIFFKFC_WORK:-work}/synth" count=64 seed=1 extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --) shift; extra=("$@"); break ;;
    --data) data=$2; shift 2 ;;
    --count) count=$2; shift 2 ;;
    --seed) need_uint --seed "${2-}"; seed=$2; shift 2 ;;
    *) unknown_arg "$1" ;;
  esac
done
need_path MODEL "$model"
need_data --data "$data"
need_bin
mkdir -p "$out"

mapfile -t clips < <("$bin" data clips "$data" --split test --count "$count")
for w in "${clips[@]}"; do
  text=$(head -n 1 "$data/texts/$w.txt" | cut -d'#' -f1)
  "$bin" sample --checkpoint "$model" --text "$text" --from "$data/new_joint_vecs/$w.npy" \
    --keyframe-rate 0 --seed "$seed" --out "$out/$w" --force "${extra[@]}" >/dev/null
done

python3 - "$out" "$data" "${clips[@]}" <<'PY'
import sys
import numpy as np

out, data, clips = sys.argv[1], sys.argv[2], sys.argv[3:]
FPS = 20


def root(path):
    # HumanML3D features: 0 root yaw rate, 1-2 root planar velocity (per frame).
    x = np.load(path)
    return np.linalg.norm(x[:, 1:3], axis=1).mean() * FPS, np.abs(x[:, 0]).mean() * FPS


gen = np.array([root(f"{out}/{w}/sample_00.npy") for w in clips])
src = np.array([root(f"{data}/new_joint_vecs/{w}.npy") for w in clips])
moving = src[:, 0] > 0.3
corr = f"{np.corrcoef(gen[:, 0], src[:, 0])[0, 1]:.2f}" if gen[:, 0].std() > 0 and src[:, 0].std() > 0 else "n/a"
ratio = f"{gen[moving, 0].mean() / src[moving, 0].mean():.2f}" if moving.any() else "n/a (none moves)"
print(
    f"{len(clips)} clips: root speed {gen[:, 0].mean():.2f} m/s (sources {src[:, 0].mean():.2f}); "
    f"moving clips' ratio of means {ratio}; "
    f"speed correlation {corr}; "
    f"|yaw rate| {gen[:, 1].mean():.3f} rad/s (sources {src[:, 1].mean():.3f})"
)
PY
