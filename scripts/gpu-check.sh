#!/usr/bin/env bash
# The GPU path end to end, in one command; run it first on any machine with a GPU.
#   scripts/gpu-check.sh [wgpu|cuda] [--quick] [--torch PYTHON] [--json FILE] [--features LIST]
# Builds the feature, runs the backend-parity test against flex (forward, training-step
# gradients, Adam with its state on the device, a guided sample), trains on the device with
# validation loss (the small config for 500 steps; --quick: a one-layer tiny config for 30),
# resumes that run on flex and a flex run on the device (the next steps must agree), samples the
# reference model on the device and on flex, and runs one bench case (the paper config side by
# side with PyTorch when --torch is given). Prints one table and writes it as JSON.
# Without a GPU, wgpu runs on Mesa's lavapipe (software Vulkan): apt-get install
# mesa-vulkan-drivers and VK_ICD_FILENAMES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json.
set -euo pipefail
cd "$(dirname "$0")/.."
dev="${1:-wgpu}"
case "$dev" in wgpu|cuda) shift || true ;; -*) dev=wgpu ;; *) echo "error: device '$dev': wgpu or cuda" >&2; exit 2 ;; esac
quick=0; torch=""; json=""; extra=""
while [ $# -gt 0 ]; do
  case "$1" in
    --quick) quick=1; shift ;;
    --torch) torch="$2"; shift 2 ;;
    --json) json="$2"; shift 2 ;;
    # More cargo features for the same build (CI adds diffkfc/ndarray so that backend's parity
    # test reuses this build instead of compiling the Burn stack once more).
    --features) extra="$2"; shift 2 ;;
    *) echo "error: unknown argument '$1' (usage: scripts/gpu-check.sh [wgpu|cuda] [--quick] [--torch PYTHON] [--json FILE] [--features LIST])" >&2; exit 2 ;;
  esac
done
work="${DIFFKFC_WORK:-work}/gpu-check-$dev"
json="${json:-$work/gpu-check.json}"
# --quick builds with the gpu-quick profile (Cargo.toml: optimisation level 1), which shortens
# the GPU stack's build; its timings are not meant to be read.
profile=release; [ "$quick" = 1 ] && profile=gpu-quick
bin="${CARGO_TARGET_DIR:-target}/$profile/diffkfc"
mkdir -p "$work"
# Vulkan's loader warns on every start without one (headless machines, CI).
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
log() { echo "== $*"; }
now() { date +%s.%N; }

# One feature resolution for the binary and the parity test (an integration test of the cli
# builds the binary), so the GPU stack compiles once.
build=(cargo test --profile "$profile" -p diffkfc-model -p diffkfc --features "diffkfc/$dev${extra:+,$extra}" --test backend_parity)
log "build --features $dev"
t0=$(now)
"${build[@]}" --test cli_model --no-run
build_s=$(python3 -c "print(round($(now) - $t0, 1))")
# A copy: a later build of other features in the same target folder replaces the binary.
cp "$bin" "$work/diffkfc-$dev"
bin="$work/diffkfc-$dev"

log "backend parity: flex against $dev"
"${build[@]}" -- "$dev" --nocapture 2>&1 | tee "$work/parity.log" || true  # judged by the report

log "data"
clips=3000; [ "$quick" = 1 ] && clips=200
[ -f "$work/synth/manifest.json" ] || "$bin" data synth --out "$work/synth" --clips "$clips"

if [ "$quick" = 1 ]; then
  # A one-layer tiny network on 64-frame crops: small enough for a software driver.
  steps=30; half=15
  cat > "$work/train.json" <<'JSON'
{"model": {"preset": "tiny", "dec_layers": 1, "dma_sizes": [2, 0], "max_frames": 64},
 "training": {"batch_size": 4, "lr": 0.001, "max_steps": 30, "warmup_steps": 2, "checkpoint_every": 15,
              "keep_checkpoints": 3, "val_every": 15, "val_batches": 1, "log_every": 1, "seed": 0}}
JSON
else
  steps=500; half=250
  python3 - "$work/train.json" <<'PY'
import json, sys
c = json.load(open("configs/small.json"))
t = c.setdefault("training", {})
t.update(max_steps=500, checkpoint_every=250, val_every=100, log_every=10, keep_checkpoints=3)
json.dump(c, open(sys.argv[1], "w"))
PY
fi

log "train on $dev ($steps steps)"
rm -rf "$work/run-$dev" "$work/run-flex"
"$bin" train --config "$work/train.json" --data "$work/synth" --out "$work/run-$dev" --device "$dev" --max-steps "$steps"

log "resume across backends: $dev's step $half continued on flex and on $dev; flex's continued on $dev"
"$bin" train --config "$work/train.json" --data "$work/synth" --out "$work/run-flex" --device flex --max-steps "$half"
for pair in "$dev:flex" "$dev:$dev" "flex:$dev" "flex:flex"; do
  from=${pair%%:*}; on=${pair##*:}
  dir="$work/resume-$from-on-$on"
  rm -rf "$dir"; mkdir -p "$dir"
  # The run as it stood at step $half: its config, normalisation and that checkpoint.
  find "$work/run-$from" -maxdepth 1 -type f ! -name 'ckpt-*' ! -name metrics.jsonl ! -name '*.lock' -exec cp {} "$dir/" \;
  cp "$work/run-$from/ckpt-$(printf %08d "$half").safetensors" "$dir/"
  python3 - "$work/run-$from/metrics.jsonl" "$dir/metrics.jsonl" "$half" <<'PY'
import json, sys
rows = [l for l in open(sys.argv[1]) if json.loads(l).get("step", 0) <= int(sys.argv[3])]
open(sys.argv[2], "w").writelines(rows)
PY
  "$bin" train --config "$work/train.json" --data "$work/synth" --out "$dir" --device "$on" --resume --max-steps $((half + 2))
done

log "sample the reference model on $dev and on flex (keyframe guidance 2.5, DPM-10, no fit)"
for d in "$dev" flex; do
  "$bin" sample --checkpoint models/mid-synth --text "a person walks forward." --from "$work/synth/new_joint_vecs/000001.npy" \
    --frames 0,30,59 --length 60 --kf-guidance 2.5 --keyframe-fit none --no-foot-lock --no-rigid --device "$d" --out "$work/sample-$d" --force
done

log "bench on $dev"
"$bin" bench --device "$dev" --config tiny --cases call --quick | tee "$work/bench.jsonl"
if [ -n "$torch" ]; then
  "$bin" bench --device "$dev" --config paper --cases train,call --torch "$torch" --rounds 3 | tee -a "$work/bench.jsonl"
fi

python3 scripts/gpu_check_report.py "$dev" "$work" "$steps" "$half" "$build_s" "$json"
