#!/usr/bin/env bash
# Foot skating of a model's keyed walks under each foot post-process (docs/feet.md): the six
# keyed test walks of the design panel (5% keys, seed 2) and the quick start's walk (seed 1),
# each through the default track fit with --no-foot-lock, --feet warp, pin, network and steps.
#   scripts/feet-walks.sh MODEL OUT [--data DIR] [--samples N]
# Prints one Markdown table (also OUT/feet.md; the samples stay under OUT): per walk, the mean
# over its N samples (default 1) of each mode's foot skating, the default pipeline's (steps)
# planted share, the warp's stride factor and both pelvis drops, then the issue's planted
# share: the six walks' shares summed against the sources' (one sample moves it by about 0.03;
# four read it steadier).
set -euo pipefail
usage="usage: scripts/feet-walks.sh MODEL OUT [--data DIR] [--samples N]"
source "$(dirname "$0")/args.sh"
need_args $# 2
model=$1 out=$2
shift 2
data="${DIFFKFC_WORK:-work}/synth" samples=1
while [ $# -gt 0 ]; do
  case "$1" in
    --data) data=$2; shift 2 ;;
    --samples) need_count --samples "${2-}"; samples=$2; shift 2 ;;
    *) unknown_arg "$1" ;;
  esac
done
need_path MODEL "$model"
need_data --data "$data"
need_bin
mkdir -p "$out"

mapfile -t walks < <("$bin" data clips "$data" --split test --action walk_forward --min-frames 120 --count 6)
quick=$("$bin" data clips "$data" --split test --count 1 --action walk_forward --action wave)
cases=()
for w in "${walks[@]}"; do cases+=("$w:2"); done
cases+=("$quick:1")
for c in "${cases[@]}"; do
  w=${c%%:*} seed=${c##*:}
  text=$(head -n 1 "$data/texts/$w.txt" | cut -d'#' -f1)
  for mode in none warp pin network steps; do
    flags=(--feet "$mode")
    [ "$mode" = none ] && flags=(--no-foot-lock)
    "$bin" sample --checkpoint "$model" --text "$text" --from "$data/new_joint_vecs/$w.npy" \
      --keyframe-rate 0.05 --seed "$seed" --num-samples "$samples" --out "$out/$w-seed$seed/$mode" --force "${flags[@]}" >/dev/null
  done
done

python3 - "$out" "${cases[@]}" <<'PY' | tee "$out/feet.md"
import json, os, statistics, sys
out, cases = sys.argv[1], sys.argv[2:]
modes = ["none", "warp", "pin", "network", "steps"]
mean = statistics.fmean
print("| walk | source | " + " | ".join(modes) + " | planted share steps / source | warp: mean stride factor | pelvis drop warp / steps (m) |")
print("|---|---|" + "---|" * len(modes) + "---|---|---|")
cols = {m: [] for m in modes}
planted, planted_src = [], []
for c in cases:
    w, seed = c.split(":")
    r = {m: json.load(open(os.path.join(out, f"{w}-seed{seed}", m, "results.json"))) for m in modes}
    skate = {m: mean(s["foot_skating"] for s in r[m]["samples"]) for m in modes}
    for m in modes:
        cols[m].append(skate[m])
    share = mean(s["gait"]["planted_share"] for s in r["steps"]["samples"])
    src = r["none"]["real_gait"]["planted_share"]
    if c != cases[-1]:  # the panel's six walks; the last case is the quick start's walk
        planted.append(share)
        planted_src.append(src)
    strides = [s.get("stride") or {} for s in r["warp"]["samples"]]
    factor = f"{mean(st.get('mean_factor', 1.0) for st in strides):.2f}"
    kept = sum(1 for st in strides if st.get("warped"))
    if kept < len(strides):  # why the first unwarped sample was left as it was
        note = next(st.get("note") or "" for st in strides if not st.get("warped"))
        why = "undone: skated more" if note.startswith("undone") else "legs do not cycle"
        factor += f" ({len(strides) - kept} of {len(strides)} unwarped: {why})"
    drop_warp = mean(st.get("pelvis_drop_m", 0.0) for st in strides)
    drop_steps = mean(s["foot_lock"]["pelvis_drop_m"] for s in r["steps"]["samples"])
    print(f"| {w} (seed {seed}) | {r['none']['real_foot_skating']:.3f} | "
          + " | ".join(f"{skate[m]:.3f}" for m in modes)
          + f" | {share:.2f} / {src:.2f} | {factor} | {drop_warp:.3f} / {drop_steps:.3f} |")
print("| mean | | " + " | ".join(f"{mean(cols[m]):.3f}" for m in modes) + " | | | |")
n = len(r["steps"]["samples"])
ratio = sum(planted) / sum(planted_src) if sum(planted_src) > 0 else float("nan")
print(f"\nplanted share, default pipeline (steps), {len(planted)} walks x {n} sample(s): "
      f"{ratio:.3f} of the sources' ({sum(planted):.3f} / {sum(planted_src):.3f})")
PY
