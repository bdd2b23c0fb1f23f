"""The armature as diffkfc sees it: its bones named as our 22 joints, the joints' world
positions at a frame (Y up, metres, as diffkfc's keys are), and positions written back as a
pose (each bone turned onto its joints: the shortest arc for one child, the best rigid fit for
several, as diffkfc's BVH export does). No bpy at import time, so the math is testable alone."""

import math

import numpy

# HumanML3D's 22 joints: our rig's names (the BVH `diffkfc` writes) and their parents.
OURS = ["Hips", "LeftUpLeg", "RightUpLeg", "Spine", "LeftLeg", "RightLeg", "Spine1", "LeftFoot",
        "RightFoot", "Spine2", "LeftToe", "RightToe", "Neck", "LeftShoulder", "RightShoulder", "Head",
        "LeftArm", "RightArm", "LeftForeArm", "RightForeArm", "LeftHand", "RightHand"]
PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19]
KIDS = [[c for c, p in enumerate(PARENTS) if p == j] for j in range(22)]

# Other conventions, as the joints where they differ from ours (`--rig-map`'s known names).
CONVENTIONS = {
    "diffkfc": {},
    "Mixamo": {10: "LeftToeBase", 11: "RightToeBase"},
    "CMU": {3: "LowerBack", 6: "Spine", 9: "Spine1", 10: "LeftToeBase", 11: "RightToeBase", 12: "Neck1"},
}
# diffkfc's snake_case joint names, which a rig map may use for our side.
SNAKE = ["pelvis", "l_hip", "r_hip", "spine1", "l_knee", "r_knee", "spine2", "l_ankle", "r_ankle", "spine3",
         "l_foot", "r_foot", "neck", "l_collar", "r_collar", "head", "l_shoulder", "r_shoulder", "l_elbow",
         "r_elbow", "l_wrist", "r_wrist"]


class RigError(Exception):
    """A one-line reason the armature cannot be used."""


def _strip(name):
    # Mixamo's "mixamorig:Hips", other exporters' "Armature|Hips" or "rig_Hips".
    for sep in (":", "|"):
        name = name.rsplit(sep, 1)[-1]
    return name


def bone_map(bone_names, rig_map=None):
    """The armature's bone for each of our 22 joints: by a rig map ({our name: theirs}, ours
    in either naming) first, then by the known convention that names the most joints."""
    names = list(bone_names)
    by_stripped = {}
    for n in names:
        by_stripped.setdefault(_strip(n).lower(), n)
    mapped = [None] * 22
    for ours, theirs in (rig_map or {}).items():
        j = OURS.index(ours) if ours in OURS else SNAKE.index(ours) if ours in SNAKE else None
        if j is None:
            raise RigError(f"rig map: '{ours}' is not one of our joints (Hips, LeftUpLeg, ... or pelvis, l_hip, ...)")
        if theirs not in names:
            raise RigError(f"rig map: the armature has no bone '{theirs}' (for {ours})")
        mapped[j] = theirs
    best = None
    for conv, changes in CONVENTIONS.items():
        want = [changes.get(j, OURS[j]) for j in range(22)]
        found = [m or by_stripped.get(w.lower()) for m, w in zip(mapped, want)]
        score = sum(f is not None for f in found)
        if best is None or score > best[0]:
            best = (score, conv, found)
    score, conv, found = best
    if score < 22:
        missing = [OURS[j] for j in range(22) if found[j] is None]
        raise RigError(f"unknown bones: no bone for {', '.join(missing[:6])}{' ...' if len(missing) > 6 else ''} "
                       f"(closest naming: {conv}); set a rig map in the add-on's preferences")
    return found


def to_ours(p, scale):
    """Blender (Z up) to diffkfc (Y up), metres."""
    return [p[0] * scale, p[2] * scale, -p[1] * scale]


def to_blender(p, scale):
    return [p[0] / scale, -p[2] / scale, p[1] / scale]


