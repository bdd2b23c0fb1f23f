#!/usr/bin/env python3
"""The real dev set: motion capture the models never trained on, for evaluation only.

Writes a HumanML3D-format folder (new_joint_vecs/, new_joints/, texts/, test.txt, Mean.npy,
Std.npy) of
* the DeepMimic clips inside PyPI's pybullet wheel (pybullet_data/data/motions/humanoid3d_*.txt
  and walker/*.txt; zlib licence), fetched at run time with `pip download` and turned into joint
  positions by the forward kinematics of pybullet_data/humanoid/humanoid.urdf (as DeepMimic
  loads it, scaled by 0.25), mapped onto HumanML3D's 22 joints, resampled to 20 fps and
  converted to features by `diffkfc data features` (HumanML3D's processing). Cyclic clips
  ("Loop": "wrap") are played on, each cycle continuing from where the last one ended, to 7.5 s.
* the two real HumanML3D clips of the shared fixtures (012314, and 000021 through HumanML3D's
  own processing).
The captions are ours. Never train on this folder, and never commit it or anything derived from
it: it is for `diffkfc eval inbetween --data DIR`.

  scripts/devset.py OUT [--bin target/release/diffkfc] [--fixtures ../shared/fixtures]
                        [--stats models/mid-synth] [--cache ~/.cache/diffkfc/pybullet]
  scripts/devset.py --check OUT      bones rigid in every clip's forward kinematics
"""
import argparse
import glob
import json
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile

import numpy as np

PYBULLET = "pybullet==3.2.7"
SCALE = 0.25  # DeepMimic loads humanoid.urdf with globalScaling 0.25
FPS = 20.0
CYCLE_SECONDS = 7.5

# Joint offsets of humanoid.urdf (its <joint><origin xyz>), before scaling; y up, x forward,
# right at +z.
CHEST = (0.0, 0.944604, 0.0)
NECK = (0.0, 0.895576, 0.0)
HIP = (0.0, 0.0, 0.339548)  # right; left mirrored in z
KNEE = (0.0, -1.686184, 0.0)
ANKLE = (0.0, -1.639480, 0.0)
SHOULDER = (-0.096200, 0.974000, 0.732440)  # right
ELBOW = (0.0, -1.099152, 0.0)
WRIST = (0.0, -1.035788, 0.0)
# Where HumanML3D's joints with no DeepMimic counterpart sit, in their parent body's frame
# (scaled units): the toe at the front of the foot box above its sole, spine points between the
# pelvis, chest and neck, the head above the neck, the collars between chest and shoulders.
TOE = (0.46, -0.12, 0.0)
SPINE1 = (0.0, 0.45, 0.0)
SPINE3 = (0.0, 0.25, 0.0)
HEAD = (0.0, 0.40, 0.0)
COLLAR = (-0.05, 0.70, 0.28)

# Columns of a DeepMimic frame that start a rotation quaternion (root, chest, neck, then per
# side hip, ankle, shoulder); the knees and elbows are single angles.
QUAT_COLUMNS = (4, 8, 12, 16, 21, 25, 30, 35, 39)

CAPTIONS = {
    "humanoid3d_walk": "a person walks forward.",
    "humanoid3d_run": "a person runs forward.",
    "humanoid3d_jump": "a person jumps forward.",
    "humanoid3d_kick": "a person kicks.",
    "humanoid3d_punch": "a person punches.",
    "humanoid3d_spinkick": "a person spins around and kicks.",
    "humanoid3d_spin": "a person spins around.",
    "humanoid3d_dance_a": "a person dances.",
    "humanoid3d_dance_b": "a person dances.",
    "humanoid3d_backflip": "a person does a backflip.",
    "humanoid3d_cartwheel": "a person does a cartwheel.",
    "humanoid3d_crawl": "a person crawls forward.",
    "humanoid3d_roll": "a person rolls on the ground.",
    "humanoid3d_getup_faceup": "a person lying on their back gets up.",
    "humanoid3d_getup_facedown": "a person lying face down gets up.",
    "walker_0walk_forward": "a person walks forward.",
    "walker_turn_left0": "a person walks and turns left.",
    "walker_turn_left1": "a person walks and turns left.",
    "walker_turn_right0": "a person walks and turns right.",
    "walker_turn_right1": "a person walks and turns right.",
}
FIXTURES = [
    ("hml_012314", "humanml3d/new_joint_vecs/012314.npy", "a person walks forward, turns around and walks back."),
    ("hml_000021", "humanml3d/000021_features_reference.npy", "a person walks in a circle."),
]


