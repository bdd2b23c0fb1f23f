#!/usr/bin/env bash
# SIGTERM at a random moment of a training, N times: each trial must exit 143 with a checkpoint
# no older than one checkpoint interval, and resume exactly (the resumed run logs the same loss
# at every step as an uninterrupted run of the same length).
# Usage: scripts/sigterm-trials.sh [TRIALS] [WORK]   (builds nothing: uses target/release/diffkfc)
set -euo pipefail
trials=${1:-10}
work=${2:-$(mktemp -d)}
bin=${DIFFKFC_BIN:-target/release/diffkfc}
mkdir -p "$work"
[ -d "$work/synth" ] || "$bin" data synth --out "$work/synth" --clips 40 --seed 9 >/dev/null
cat > "$work/cfg.json" <<'JSON'
{"model": {"preset": "tiny", "dec_layers": 1, "dma_sizes": [2, 0]},
 "training": {"batch_size": 4, "max_steps": 300, "checkpoint_every": 2, "keep_checkpoints": 2,
              "val_every": 0, "log_every": 1}}
JSON
loss_at() { python3 -c "import json,sys; [print(d['step'], d['loss']) for d in map(json.loads, open(sys.argv[1])) if 'loss' in d]" "$1"; }
rm -rf "$work/ref"
"$bin" train --config "$work/cfg.json" --data "$work/synth" --out "$work/ref" --max-steps 300 >/dev/null
loss_at "$work/ref/metrics.jsonl" > "$work/ref.txt"
ok=0
for t in $(seq 1 "$trials"); do
  run="$work/t$t"; rm -rf "$run"
  "$bin" train --config "$work/cfg.json" --data "$work/synth" --out "$run" --max-steps 300 >/dev/null 2>"$run.err" &
  pid=$!
  # A random moment between 1 and 8 s after the start (loading included).
  sleep "$(python3 -c "import random; print(round(random.uniform(1, 8), 2))")"
  kill -TERM "$pid" 2>/dev/null || true
  set +e; wait "$pid"; code=$?; set -e
  last_logged=$( (loss_at "$run/metrics.jsonl" 2>/dev/null || true) | tail -1 | cut -d' ' -f1)
  newest=$( (ls "$run" 2>/dev/null || true) | sed -n 's/^ckpt-0*\([0-9]*\)\.safetensors$/\1/p' | sort -n | tail -1)
  # Stopped before its first step (while loading): nothing to resume, a new run starts.
  resume=--resume; [ -n "$newest" ] || resume=""
  "$bin" train --config "$work/cfg.json" --data "$work/synth" --out "$run" $resume --max-steps 300 >/dev/null
  loss_at "$run/metrics.jsonl" > "$run.txt"
  same=$(cmp -s "$run.txt" "$work/ref.txt" && echo yes || echo no)
  echo "trial $t: exit $code, last logged step ${last_logged:-none}, newest checkpoint ${newest:-none}, resumed log equals uninterrupted: $same"
  if [ "$code" = 143 ] && [ "$same" = yes ] && [ "${newest:-0}" -ge "${last_logged:-0}" ]; then ok=$((ok + 1)); fi
done
echo "$ok of $trials trials: exit 143, checkpoint within one interval, exact resume"
