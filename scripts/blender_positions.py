"""Joint world positions of a BVH or glTF (.glb) as Blender imports it (background mode).

    blender -b --factory-startup --python scripts/blender_positions.py -- IN.bvh|IN.glb 0,10,40 OUT.json

Imports with Blender's own BVH importer (centimetres to metres, BVH Y up) or glTF importer
(metres, Y up, the scene at the file's 20 fps), then writes for each
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


if path.lower().endswith(".glb"):
    # Blender 3.4's glTF importer uses numpy.bool, which numpy 1.24 (Debian's) dropped.
    import numpy
    if not hasattr(numpy, "bool"):
        numpy.bool = numpy.bool_
    # glTF at 20 fps: the scene's rate, so that frames fall on whole scene frames.
    bpy.context.scene.render.fps = 20
    bpy.ops.import_scene.gltf(filepath=path)
    arm = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
    first = min(k.co[0] for fc in arm.animation_data.action.fcurves for k in fc.keyframe_points)
else:
    builtins.open = _open_without_u
    bpy.ops.import_anim.bvh(filepath=path, global_scale=0.01, axis_forward="-Z", axis_up="Y",
                            rotate_mode="NATIVE", update_scene_fps=False, use_fps_scale=False, frame_start=1)
    builtins.open = _open
    arm = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
    first = 1
result = {}
for f in frames:
    bpy.context.scene.frame_set(int(round(first)) + f)
    heads = {}
    for pb in arm.pose.bones:
        x, y, z = arm.matrix_world @ pb.head
        # Blender is Z up; both imports turn (x, y, z) into (x, -z, y).
        heads[pb.name] = [x, z, -y]
    result[str(f)] = heads
with _open(out, "w") as fh:
    json.dump({"frames": result, "blender": bpy.app.version_string}, fh)