def die(msg):
    sys.exit(f"devset: {msg}")


def qmul(a, b):
    """Hamilton product of (..., 4) quaternions (w, x, y, z)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], -1)


def qrot(q, v):
    """Rotate (..., 3) vectors by unit quaternions (..., 4)."""
    v = np.asarray(v, dtype=np.float64)
    shape = np.broadcast_shapes(q.shape[:-1], v.shape[:-1])
    q, v = np.broadcast_to(q, shape + (4,)), np.broadcast_to(v, shape + (3,))
    p = np.concatenate([np.zeros(v.shape[:-1] + (1,)), v], -1)
    conj = q * np.array([1.0, -1.0, -1.0, -1.0])
    return qmul(qmul(q, p), conj)[..., 1:]


def about_z(angle):
    return np.stack([np.cos(angle / 2), 0 * angle, 0 * angle, np.sin(angle / 2)], -1)


def unit(q):
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def forward_kinematics(frames):
    """DeepMimic frames (T, 44) -> HumanML3D's 22 joints (T, 22, 3), metres, y up."""
    f = np.asarray(frames, dtype=np.float64)
    root_p, root_q = f[:, 1:4], unit(f[:, 4:8])
    q = lambda a: unit(f[:, a:a + 4])
    chest_q = qmul(root_q, q(8))
    neck_q = qmul(chest_q, q(12))
    s = lambda v, side=1.0: np.array([v[0], v[1], side * v[2]]) * SCALE
    at = lambda p, rot, off: p + qrot(rot, off)
    j = np.zeros((len(f), 22, 3))
    j[:, 0] = root_p
    j[:, 3] = at(root_p, root_q, s(SPINE1) * np.array([1, CHEST[1], 1]))
    j[:, 6] = at(root_p, root_q, s(CHEST))
    j[:, 9] = at(j[:, 6], chest_q, s(SPINE3) * np.array([1, NECK[1], 1]))
    j[:, 12] = at(j[:, 6], chest_q, s(NECK))
    j[:, 15] = at(j[:, 12], neck_q, s(HEAD))
    # (hip, knee, ankle, foot) and (collar, shoulder, elbow, wrist) of each side: SMPL's indices,
    # the frame's columns of hip, knee, ankle, shoulder, elbow, and the side's sign (right: +z).
    for (hip, knee, ankle, foot, col, sho, elb, wri), (c_hip, c_knee, c_ank, c_sho, c_elb), side in [
        ((2, 5, 8, 11, 14, 17, 19, 21), (16, 20, 21, 25, 29), 1.0),
        ((1, 4, 7, 10, 13, 16, 18, 20), (30, 34, 35, 39, 43), -1.0),
    ]:
        hip_q = qmul(root_q, q(c_hip))
        knee_q = qmul(hip_q, about_z(f[:, c_knee]))
        ankle_q = qmul(knee_q, q(c_ank))
        j[:, hip] = at(root_p, root_q, s(HIP, side))
        j[:, knee] = at(j[:, hip], hip_q, s(KNEE))
        j[:, ankle] = at(j[:, knee], knee_q, s(ANKLE))
        j[:, foot] = at(j[:, ankle], ankle_q, s(TOE))
        sho_q = qmul(chest_q, q(c_sho))
        elb_q = qmul(sho_q, about_z(f[:, c_elb]))
        j[:, col] = at(j[:, 6], chest_q, s(COLLAR, side))
        j[:, sho] = at(j[:, 6], chest_q, s(SHOULDER, side))
        j[:, elb] = at(j[:, sho], sho_q, s(ELBOW))
        j[:, wri] = at(j[:, elb], elb_q, s(WRIST))
    return j


def yaw_of(q):
    """Heading (rotation about y) of root quaternions: the body's x axis on the ground."""
    fwd = qrot(q, [1.0, 0.0, 0.0])
    return np.arctan2(-fwd[..., 2], fwd[..., 0])


