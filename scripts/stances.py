#!/usr/bin/env python3
"""Where a sample's feet stand against its source's footprints (README's quick-start walk,
docs/feet.md). A stance is a run of planted frames of one toe: within 5 cm of the motion's
floor (its lowest toe height) and slower than 0.15 m/s horizontally, as the eval crate's
planted share counts them. Each of the sample's stances is placed at its toe's mean floor
position and compared with the nearest stance of the same toe in the source. Needs numpy.

    scripts/stances.py SAMPLE_JOINTS.npy SOURCE_JOINTS.npy [--within M] [--min-frames N]

JOINTS.npy: joint positions (T, 22, 3) in metres at 20 fps (a sample's sample_00_joints.npy
and source_joints.npy). Prints, per toe, how many stances stand within M metres (default 0.04)
of a source stance, and how far the others are."""
import sys

import numpy as np

FPS, LOW, SLOW = 20.0, 0.05, 0.15
TOES = {"left": 10, "right": 11}
USAGE = "usage: scripts/stances.py SAMPLE_JOINTS.npy SOURCE_JOINTS.npy [--within M] [--min-frames N]"


def die(msg):
    print(f"error: {msg}", file=sys.stderr)
    sys.exit(2)


def stances(joints, toe, min_frames):
    """Mean floor positions (x, z) of the runs of planted frames of one toe."""
    floor = joints[:, [10, 11], 1].min()
    p = joints[:, toe]
    v = np.zeros(len(p))
    v[1:] = np.linalg.norm(np.diff(p[:, [0, 2]], axis=0), axis=1) * FPS
    v[0] = v[1]
    planted = (p[:, 1] - floor < LOW) & (v < SLOW)
    runs, start = [], None
    for f, on in enumerate(list(planted) + [False]):
        if on and start is None:
            start = f
        elif not on and start is not None:
            if f - start >= min_frames:
                runs.append(p[start:f][:, [0, 2]].mean(axis=0))
            start = None
    return np.array(runs).reshape(-1, 2)


def load(path):
    try:
        j = np.load(path)
    except (OSError, ValueError) as e:
        die(f"{path}: {e}")
    if j.ndim != 3 or j.shape[1:] != (22, 3) or len(j) < 2:
        die(f"{path}: joints of shape {j.shape}, expected (T >= 2, 22, 3)")
    return j


def main(argv):
    args, within, min_frames = [], 0.04, 1
    it = iter(argv)
    for a in it:
        try:
            if a == "--within":
                within = float(next(it))
            elif a == "--min-frames":
                min_frames = int(next(it))
            elif a.startswith("-"):
                die(f"unknown argument '{a}' ({USAGE})")
            else:
                args.append(a)
        except (StopIteration, ValueError):
            die(f"{a} needs a number ({USAGE})")
    if len(args) != 2:
        print(USAGE, file=sys.stderr)
        sys.exit(2)
    if not within > 0 or min_frames < 1:
        die(f"--within {within} / --min-frames {min_frames}: expected M > 0 and N >= 1")
    sample, source = (load(a) for a in args)
    for name, toe in sorted(TOES.items(), reverse=True):
        mine, theirs = stances(sample, toe, min_frames), stances(source, toe, min_frames)
        if len(mine) == 0 or len(theirs) == 0:
            print(f"{name}: {len(mine)} stances, source {len(theirs)}")
            continue
        off = np.linalg.norm(mine[:, None] - theirs[None], axis=2).min(axis=1)
        near = int((off <= within).sum())
        far = ", ".join(f"{d:.2f}" for d in sorted(off[off > within]))
        print(
            f"{name}: {near} of {len(mine)} stances within {within:.2f} m of the source's "
            f"{len(theirs)}" + (f"; the others {far} m off" if far else "")
        )


if __name__ == "__main__":
    main(sys.argv[1:])
