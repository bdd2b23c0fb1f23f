#!/usr/bin/env python3
"""The table of scripts/gpu-check.sh: reads what its steps wrote, checks each number against its
bound, prints one table, writes it as JSON and exits 1 when a check fails."""
import json, re, sys

import numpy as np

dev, work, steps, half, build_s, out = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5]), sys.argv[6]
rows = []


def row(check, value, bound=None, ok=None, unit=""):
    if ok is None and bound is not None and value is not None:
        ok = value <= bound
    rows.append(dict(check=check, value=value, bound=bound, ok=ok, unit=unit))


def metrics(path):
    return [json.loads(l) for l in open(path) if l.strip()]


def grab(pattern, text):
    m = re.search(pattern, text)
    return float(m.group(1)) if m else None


parity = open(f"{work}/parity.log").read()
row("parity test passed", 1.0 if "test result: ok. 1 passed" in parity else 0.0, ok="test result: ok. 1 passed" in parity)
row("forward, relative difference to flex", grab(r"forward: relative difference ([0-9.e+-]+)", parity), 1e-4)
row("training-step gradients, relative difference", grab(r"gradients differ by ([0-9.e+-]+)", parity), 1e-4)
row("weights after one Adam step, relative difference", grab(r"weights after Adam by ([0-9.e+-]+)", parity), 1e-4)
row("device-state Adam against flex's", grab(r"from flex's by ([0-9.e+-]+)", parity), 1e-4)
row("guided DDIM-5 sample, relative difference", grab(r"DDIM-5 sample: relative difference ([0-9.e+-]+)", parity), 1e-3)

m = metrics(f"{work}/run-{dev}/metrics.jsonl")
train = [r for r in m if "loss" in r]
val = [r for r in m if "val_loss" in r]
# A quarter of the logged steps on each side: single steps of a small batch are noisy.
k = max(1, len(train) // 4)
first, last = np.mean([r["loss"] for r in train[:k]]), np.mean([r["loss"] for r in train[-k:]])
row(f"training loss, mean of the first {k} logged steps", float(first))
row(f"training loss, mean of the last {k} logged steps", float(last), ok=bool(last < first))
if len(val) >= 2:
    row("validation loss, first -> last", float(val[-1]["val_loss"]), ok=bool(val[-1]["val_loss"] < val[0]["val_loss"]))
    rows[-1]["first"] = val[0]["val_loss"]
secs = (train[-1]["wall_s"] - train[0]["wall_s"]) / max(1, train[-1]["step"] - train[0]["step"])
row(f"seconds per training step on {dev}", round(secs, 3), unit="s")


def resumed(frm, on):
    """Loss and gradient norm of the two steps after the resumed checkpoint."""
    rs = {r["step"]: r for r in metrics(f"{work}/resume-{frm}-on-{on}/metrics.jsonl") if "loss" in r}
    return [rs[s][k] if s in rs else None for s in (half + 1, half + 2) for k in ("loss", "grad_norm")]


for frm in (dev, "flex"):
    a, b = resumed(frm, "flex"), resumed(frm, dev)
    if None in a or None in b:
        row(f"{frm}'s checkpoint resumed on flex and on {dev}", None, ok=False)
        continue
    d = max(abs(x - y) / abs(y) for x, y in zip(a, b))
    row(f"{frm}'s step-{half} checkpoint on flex vs {dev}: next 2 steps' loss, grad norm (rel.)", d, 1e-3)

x = np.load(f"{work}/sample-{dev}/sample_00.npy")
y = np.load(f"{work}/sample-flex/sample_00.npy")
row("reference model's guided DPM-10 sample, largest feature difference", float(np.abs(x - y).max()), 1e-3)

bench = [json.loads(l) for l in open(f"{work}/bench.jsonl") if l.startswith("{")]
call = [b for b in bench if b.get("case") == "call"]
if call:
    row(f"bench: tiny guided call on {dev} (not a target)", call[0].get("ms", call[0].get("median_ms")), unit="ms")

print(f"\ngpu-check {dev} ({'quick' if steps <= 50 else 'full'}; build {build_s:.0f} s)")
print(f"{'check':<78} {'value':>12} {'bound':>9}  result")
for r in rows:
    v = "-" if r["value"] is None else (f"{r['value']:.3e}" if isinstance(r["value"], float) and abs(r["value"]) < 1e-2 and r["value"] != 0 else f"{r['value']:.4g}")
    b = "" if r["bound"] is None else f"{r['bound']:.0e}"
    res = "" if r["ok"] is None else ("ok" if r["ok"] else "FAILED")
    print(f"{r['check']:<78} {v:>12} {b:>9}  {res}")
json.dump(dict(device=dev, steps=steps, build_s=build_s, checks=rows), open(out, "w"), indent=1)
print(f"written: {out}")
sys.exit(0 if all(r["ok"] is not False for r in rows) else 1)