def about_y(angle):
    return np.stack([np.cos(angle / 2), 0 * angle, np.sin(angle / 2), 0 * angle], -1)


def play_on(frames, seconds):
    """A cyclic clip's frames repeated until `seconds`, each cycle starting where the previous
    one ended: the rigid ground motion M taking the first frame's root to the last's (its yaw
    turn and its step on the ground) applied to the previous cycle, as DeepMimic's wrap mode."""
    f = np.asarray(frames, dtype=np.float64)
    total = f[:-1, 0].sum()
    if total <= 0:
        return f
    turn = about_y(np.array(yaw_of(unit(f[-1, 4:8])) - yaw_of(unit(f[0, 4:8]))))
    ground = np.array([1.0, 0.0, 1.0])
    out = [f]
    for _ in range(int(np.ceil(seconds / total)) - 1):
        prev = out[-1] if len(out) > 1 else f[1:]
        nxt = prev.copy()
        nxt[:, 1:4] = qrot(turn, (prev[:, 1:4] - f[0, 1:4]) * ground) + f[-1, 1:4] * ground + prev[:, 1:4] * (1 - ground)
        nxt[:, 4:8] = qmul(np.broadcast_to(turn, (len(nxt), 4)), unit(prev[:, 4:8]))
        out.append(nxt)
    return np.concatenate(out)


def resample(frames, fps):
    """DeepMimic frames at their own times (each row's first value: its duration) to `fps`:
    root position and revolute angles linearly, rotations by normalised linear interpolation of
    the nearer-signed quaternions, so the forward kinematics stays rigid."""
    f = np.asarray(frames, dtype=np.float64)
    t = np.concatenate([[0.0], np.cumsum(f[:-1, 0])])
    out_t = np.arange(0.0, t[-1] + 1e-9, 1.0 / fps)
    i = np.clip(np.searchsorted(t, out_t, side="right") - 1, 0, len(f) - 2)
    w = ((out_t - t[i]) / np.maximum(t[i + 1] - t[i], 1e-12))[:, None]
    a, b = f[i], f[i + 1].copy()
    for c in QUAT_COLUMNS:
        flip = np.sum(a[:, c:c + 4] * b[:, c:c + 4], -1) < 0
        b[flip, c:c + 4] *= -1
    out = a + w * (b - a)
    for c in QUAT_COLUMNS:
        out[:, c:c + 4] = unit(out[:, c:c + 4])
    out[:, 0] = 1.0 / fps
    return out


def fetch(cache):
    """pybullet_data's motions and humanoid.urdf, from the pybullet wheel (pip download)."""
    motions = os.path.join(cache, "pybullet_data", "data", "motions")
    if os.path.isdir(motions):
        return motions
    os.makedirs(cache, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:",
               "--python-version", "3.11", "--platform", "manylinux2014_x86_64", PYBULLET, "-d", tmp]
        if subprocess.run(cmd).returncode != 0:
            die(f"pip download {PYBULLET} failed (PyPI unreachable?)")
        wheel = glob.glob(os.path.join(tmp, "pybullet-*.whl"))[0]
        with zipfile.ZipFile(wheel) as z:
            names = [n for n in z.namelist() if n.startswith("pybullet_data/data/motions/")
                     or n == "pybullet_data/humanoid/humanoid.urdf"]
            z.extractall(tmp, names)
        shutil.move(os.path.join(tmp, "pybullet_data"), os.path.join(cache, "pybullet_data"))
    return motions


def deepmimic_clips(motions):
    for path in sorted(glob.glob(os.path.join(motions, "humanoid3d_*.txt"))
                       + glob.glob(os.path.join(motions, "walker", "*.txt"))):
        name = os.path.splitext(os.path.basename(path))[0]
        if "walker" in path:
            name = "walker_" + name
        with open(path) as fh:
            spec = json.load(fh)
        yield name, spec


def clip_joints(spec):
    frames = np.asarray(spec["Frames"], dtype=np.float64)
    if spec.get("Loop") == "wrap":
        frames = play_on(frames, CYCLE_SECONDS)
    return forward_kinematics(resample(frames, FPS))


