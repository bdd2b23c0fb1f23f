"""Joint world positions of a BVH as Blender imports it (run inside Blender, background mode).

    blender -b --factory-startup --python scripts/blender_positions.py -- IN.bvh 0,10,40 OUT.json

Imports with Blender's own BVH importer (centimetres to metres, BVH Y up), then writes for each
requested frame (0-based, BVH frames) every pose bone's head in the BVH's axes (Y up) and
metres: {"frames": {"0": {"Hips": [x, y, z], ...}, ...}, "blender": "3.4.1"}.
"""
import builtins
import json
import sys

import bpy

args = sys.argv[sys.argv.index("--") + 1:]
path, frames, out = args[0], [int(f) for f in args[1].split(",")], args[2]

# Debian's Blender 3.4 importer opens files with mode 'rU', which Python 3.11 rejects.
_open = builtins.open


def _open_without_u(file, mode="r", *a, **k):
    return _open(file, mode.replace("U", ""), *a, **k)


builtins.open = _open_without_u
bpy.ops.import_anim.bvh(filepath=path, global_scale=0.01, axis_forward="-Z", axis_up="Y", rotate_mode="NATIVE",
                        update_scene_fps=False, use_fps_scale=False, frame_start=1)
builtins.open = _open
arm = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
result = {}
for f in frames:
    bpy.context.scene.frame_set(f + 1)
    heads = {}
    for pb in arm.pose.bones:
        x, y, z = arm.matrix_world @ pb.head
        # Blender is Z up; the import turned BVH (x, y, z) into (x, -z, y).
        heads[pb.name] = [x, z, -y]
    result[str(f)] = heads
with _open(out, "w") as fh:
    json.dump({"frames": result, "blender": bpy.app.version_string}, fh)