def heading_deg(pose):
    """The body's heading as diffkfc reads it (hips and shoulders across, 0 faces +Z)."""
    across = [pose[2][k] - pose[1][k] + pose[17][k] - pose[16][k] for k in range(3)]
    # forward = up x across
    fx, fz = across[2], -across[0]
    return math.degrees(math.atan2(fx, fz))


def leg_scale(pose):
    """Metres per Blender unit that make the leg (hip to ankle) human-sized."""
    leg = sum(math.dist(pose[a], pose[b]) for a, b in ((1, 4), (4, 7), (2, 5), (5, 8))) / 2
    for k in (1.0, 0.01, 0.001):
        if 0.2 <= leg * k <= 3.0:
            return k
    raise RigError(f"the armature's leg is {leg:.3g} units long; neither metres nor centimetres")


# --- small vector and rotation math on lists (quaternions as w, x, y, z) ---

def sub(a, b):
    return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]


def cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def qmul(q, r):
    w1, x1, y1, z1 = q
    w0, x0, y0, z0 = r
    return [w1 * w0 - x1 * x0 - y1 * y0 - z1 * z0, w1 * x0 + x1 * w0 + y1 * z0 - z1 * y0,
            w1 * y0 - x1 * z0 + y1 * w0 + z1 * x0, w1 * z0 + x1 * y0 - y1 * x0 + z1 * w0]


def qrot(q, v):
    qv = q[1:]
    uv = cross(qv, v)
    uuv = cross(qv, uv)
    return [v[k] + 2 * (q[0] * uv[k] + uuv[k]) for k in range(3)]


def qnorm(q):
    n = math.sqrt(sum(x * x for x in q))
    return [1.0, 0.0, 0.0, 0.0] if n < 1e-12 else [x / n for x in q]


def qbetween(a, b):
    if dot(a, a) < 1e-24 or dot(b, b) < 1e-24:
        return [1.0, 0.0, 0.0, 0.0]
    v = cross(a, b)
    w = math.sqrt(dot(a, a) * dot(b, b)) + dot(a, b)
    if w * w + dot(v, v) < 1e-24:
        axis = cross(a, [1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else cross(a, [0.0, 1.0, 0.0])
        return qnorm([0.0] + axis)
    return qnorm([w] + v)


def best_rotation(frm, to):
    """The rotation taking the vectors `frm` closest onto `to` (Horn's quaternion method)."""
    s = [[sum(a[i] * b[j] for a, b in zip(frm, to)) for j in range(3)] for i in range(3)]
    (xx, xy, xz), (yx, yy, yz), (zx, zy, zz) = s
    n = [[xx + yy + zz, yz - zy, zx - xz, xy - yx], [yz - zy, xx - yy - zz, xy + yx, zx + xz],
         [zx - xz, xy + yx, -xx + yy - zz, yz + zy], [xy - yx, zx + xz, yz + zy, -xx - yy + zz]]
    w, v = numpy.linalg.eigh(numpy.array(n))
    return qnorm([float(x) for x in v[:, int(numpy.argmax(w))]])


def global_deltas(rest_heads, targets):
    """Per joint, the rotation (armature space) from its rest orientation to its pose, such that
    its children's rest offsets turn onto the targets' (the BVH export's fit)."""
    delta = [None] * 22
    order = sorted(range(22), key=lambda j: _depth(j))
    for j in order:
        base = delta[PARENTS[j]] if PARENTS[j] >= 0 else [1.0, 0.0, 0.0, 0.0]
        kids = KIDS[j]
        if not kids:
            delta[j] = base
        elif len(kids) == 1:
            c = kids[0]
            rest = qrot(base, sub(rest_heads[c], rest_heads[j]))
            delta[j] = qnorm(qmul(qbetween(rest, sub(targets[c], targets[j])), base))
        else:
            frm = [sub(rest_heads[c], rest_heads[j]) for c in kids]
            to = [sub(targets[c], targets[j]) for c in kids]
            delta[j] = best_rotation(frm, to)
    return delta


def _depth(j):
    d = 0
    while PARENTS[j] >= 0:
        j = PARENTS[j]
        d += 1
    return d
