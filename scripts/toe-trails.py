#!/usr/bin/env python3
"""Toes seen from above, for looking at foot planting (docs/feet.md): each toe's path, a dot
where it is on the floor (below 5 cm) and still, an x where it is on the floor and sliding
faster than 0.5 m/s (the foot skating measure's test). Needs numpy and matplotlib.

    scripts/toe-trails.py OUT.png LABEL=JOINTS.npy [LABEL=JOINTS.npy ...]

JOINTS.npy: joint positions (T, 22, 3) in metres at 20 fps (a sample's sample_00_joints.npy
or source_joints.npy)."""
import sys

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

if len(sys.argv) < 3 or any("=" not in a for a in sys.argv[2:]):
    sys.exit(__doc__)
out, panels = sys.argv[1], [a.split("=", 1) for a in sys.argv[2:]]
fig, axs = plt.subplots(1, len(panels), figsize=(4 * len(panels), 4.2), sharey=True, squeeze=False)
for ax, (label, path) in zip(axs[0], panels):
    j = np.load(path)
    for toe, colour in [(10, "tab:blue"), (11, "tab:red")]:
        p = j[:, toe]
        low = p[:, 1] < 0.05
        speed = np.r_[0, np.linalg.norm(np.diff(p[:, [0, 2]], axis=0), axis=1) * 20]
        ax.plot(p[:, 0], p[:, 2], "-", color=colour, lw=0.6, alpha=0.5)
        ax.scatter(p[low & (speed <= 0.5), 0], p[low & (speed <= 0.5), 2], s=6, color=colour)
        ax.scatter(p[low & (speed > 0.5), 0], p[low & (speed > 0.5), 2], s=14, marker="x", color="k")
    ax.set_title(label)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
axs[0][0].set_ylabel("z (m)")
fig.suptitle("toes from above: dots on the floor and still, x on the floor and sliding (> 0.5 m/s)")
plt.tight_layout()
plt.savefig(out, dpi=70)
