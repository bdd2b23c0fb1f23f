"""Render one frame of a BVH as Blender imports it (run inside Blender, background mode):
sticks from every joint to its parent, right side red, on a floor, Workbench engine.

    blender -b --factory-startup --python scripts/blender_render.py -- IN.bvh FRAME OUT.png [rest]

Used for the README's picture of an exported sample in Blender (docs/blender-bvh.png).
"""
import bpy, sys, builtins, math
args = sys.argv[sys.argv.index("--") + 1:]
path, frame, out = args[0], int(args[1]), args[2]
_open = builtins.open
builtins.open = lambda f, mode="r", *a, **k: _open(f, mode.replace("U", ""), *a, **k)
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_anim.bvh(filepath=path, global_scale=0.01, axis_forward="-Z", axis_up="Y", update_scene_fps=False, use_fps_scale=False, frame_start=1)
builtins.open = _open
scene = bpy.context.scene
arm = next(o for o in scene.objects if o.type == "ARMATURE")
arm.data.display_type = "OCTAHEDRAL"
arm.show_in_front = True
scene.frame_set(frame + 1)
# Armatures do not render: a stick per bone, from its head to its tail, at this frame.
from mathutils import Vector
mat = bpy.data.materials.new("bone"); mat.diffuse_color = (0.15, 0.35, 0.85, 1)
matr = bpy.data.materials.new("boner"); matr.diffuse_color = (0.85, 0.2, 0.2, 1)
if len(args) > 3 and args[3] == "rest":
    arm.data.pose_position = "REST"
    bpy.context.view_layer.update()
segs = []
for pb in arm.pose.bones:
    # Joint to joint (a branching joint's bone is short in Blender's import), and the leaves' ends.
    if pb.parent: segs.append((pb.parent.head, pb.head, pb.name))
    if not pb.children: segs.append((pb.head, pb.tail, pb.name))
for ha, hb, name in segs:
    a = arm.matrix_world @ ha; b = arm.matrix_world @ hb
    v = b - a
    if v.length < 1e-4: continue
    bpy.ops.mesh.primitive_cylinder_add(radius=0.025, depth=v.length, location=(a + b) / 2)
    o = bpy.context.active_object
    o.rotation_mode = "QUATERNION"; o.rotation_quaternion = Vector((0, 0, 1)).rotation_difference(v)
    o.data.materials.append(matr if name.startswith("Right") else mat)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.035, location=b)
bpy.ops.mesh.primitive_uv_sphere_add(radius=0.09, location=arm.matrix_world @ arm.pose.bones["Head"].head + Vector((0, 0, 0.08)))
arm.hide_render = True
# a floor
bpy.ops.mesh.primitive_plane_add(size=20, location=(0, 0, 0))
# camera looking at the hips
hips = arm.matrix_world @ arm.pose.bones["Hips"].head
cam_data = bpy.data.cameras.new("cam"); cam = bpy.data.objects.new("cam", cam_data); scene.collection.objects.link(cam)
cam.location = (hips.x + 2.2, hips.y - 3.2, 1.6)
d = hips - cam.location
cam.rotation_euler = (math.atan2(math.hypot(d.x, d.y), -d.z), 0, math.atan2(d.y, d.x) - math.pi / 2)
scene.camera = cam
light = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN")); scene.collection.objects.link(light)
light.rotation_euler = (0.6, 0.2, 0.5)
scene.render.engine = "BLENDER_WORKBENCH"
scene.render.resolution_x, scene.render.resolution_y = 480, 480
scene.display.shading.show_xray = False
scene.display.shading.color_type = "MATERIAL"
scene.render.filepath = out
bpy.ops.render.render(write_still=True)
