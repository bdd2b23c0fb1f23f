#!/usr/bin/env bash
# Everything issue 49 measures to adopt a model as the reference, in one resumable run
# (docs/long-run.md): the evaluator's table (default pipeline at 5% keys and text only, 3 x 256
# items; the raw network at 5% keys), the six keyed walks' raw speed and stride (one sample per
# walk: the panel's; four: steadier), the walks' feet under every foot post-process (one and four
# samples; the quick start's walk among them), the text-only root, and the fixtures' two real
# clips. Run it for the candidate and the adopted model with the same EVALUATOR and DATA.
#   scripts/adoption-table.sh MODEL EVALUATOR DATA OUT [--items 256] [--reps 3]
# Each part is skipped when its output is already there (delete it to measure again); the
# summary goes to stdout and OUT/adoption.md.
set -euo pipefail
usage="usage: scripts/adoption-table.sh MODEL EVALUATOR DATA OUT [--items N] [--reps N]"
source "$(dirname "$0")/args.sh"
need_args $# 4
model=$1 evaluator=$2 data=$3 out=$4
shift 4
items=256 reps=3
while [ $# -gt 0 ]; do
  case "$1" in
    --items) need_count --items "${2-}"; items=$2; shift 2 ;;
    --reps) need_count --reps "${2-}"; reps=$2; shift 2 ;;
    *) unknown_arg "$1" ;;
  esac
done
need_path MODEL "$model"
need_path EVALUATOR "$evaluator"
need_data DATA "$data"
need_bin
mkdir -p "$out"
here=$(dirname "$0")
export DIFFKFC_BIN=$bin

part() { # name, marker file, then the command
  local name=$1 marker=$2; shift 2
  if [ -f "$out/$name/$marker" ]; then echo "present: $out/$name" >&2; return; fi
  local t0; t0=$(date +%s)
  "$@" >/dev/null
  echo "done: $name ($(( $(date +%s) - t0 )) s)" >&2
}
ev() { # name, then eval flags
  local name=$1; shift
  part "$name" report.json "$bin" eval --checkpoint "$model" --evaluator "$evaluator" --data "$data" \
    --out "$out/$name" --num-items "$items" --replications "$reps" --samples-for-ade 1 "$@"
}
ev eval-default --sweep-rates 0,0.05
ev eval-raw --keyframe-fit none --no-foot-lock --no-rigid
part raw-walks-1 walks.json "$here/raw-walks.sh" "$model" "$out/raw-walks-1" --data "$data" --samples 1
part raw-walks-4 walks.json "$here/raw-walks.sh" "$model" "$out/raw-walks-4" --data "$data" --samples 4
part feet-walks-1 feet.md "$here/feet-walks.sh" "$model" "$out/feet-walks-1" --data "$data" --samples 1
part feet-walks-4 feet.md "$here/feet-walks.sh" "$model" "$out/feet-walks-4" --data "$data" --samples 4
text_only_root() { # its one line, kept in root.txt
  local dir=$out/text-only-root
  mkdir -p "$dir"
  "$here/text-only-root.sh" "$model" "$dir" --data "$data" > "$dir/root.txt.partial"
  mv "$dir/root.txt.partial" "$dir/root.txt"
}
part text-only-root root.txt text_only_root
part fixture-walks fixture-walks.json "$here/fixture-walks.sh" "$model" "$out/fixture-walks"

python3 - "$out" "$model" "$data" <<'PY' | tee "$out/adoption.md"
import json, os, sys
out, model, data = sys.argv[1:4]
load = lambda *p: json.load(open(os.path.join(out, *p)))
print(f"# {model} on {data}\n")
cols = [("fid", "FID"), ("r_top3", "R top-3"), ("k_err", "K-Err"), ("k_trans", "K-TranS"),
        ("foot_skate", "foot skating"), ("planted", "planted"), ("penetrate", "penetrate (m)")]
def cell(row, k):
    m = row["metrics"].get(k)
    return "-" if m is None else f"{m['mean']:.4f} ± {m['ci95']:.4f}" if "ci95" in m else f"{m['mean']:.4f}"
print("| eval row | " + " | ".join(c for _, c in cols) + " |")
print("|---" * (len(cols) + 1) + "|")
for name in ("eval-default", "eval-raw"):
    seen_real = False
    for row in load(name, "report.json")["rows"]:
        if row["real"] and seen_real:
            continue
        seen_real |= row["real"]
        label = "real" if row["real"] else f"{name[5:]} @ {row['keyframe_rate'] * 100:g}%"
        print(f"| {label} | " + " | ".join(cell(row, k) for k, _ in cols) + " |")
print()
for n in (1, 4):
    w = load(f"raw-walks-{n}", "walks.json")
    print(f"Raw walks, {n} sample(s): speed {w['speed_ratio']:.2f} (smallest {w['speed_ratio_min']:.2f}), stride {w['stride_ratio']:.2f}")
print()
for n in (1, 4):
    print(f"Feet, {n} sample(s):\n")
    print(open(os.path.join(out, f"feet-walks-{n}", "feet.md")).read())
print("Text-only root: " + open(os.path.join(out, "text-only-root", "root.txt")).read().strip() + "\n")
print(open(os.path.join(out, "fixture-walks", "fixture-walks.md")).read())
PY
