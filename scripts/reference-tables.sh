#!/usr/bin/env bash
# The reference model's tables of README ("Reference model"): the paper's Table 2 (methods at
# 5% keyframes) and Table 4 (keyframe rates), a guidance sweep and quality against sampling
# steps, each row an `diffkfc eval` report under OUT, then one markdown summary.
#   scripts/reference-tables.sh MODEL EVALUATOR DATA OUT [--items 256] [--reps 3] [--ade 1]
set -euo pipefail
usage="usage: scripts/reference-tables.sh MODEL EVALUATOR DATA OUT [--items N] [--reps N] [--ade N]"
source "$(dirname "$0")/args.sh"
need_args $# 4
model=$1 evaluator=$2 data=$3 out=$4
shift 4
items=256 reps=3 ade=1
while [ $# -gt 0 ]; do
  case "$1" in
    --items) items=$2; shift 2 ;;
    --reps) reps=$2; shift 2 ;;
    --ade) ade=$2; shift 2 ;;
    *) unknown_arg "$1" ;;
  esac
done
need_path MODEL "$model"
need_path EVALUATOR "$evaluator"
need_data DATA "$data"
need_bin
ev() { # name, then eval flags
  local name=$1; shift
  if [ -f "$out/$name/report.json" ]; then echo "present: $out/$name" >&2; return; fi
  local t0; t0=$(date +%s)
  "$bin" eval --checkpoint "$model" --evaluator "$evaluator" --data "$data" --out "$out/$name" "$@" >/dev/null
  echo "done: $name ($(( $(date +%s) - t0 )) s)" >&2
}
# Table 2 and Table 4 in one run: defaults (DPM-Solver++(2M)-10, s = 1, r = 10, warp, foot lock) at 5%,
# the same without transition guidance, MDM-inp, and the defaults at 0, 2 and 10%.
ev tables --num-items "$items" --replications "$reps" --samples-for-ade "$ade" --compare --sweep-rates 0,0.02,0.05,0.1
# Guidance: transition guidance strengths and the paper's keyframe guidance scale against the
# default on the same items (half the tables' items, one replication).
half=$(( items / 2 )); [ "$half" -lt 32 ] && half=32
ev s1-r10-half --num-items "$half" --replications 1 --samples-for-ade "$ade"
for r in 0 30 100; do
  ev s1-r$r-half --num-items "$half" --replications 1 --samples-for-ade "$ade" --transition-guidance $r
done
ev s2.5-r0 --num-items "$half" --replications 1 --samples-for-ade "$ade" --kf-guidance 2.5 --transition-guidance 0
ev s2.5-r100 --num-items "$half" --replications 1 --samples-for-ade "$ade" --kf-guidance 2.5 --transition-guidance 100
# Post-processing: the defaults without foot locking, and without any fit (one replication).
ev fit-default --num-items "$items" --replications 1 --samples-for-ade "$ade"
ev no-foot-lock --num-items "$items" --replications 1 --samples-for-ade "$ade" --no-foot-lock
ev fit-none --num-items "$items" --replications 1 --samples-for-ade "$ade" --keyframe-fit none --no-foot-lock
# Quality against denoiser calls: DDIM 5, 10, 20, 50 and DPM-Solver++(2M) 5, 8, 10 (the
# default) on the tables' items and replications; DDPM-1000 and its default twin on 32 items.
for k in 5 10 20 50; do
  ev ddim$k --num-items "$items" --replications "$reps" --samples-for-ade "$ade" --sampler ddim --steps $k
done
for k in 5 8 10; do
  ev dpm$k --num-items "$items" --replications "$reps" --samples-for-ade "$ade" --sampler dpm --steps $k
