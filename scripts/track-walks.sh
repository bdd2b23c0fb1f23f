#!/usr/bin/env bash
# The track fit on six keyed walks of the synthetic test split (README, "Keyframe fits"): each
# walk sampled from MODEL with 5% keyframes and its places (seed 1), and per walk the source's
# mean root speed, the first stage's track speed, the second stage's own root speed with that
# track observed (before any fit), its distance from the track, the largest place correction of
# the final motion, and foot skating of the final motion against the source's.
#   scripts/track-walks.sh MODEL DATA OUT [extra sample flags...]
set -euo pipefail
usage="usage: scripts/track-walks.sh MODEL DATA OUT [extra sample flags]"
source "$(dirname "$0")/args.sh"
need_args $# 3
model=$1 data=$2 out=$3
shift 3
need_path MODEL "$model"
need_data DATA "$data"
need_bin
mapfile -t walks < <(python3 - "$data/manifest.json" <<'PY'
import json, sys
clips = [c for c in json.load(open(sys.argv[1]))["clips"] if c["split"] == "test"]
acts = lambda c: [a["action"] for a in c["actions"]]
walks = [c["id"] for c in clips if any(a.startswith("walk") or a == "run" for a in acts(c)) and c["frames"] >= 80]
print("\n".join(walks[:6]))
PY
)
for w in "${walks[@]}"; do
  "$bin" sample --checkpoint "$model" --text "$(head -n 1 "$data/texts/$w.txt" | cut -d'#' -f1)" \
    --from "$data/new_joint_vecs/$w.npy" --keyframe-rate 0.05 --seed 1 --out "$out/$w" "$@" >/dev/null
done
python3 - "$out" "${walks[@]}" <<'PY'
import json, math, os, struct, sys
out, walks = sys.argv[1], sys.argv[2:]
def npy(path):
    raw = open(path, "rb").read()
    hl = struct.unpack("<H", raw[8:10])[0]
    header = raw[10:10 + hl].decode()
    shape = tuple(int(v) for v in header.split("(")[1].split(")")[0].split(",") if v.strip())
    vals = struct.unpack(f"<{math.prod(shape)}f", raw[10 + hl:])
    return shape, vals
def speed(path):  # mean ground speed of the root (joint 0) of joints [T, 22, 3], 20 fps
    (t, j, _), v = npy(path)
    p = [(v[f * j * 3], v[f * j * 3 + 2]) for f in range(t)]
    return sum(math.dist(p[f], p[f - 1]) for f in range(1, t)) * 20 / (t - 1)
print("| walk | text | source speed (m/s) | track speed | stage-2 root speed | ratio to source | stage-2 distance from track (m) | largest place correction (m) | foot skating | source foot skating |")
print("|---|---|---|---|---|---|---|---|---|---|")
for w in walks:
    r = json.load(open(os.path.join(out, w, "results.json")))
    s = r["samples"][0]
    src = speed(os.path.join(out, w, "source_joints.npy"))
    tr = s.get("track") or {}
    place = max([abs(c.get("place_m") or 0) for c in s["corrections"]] or [0])
    raw = tr.get("raw_speed_mps")
    f = lambda v: "-" if v is None else f"{v:.3f}"
    print(f"| {w} | {r['text']} | {src:.3f} | {f(tr.get('track_speed_mps'))} | {f(raw)} | {f(raw / src if raw else None)} | {f(tr.get('raw_distance_m'))} | {place:.3f} | {s['foot_skating']:.3f} | {r['real_foot_skating']:.3f} |")
PY
