#!/usr/bin/env bash
# Quality per CPU-hour: train CONFIG from scratch for a fixed budget, then print one panel of
# the numbers that tell a network that walks from one that shuffles (docs/reference-model.md).
#   scripts/design-panel.sh CONFIG OUT (--steps N | --budget 45m) [--data DIR] [--evaluator DIR]
#                           [--items 256] [--threads 2]
# --budget turns minutes into steps with this design's training step time, measured by
# `diffkfc bench` before training on this machine (so a slower design gets fewer steps); --steps
# fixes them (the study measures every design's step time side by side and passes --steps).
# The run's learning-rate schedule ends at those steps (a copy of CONFIG with
# training.max_steps set is written to OUT). Running it again resumes an unfinished training
# and redoes the evaluation. Fixed seeds, data and evaluator: two designs compare at equal cost.
#
# The panel (OUT/panel.json and OUT/panel.md):
#  - text-only FID and R-precision top-3 (default pipeline), keyed (5%) FID of the raw network
#    (no fit, no foot lock, no rigid refit): `diffkfc eval`, 1 x ITEMS test items;
#  - six keyed walks of the test split (forward walks of at least 120 frames, 5% keys with their
#    places, seed 2): the raw network's root speed and stride amplitude as ratios to the
#    source's, its planted share, and foot skating raw and after the default pipeline;
#  - the training rate: samples per second and the fraction of the measured matmul peak.
set -euo pipefail
usage="usage: scripts/design-panel.sh CONFIG OUT (--steps N | --budget 45m) [--data DIR] [--evaluator DIR] [--items 256]"
source "$(dirname "$0")/args.sh"
need_args $# 2
config=$1 out=$2
shift 2
work="${DIFFKFC_WORK:-work}"
data="$work/synth" evaluator="$work/evaluator" items=256 steps="" budget=""
while [ $# -gt 0 ]; do
  case "$1" in
    --steps) steps=$2; shift 2 ;;
    --budget) budget=$2; shift 2 ;;
    --data) data=$2; shift 2 ;;
    --evaluator) evaluator=$2; shift 2 ;;
    --items) items=$2; shift 2 ;;
    *) unknown_arg "$1" ;;
  esac
done
[ -n "$steps$budget" ] || die "give --steps N or --budget DURATION ($usage)"
need_path CONFIG "$config"
need_data --data "$data"
[ -d "$evaluator" ] || die "--evaluator $evaluator does not exist (diffkfc eval train-evaluator --data $data --out $evaluator --max-steps 800)"
need_bin
mkdir -p "$out"

# The training step's time and rate on this machine (batch of the config).
batch=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1])).get("training",{}).get("batch_size",64))' "$config")
"$bin" bench --config "$config" --cases train --batch "$batch" --repeats 5 >"$out/bench.jsonl"
if [ -z "$steps" ]; then
  steps=$(python3 - "$out/bench.jsonl" "$budget" <<'PY'
import json, re, sys
ms = [json.loads(l)["ms"] for l in open(sys.argv[1]) if json.loads(l).get("case") == "train_step"][0]
m = re.fullmatch(r"(\d+(?:\.\d+)?)(h|m|s)?", sys.argv[2])
if not m: sys.exit(f"error: --budget {sys.argv[2]} is not a duration like 45m, 1h or 900s")
secs = float(m[1]) * {"h": 3600, "m": 60, "s": 1, None: 1}[m[2]]
print(max(1, int(secs / (ms / 1000))))
PY
)
fi
python3 - "$config" "$out/config.json" "$steps" <<'PY'
import json, sys
c = json.load(open(sys.argv[1]))
c.setdefault("training", {})["max_steps"] = int(sys.argv[3])
json.dump(c, open(sys.argv[2] + ".tmp", "w"), indent=1)
PY
mv "$out/config.json.tmp" "$out/config.json"
echo "== $config: $steps steps (batch $batch) -> $out/run"
resume=()
ls "$out/run"/ckpt-*.safetensors >/dev/null 2>&1 && resume=(--resume)
"$bin" train --config "$out/config.json" --data "$data" --out "$out/run" "${resume[@]}"

# Text-only and keyed-raw tables.
common=(--checkpoint "$out/run" --evaluator "$evaluator" --data "$data" --num-items "$items" --replications 1 --samples-for-ade 1)
"$bin" eval "${common[@]}" --keyframe-rate 0 --out "$out/eval-text" >/dev/null
"$bin" eval "${common[@]}" --keyframe-rate 0.05 --keyframe-fit none --no-foot-lock --no-rigid --out "$out/eval-keyed-raw" >/dev/null

# The six keyed walks, raw and through the default pipeline.
mapfile -t walks < <("$bin" data clips "$data" --split test --action walk_forward --min-frames 120 --count 6)
for w in "${walks[@]}"; do
  text=$(head -n 1 "$data/texts/$w.txt" | cut -d'#' -f1)
  for mode in raw default; do
    flags=()
    [ "$mode" = raw ] && flags=(--keyframe-fit none --no-foot-lock --no-rigid)
    "$bin" sample --checkpoint "$out/run" --text "$text" --from "$data/new_joint_vecs/$w.npy" \
      --keyframe-rate 0.05 --seed 2 --out "$out/walks/$mode/$w" --force "${flags[@]}" >/dev/null
  done