def build(a):
    out = a.out
    if os.path.exists(out) and os.listdir(out):
        die(f"{out}: exists and is not empty")
    if not os.access(a.bin, os.X_OK):
        die(f"--bin {a.bin}: not an executable (cargo build --release first)")
    motions = fetch(a.cache)
    for sub in ("new_joint_vecs", "new_joints", "texts", "fk"):
        os.makedirs(os.path.join(out, sub), exist_ok=True)
    ids = []
    for name, spec in deepmimic_clips(motions):
        if name not in CAPTIONS:
            continue
        joints = clip_joints(spec)
        fk = os.path.join(out, "fk", f"{name}.npy")
        np.save(fk, joints.astype(np.float32))
        feats = os.path.join(out, "new_joint_vecs", f"{name}.npy")
        subprocess.run([a.bin, "data", "features", fk, "-o", feats, "--fps", str(FPS)], check=True,
                       stdout=subprocess.DEVNULL)
        ids.append((name, CAPTIONS[name]))
    for name, rel, caption in FIXTURES:
        src = os.path.join(a.fixtures, rel)
        if not os.path.exists(src):
            die(f"--fixtures {a.fixtures}: no {rel}")
        shutil.copy(src, os.path.join(out, "new_joint_vecs", f"{name}.npy"))
        ids.append((name, caption))
    for name, caption in ids:
        subprocess.run([a.bin, "data", "joints", os.path.join(out, "new_joint_vecs", f"{name}.npy"),
                        "-o", os.path.join(out, "new_joints", f"{name}.npy")], check=True, stdout=subprocess.DEVNULL)
        with open(os.path.join(out, "texts", f"{name}.txt"), "w") as fh:
            tokens = " ".join(f"{w}/OTHER" for w in caption.rstrip(".").replace(",", "").split())
            fh.write(f"{caption}#{tokens}#0.0#0.0\n")
    for stat in ("Mean.npy", "Std.npy"):
        shutil.copy(os.path.join(a.stats, stat), os.path.join(out, stat))
    with open(os.path.join(out, "test.txt"), "w") as fh:
        fh.write("".join(f"{n}\n" for n, _ in ids))
    with open(os.path.join(out, "README.txt"), "w") as fh:
        fh.write("The real dev set (scripts/devset.py): for evaluation only; never train on it or commit it.\n"
                 "DeepMimic clips from pybullet_data (zlib licence); HumanML3D fixture clips (its licence).\n")
    print(f"devset: {len(ids)} clips in {out} (test.txt)")


def check(out):
    """Every DeepMimic clip's forward kinematics keeps its bones rigid (1e-5 m: float32), and the
    joints recovered from its features (HumanML3D's processing) do too (1 mm)."""
    parents = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19]
    files = sorted(glob.glob(os.path.join(out, "fk", "*.npy")))
    if not files:
        die(f"{out}: no fk/*.npy (run scripts/devset.py {out} first)")
    def change(j):
        j = j.astype(np.float64)
        lengths = np.stack([np.linalg.norm(j[:, c] - j[:, p], axis=-1) for c, p in enumerate(parents) if p >= 0], -1)
        return float(np.max(np.abs(lengths - lengths[0])))
    fk = max(change(np.load(p)) for p in files)
    recovered = max(change(np.load(os.path.join(out, "new_joints", os.path.basename(p)))) for p in files)
    print(f"devset check: {len(files)} clips, largest bone-length change {fk:.2e} m (forward kinematics), "
          f"{recovered:.2e} m (recovered from the features)")
    if fk > 1e-5 or recovered > 1e-3:
        die(f"bones not rigid: {fk:.2e} m, {recovered:.2e} m")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out")
    here = os.path.dirname(os.path.abspath(__file__))
    p.add_argument("--bin", default=os.path.join(here, "..", "target", "release", "diffkfc"))
    p.add_argument("--fixtures", default=os.environ.get("DIFFKFC_FIXTURES", os.path.join(here, "..", "..", "shared", "fixtures")))
    p.add_argument("--stats", default=os.path.join(here, "..", "models", "mid-synth"))
    p.add_argument("--cache", default=os.path.join(os.environ.get("DIFFKFC_HOME", os.path.expanduser("~/.cache/diffkfc")), "pybullet"))
    p.add_argument("--check", action="store_true")
    a = p.parse_args()
    check(a.out) if a.check else build(a)


if __name__ == "__main__":
    main()
