"""The diffkfc add-on driven in Blender (background mode), for tests/blender_addon.rs:

    blender -b --factory-startup --python scripts/blender_addon_check.py -- ADDON.zip RIG.bvh SERVER OUT.json [--mixamo]

Installs the add-on from its zip, imports our rig's BVH (metres), keeps three of its poses as
keys (the third moved 2 m ahead and turned to face 90 degrees), optionally renames the bones to
Mixamo's, then checks the errors the panel reports (no armature, no server) leave the scene as
it was, presses Generate and writes every frame's joints (Y up, metres) with the request it sent.
"""
import builtins
import json
import math
import sys
import time

import bpy
from mathutils import Matrix, Vector

args = sys.argv[sys.argv.index("--") + 1:]
zip_path, bvh, server, out = args[:4]
mixamo = "--mixamo" in args

bpy.ops.preferences.addon_install(filepath=zip_path, overwrite=True)
bpy.ops.preferences.addon_enable(module="diffkfc_blender")
import diffkfc_blender  # noqa: E402
from diffkfc_blender import rig  # noqa: E402

# Debian's Blender 3.4 importer opens files with mode 'rU', which Python 3.11 rejects.
_open = builtins.open
builtins.open = lambda f, mode="r", *a, **k: _open(f, mode.replace("U", ""), *a, **k)
bpy.ops.import_anim.bvh(filepath=bvh, global_scale=0.01, axis_forward="-Z", axis_up="Y", rotate_mode="NATIVE",
                        update_scene_fps=False, use_fps_scale=False, frame_start=1)
builtins.open = _open
scene = bpy.context.scene
arm = next(o for o in scene.objects if o.type == "ARMATURE")
if mixamo:
    for b in arm.data.bones:
        b.name = "mixamorig:" + {"LeftToe": "LeftToeBase", "RightToe": "RightToeBase"}.get(b.name, b.name)
hips = next(b.name for b in arm.data.bones if b.parent is None)

# Three keys: frames 1, 50 and 100 of the walk; the third 2 m ahead of the first, facing 90
# degrees (+X).
KEYS = [1, 50, 100]
poses = {}
for f in KEYS:
    scene.frame_set(f)
    poses[f] = {pb.name: (pb.matrix.copy()) for pb in arm.pose.bones}
first_hips = poses[1][hips].to_translation()
m = poses[100][hips]
head = m.to_translation()
ahead = Vector((first_hips.x, first_hips.y - 2.0, head.z))  # ours +Z is Blender's -Y
# Turning about Blender's +Z by t adds t to diffkfc's heading: turn the key to face 90 degrees.
scene.frame_set(100)
named = rig.bone_map([b.name for b in arm.data.bones])
h0 = rig.heading_deg([rig.to_ours(arm.matrix_world @ arm.pose.bones[b].head, 1.0) for b in named])
turn = Matrix.Rotation(math.radians(90.0 - h0), 4, "Z")
move = Matrix.Translation(ahead) @ turn @ Matrix.Translation(-head)
poses[100] = {name: move @ pm for name, pm in poses[100].items()}
arm.animation_data.action = None
for pb in arm.pose.bones:
    pb.matrix_basis = Matrix.Identity(4)
for f in KEYS:
    scene.frame_set(f)
    for pb in sorted(arm.pose.bones, key=lambda p: len(p.parent_recursive)):
        pb.matrix = poses[f][pb.name]
        bpy.context.view_layer.update()
    for pb in arm.pose.bones:
        pb.keyframe_insert("location", frame=f)
        pb.keyframe_insert("rotation_euler" if pb.rotation_mode != "QUATERNION" else "rotation_quaternion", frame=f)

scene.frame_start, scene.frame_end = 1, 120
s = scene.diffkfc
s.prompt, s.seed = "a person walks forward and turns right.", 7
prefs = bpy.context.preferences.addons["diffkfc_blender"].preferences
bones = rig.bone_map([b.name for b in arm.data.bones])
body, scale = diffkfc_blender.request_for(bpy.context, arm, bones, s, 1, 120)
keyed_action = arm.animation_data.action


def failed():
    """The operator's one-line error with the scene as given; the action must stay."""
    try:
        result = sorted(bpy.ops.diffkfc.generate())
        message = ""
    except RuntimeError as e:  # an operator's ERROR report raises in scripts
        result, message = ["CANCELLED"], str(e).strip()
    kept = arm.animation_data is not None and arm.animation_data.action == keyed_action
    return {"result": result, "message": message, "action_kept": kept}


errors = {}
bpy.context.view_layer.objects.active = None
errors["no_armature"] = failed()
bpy.context.view_layer.objects.active = arm
prefs.server = "http://127.0.0.1:9"
errors["no_server"] = failed()
prefs.server = server
t0 = time.perf_counter()
result = bpy.ops.diffkfc.generate()
seconds = time.perf_counter() - t0
frames = []
for f in range(1, 121):
    scene.frame_set(f)
    frames.append([rig.to_ours(arm.matrix_world @ arm.pose.bones[b].head, 1.0) for b in bones])
with _open(out, "w") as fh:
    json.dump({"result": sorted(result), "seconds": seconds, "request": body, "frames": frames, "errors": errors,
               "new_action": arm.animation_data.action.name, "old_kept": keyed_action.name in bpy.data.actions,
               "blender": bpy.app.version_string}, fh)