done

python3 - "$out" "$config" "$steps" "$batch" "${walks[@]}" <<'PY'
import json, os, statistics, sys
out, config, steps, batch, walks = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5:]
bench = [json.loads(l) for l in open(os.path.join(out, "bench.jsonl"))]
machine = next((b for b in bench if "matmul_peak_gflops" in b), {})
train = next(b for b in bench if b.get("case") == "train_step")
def pick(path, name, real):
    for r in json.load(open(os.path.join(out, path, "report.json")))["rows"]:
        if r["real"] == real:
            return r["metrics"][name]["mean"]
    raise SystemExit(f"no {'real' if real else 'generated'} row in {path}/report.json")
row = lambda path, name: pick(path, name, False)
real = lambda path, name: pick(path, name, True)
per = []
for w in walks:
    raw = json.load(open(os.path.join(out, "walks", "raw", w, "results.json")))
    dft = json.load(open(os.path.join(out, "walks", "default", w, "results.json")))
    g, src = raw["samples"][0]["gait"], raw["real_gait"]
    per.append({"walk": w, "speed_ratio": g["root_speed_mps"] / src["root_speed_mps"],
                "stride_ratio": g["stride_amplitude_m"] / src["stride_amplitude_m"],
                "planted_raw": g["planted_share"], "planted_default": dft["samples"][0]["gait"]["planted_share"],
                "planted_source": src["planted_share"],
                "skate_raw": raw["samples"][0]["foot_skating"], "skate_default": dft["samples"][0]["foot_skating"],
                "skate_source": raw["real_foot_skating"]})
mean = lambda k: statistics.fmean(p[k] for p in per)
metrics = [json.loads(l) for l in open(os.path.join(out, "run", "metrics.jsonl"))]
val = [m["val_loss"] for m in metrics if m.get("val_loss") is not None]
panel = {
    "config": config, "steps": steps, "batch": batch,
    "machine": {"cpu": machine.get("cpu"), "flags": " ".join(k for k in ("avx2", "fma", "avx512f") if machine.get(k)),
                "threads": machine.get("threads"), "matmul_peak_gflops": machine.get("matmul_peak_gflops")},
    "step_ms": train["ms"], "samples_per_s": batch / (train["ms"] / 1000), "fraction_of_peak": train.get("fraction_of_peak"),
    "fraction_of_adjacent_peak": train.get("fraction_of_adjacent_peak"),
    "val_loss": val[-1] if val else None,
    "text_fid": row("eval-text", "fid"), "text_r_top3": row("eval-text", "r_top3"),
    "real_fid": real("eval-text", "fid"), "real_r_top3": real("eval-text", "r_top3"),
    "keyed_raw_fid": row("eval-keyed-raw", "fid"), "keyed_raw_foot_skate": row("eval-keyed-raw", "foot_skate"),
    "walks_speed_ratio": mean("speed_ratio"), "walks_speed_ratio_min": min(p["speed_ratio"] for p in per),
    "walks_stride_ratio": mean("stride_ratio"), "walks_planted_raw": mean("planted_raw"),
    "walks_planted_default": mean("planted_default"), "walks_planted_source": mean("planted_source"),
    "walks_skate_raw": mean("skate_raw"), "walks_skate_default": mean("skate_default"),
    "walks_skate_source": mean("skate_source"), "walks": per,
}
json.dump(panel, open(os.path.join(out, "panel.json"), "w"), indent=1)
f = lambda v, p=3: "-" if v is None else f"{v:.{p}f}"
lines = [
    f"## {config}: {steps} steps at batch {batch}",
    f"machine: {panel['machine']['cpu']} ({panel['machine']['flags']}), {panel['machine']['threads']} threads, matmul peak {f(panel['machine']['matmul_peak_gflops'], 0)} GFLOP/s",
    "",
    "| step (ms) | samples/s | of peak (of the peaks beside the steps) | val loss | text FID | R top-3 | keyed raw FID | speed ratio (min) | stride ratio | planted raw / default / source | skating raw / default / source |",
    "|---|---|---|---|---|---|---|---|---|---|---|",
    f"| {f(panel['step_ms'], 0)} | {f(panel['samples_per_s'], 1)} | {f(panel['fraction_of_peak'], 2)} ({f(panel['fraction_of_adjacent_peak'], 2)}) | {f(panel['val_loss'])} | {f(panel['text_fid'])} | {f(panel['text_r_top3'])} | {f(panel['keyed_raw_fid'])} | "
    f"{f(panel['walks_speed_ratio'], 2)} ({f(panel['walks_speed_ratio_min'], 2)}) | {f(panel['walks_stride_ratio'], 2)} | "
    f"{f(panel['walks_planted_raw'], 2)} / {f(panel['walks_planted_default'], 2)} / {f(panel['walks_planted_source'], 2)} | "
    f"{f(panel['walks_skate_raw'])} / {f(panel['walks_skate_default'])} / {f(panel['walks_skate_source'])} |",
    "",
    f"real motion (same items): FID {f(panel['real_fid'])}, R top-3 {f(panel['real_r_top3'])}; walks: {', '.join(walks)}",
]
open(os.path.join(out, "panel.md"), "w").write("\n".join(lines) + "\n")
print("\n".join(lines))
PY