done
few=32 # DDPM runs all 1000 steps: about 4 s per motion here
ev ddpm1000-32 --num-items "$few" --replications 1 --samples-for-ade 1 --sampler ddpm
ev dpm10-32 --num-items "$few" --replications 1 --samples-for-ade 1
python3 - "$out" <<'PY'
import json, os, sys
out = sys.argv[1]
cols = [("fid", "FID"), ("r_top3", "R top-3"), ("ade", "ADE"), ("k_err", "K-Err"), ("k_err_local", "K-Err root-rel."),
        ("k_trans", "K-TranS"), ("foot_skate", "foot skate")]
def report(name):
    p = os.path.join(out, name, "report.json")
    return json.load(open(p)) if os.path.exists(p) else None
def cell(row, k):
    m = row["metrics"].get(k)
    p = 4 if k in ("k_err", "k_err_local", "k_trans") else 3  # K-TranS and K-Err are small
    return "-" if m is None else f"{m['mean']:.{p}f} ± {m['ci95']:.{p}f}" if "ci95" in m else f"{m['mean']:.{p}f}"
def table(rows, label):
    print("| " + label + " | " + " | ".join(c[1] for c in cols) + " | s per item |")
    print("|---" * (len(cols) + 2) + "|")
    for title, row, secs in rows:
        print(f"| {title} | " + " | ".join(cell(row, k) for k, _ in cols) + f" | {secs} |")
    print()
r = report("tables")
if r:
    meta = r["meta"]
    n = meta["num_items"] * meta["replications"]
    print(f"Tables 2 and 4: {meta['replications']} x {meta['num_items']} items, {meta['sampler']}, ADE over {meta['samples_for_ade']} sample(s), {meta['seconds']:.0f} s\n")
    rows, real_seen = [], False
    for row in r["rows"]:
        if row["real"]:
            # One real row per keyframe rate (only K-TranS differs): the 5% one is shown.
            if real_seen or abs(row["keyframe_rate"] - 0.05) > 1e-9:
                continue
            real_seen = True
        title = f"Real motion ({n} items)" if row["real"] else f"{row['name']} @ {row['keyframe_rate'] * 100:g}%"
        rows.append((title, row, "-"))
    table(rows, "row")
def section(title, label, runs, timed=False):
    """One table of single-setting reports: (report name, row label) pairs, in order."""
    rows = []
    for name, text in runs:
        rr = report(name)
        if rr:
            gen = next(x for x in rr["rows"] if not x["real"])
            n = rr["meta"]["num_items"] * rr["meta"]["replications"] * max(1, rr["meta"]["samples_for_ade"])
            rows.append((text, gen, f"{rr['meta']['seconds'] / n:.3f}" if timed else "-"))
    if rows:
        print(title + "\n")
        table(rows, label)
section("Quality against denoiser calls (s = 1, r = 10, warp, foot lock, 5% keyframes; calls = steps):", "sampler",
        [("ddim5", "DDIM-5"), ("dpm5", "DPM-Solver++(2M)-5"), ("dpm8", "DPM-Solver++(2M)-8"), ("ddim10", "DDIM-10"), ("dpm10", "DPM-Solver++(2M)-10 (default)"),
         ("ddim20", "DDIM-20"), ("ddim50", "DDIM-50"), ("dpm10-32", "DPM-Solver++(2M)-10 (32 items)"), ("ddpm1000-32", "DDPM-1000 (32 items)")], timed=True)
section("Keyframe guidance s and transition guidance r (DPM-10, 5% keyframes, warp, foot lock):", "guidance",
        [("s1-r10-half", "s = 1, r = 10 (default)"), ("s1-r0-half", "s = 1, r = 0"), ("s1-r30-half", "s = 1, r = 30"), ("s1-r100-half", "s = 1, r = 100"), ("s2.5-r0", "s = 2.5, r = 0"), ("s2.5-r100", "s = 2.5, r = 100 (paper)")])
section("After the last step (DPM-10, 5% keyframes; one replication):", "fit",
        [("fit-default", "warp + foot lock (default)"), ("no-foot-lock", "warp"), ("fit-none", "none (the network's output)")])
PY
