#!/usr/bin/env python3
"""Legs seen from the side, for looking at steps (docs/feet.md): one panel per motion, every
second frame of FIRST..LAST drawn in the plane of the pelvis's travel (later frames darker;
left leg blue, right red, spine grey), with a dot where a toe is on the floor (below 5 cm).
A planted foot shows as dots stacked at one place; a gliding one as a trail of dots. Needs
numpy and matplotlib.

    scripts/leg-strobe.py OUT.png FIRST LAST LABEL=JOINTS.npy [LABEL=JOINTS.npy ...]

JOINTS.npy: joint positions (T, 22, 3) in metres at 20 fps (a sample's sample_00_joints.npy
or source_joints.npy)."""
import sys

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

if len(sys.argv) < 5 or any("=" not in a for a in sys.argv[4:]):
    sys.exit(__doc__)
out, first, last = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
panels = [a.split("=", 1) for a in sys.argv[4:]]
chains = [([0, 1, 4, 7, 10], "tab:blue"), ([0, 2, 5, 8, 11], "tab:red"), ([0, 3, 6, 9, 12, 15], "gray")]
fig, axs = plt.subplots(len(panels), 1, figsize=(12, 2.4 * len(panels)), sharex=True, squeeze=False)
for ax, (label, path) in zip(axs[:, 0], panels):
    j = np.load(path)
    if not 0 <= first < last < len(j):
        sys.exit(f"error: frames {first}..{last} outside {path}'s {len(j)} frames")
    d = j[last, 0, [0, 2]] - j[first, 0, [0, 2]]
    d = d / max(np.linalg.norm(d), 1e-9)
    for f in range(first, last + 1, 2):
        alpha = 0.2 + 0.7 * (f - first) / (last - first)
        for chain, colour in chains:
            ax.plot(j[f][chain][:, [0, 2]] @ d, j[f][chain][:, 1], color=colour, alpha=alpha, lw=1)
        for toe, colour in [(10, "tab:blue"), (11, "tab:red")]:
            if j[f, toe, 1] < 0.05:
                ax.plot(j[f, toe, [0, 2]] @ d, j[f, toe, 1], "o", color=colour, ms=3)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_aspect("equal")
    ax.set_title(f"{label}: frames {first}-{last}, every 2nd; dots: a toe below 5 cm", fontsize=9)
axs[-1, 0].set_xlabel("metres along the pelvis's travel")
plt.tight_layout()
plt.savefig(out, dpi=72)
print(f"wrote {out}")
