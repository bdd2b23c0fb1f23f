"""diffkfc in Blender: a panel in the 3D view's sidebar that sends the active armature's keyed
poses and a prompt to a local `diffkfc serve` and writes the motion back as a new action (the
previous one kept). Install from the zip `diffkfc blender-addon -o diffkfc_blender.zip` writes.
"""

bl_info = {
    "name": "diffkfc",
    "author": "diffkfc",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "View3D > Sidebar > diffkfc",
    "description": "Text and keyframes to motion with a local diffkfc server",
    "category": "Animation",
}

import json
import subprocess
import time
import urllib.error
import urllib.request

import bpy
from mathutils import Matrix, Quaternion, Vector

from . import rig

FEET = [("steps", "steps", "stances held, swings lifted clear of the floor (default)"),
        ("warp", "warp", "strides scaled to the root's speed, then pinned"), ("pin", "pin", "planted spans pinned"),
        ("network", "network", "the network's contact labels, pinned")]
FITS = [("track", "track", "root first, then the body (default)"), ("warp", "warp", "warp the network's motion onto the keys"),
        ("paste", "paste", "paste the keys into their frames"), ("none", "none", "the network's motion as it is")]


class DiffkfcPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__
    server: bpy.props.StringProperty(name="Server", default="http://127.0.0.1:7860")
    binary: bpy.props.StringProperty(name="diffkfc binary", default="diffkfc", subtype="FILE_PATH")
    checkpoint: bpy.props.StringProperty(name="Model", default="models/mid-synth", subtype="DIR_PATH")
    rig_map: bpy.props.StringProperty(name="Rig map (JSON)", default="", subtype="FILE_PATH",
                                      description="Our joint name to this rig's bone name, as --rig-map")

    def draw(self, context):
        for p in ("server", "binary", "checkpoint", "rig_map"):
            self.layout.prop(self, p)


class DiffkfcSettings(bpy.types.PropertyGroup):
    prompt: bpy.props.StringProperty(name="Prompt", default="a person walks forward.")
    use_scene_range: bpy.props.BoolProperty(name="Scene range", default=True)
    length: bpy.props.IntProperty(name="Frames", default=120, min=1, max=196)
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0)
    fit: bpy.props.EnumProperty(name="Fit", items=FITS, default="track")
    foot_lock: bpy.props.BoolProperty(name="Plant feet", default=True)
    feet: bpy.props.EnumProperty(name="Feet", items=FEET, default="steps")
    selected_only: bpy.props.BoolProperty(name="Selected bones only", default=False,
                                          description="Keys observe only the selected bones (body-part keys)")
    last_ms: bpy.props.FloatProperty(name="Last generation (ms)", default=0.0)


def prefs(context):
    return context.preferences.addons[__package__].preferences


def frame_range(context, s):
    scene = context.scene
    start = scene.frame_start
    end = scene.frame_end if s.use_scene_range else start + s.length - 1
    return start, end


def keyed_frames(obj, bones, selected_only, start, end):
    """The action's keyed frames within [start, end] (of the mapped or selected bones)."""
    action = obj.animation_data.action if obj.animation_data else None
    if action is None:
        return []
    names = {b for b in bones}
    if selected_only:
        names = {b.name for b in obj.data.bones if b.select} & names
    frames = set()
    for fc in action.fcurves:
        if not fc.data_path.startswith("pose.bones["):
            continue
        bone = fc.data_path.split('"')[1]
        if bone in names:
            frames.update(int(round(k.co[0])) for k in fc.keyframe_points)
    return sorted(f for f in frames if start <= f <= end)


def joints_at(context, obj, bones, frame):
    """Our 22 joints' world positions (Blender units, Z up) at `frame`."""
    context.scene.frame_set(frame)
    return [list(obj.matrix_world @ obj.pose.bones[b].head) for b in bones]


def request_for(context, obj, bones, s, start, end):
    frames = keyed_frames(obj, bones, s.selected_only, start, end)
    if not frames:
        raise rig.RigError(f"no keyed frames of the armature between {start} and {end}")
    current = context.scene.frame_current
    poses = {f: joints_at(context, obj, bones, f) for f in frames}
    context.scene.frame_set(current)
    scale = rig.leg_scale(poses[frames[0]])
    keys = []
    for f in frames:
        pose = [rig.to_ours(p, scale) for p in poses[f]]
        keys.append({"frame": f - start, "joints": pose, "root": pose[0], "heading": rig.heading_deg(pose)})
    body = {"text": s.prompt, "seed": s.seed, "fit": s.fit, "foot_lock": s.foot_lock, "feet": s.feet,
            "keyframes": {"length": end - start + 1, "keyframes": keys}}
    if s.selected_only:
        chosen = [rig.SNAKE[j] for j, b in enumerate(bones) if obj.data.bones[b].select]
        if not chosen:
            raise rig.RigError("'Selected bones only' is on but none of the armature's mapped bones is selected")
        body["keyframes"]["joints"] = ",".join(chosen)
    return body, scale


def post(url, body, timeout=120):
    req = urllib.request.Request(url + "/api/sample", data=json.dumps(body).encode(),
                                 headers={"Content-Type": "application/json"}, method="POST")
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            return json.loads(r.read())
    except urllib.error.HTTPError as e:
        try:
            msg = json.loads(e.read()).get("error", str(e))
        except ValueError:
            msg = str(e)
        raise rig.RigError(f"server: {msg}")
    except (urllib.error.URLError, OSError) as e:
        raise rig.RigError(f"server {url} is not reachable ({getattr(e, 'reason', e)}); start it with "
                           "'diffkfc serve' or the panel's Start server")


def pose_matrices(obj, bones, targets):
    """Armature-space pose matrices of the mapped bones putting their heads on `targets`."""
    rest = [obj.data.bones[b].matrix_local for b in bones]
    heads = [list(r.to_translation()) for r in rest]
    delta = rig.global_deltas(heads, targets)
    out = {}
    for j, b in enumerate(bones):
        rot = Quaternion(delta[j]).to_matrix().to_4x4() @ rest[j].to_3x3().to_4x4()
        out[b] = Matrix.Translation(Vector(targets[j])) @ rot
    return out


def basis_of(obj, name, pose_m, posed):
    """matrix_basis of bone `name` given its armature-space pose matrix (parents' in `posed`)."""
    bone = obj.data.bones[name]
    if bone.parent is None:
        return bone.matrix_local.inverted() @ pose_m
    parent_pose = posed.get(bone.parent.name)
    if parent_pose is None:
        parent_pose = bone.parent.matrix_local
    local = bone.parent.matrix_local.inverted() @ bone.matrix_local
    return (parent_pose @ local).inverted() @ pose_m


def write_action(obj, bones, joints, start, scale, name):
    """A new action on `obj` with the motion (world joints, ours) on every frame."""
    inv = obj.matrix_world.inverted()
    order = sorted(range(22), key=rig._depth)
    values = {b: ([], []) for b in bones}  # location rows, quaternion rows
    for t, frame_joints in enumerate(joints):
        targets = [list(inv @ Vector(rig.to_blender(p, scale))) for p in frame_joints]
        pose_m = pose_matrices(obj, bones, targets)
        posed = {}
        prev_q = {}
        for j in order:
            b = bones[j]
            basis = basis_of(obj, b, pose_m[b], posed)
            posed[b] = pose_m[b]
            loc, q, _ = basis.decompose()
            values[b][0].append(list(loc))
            values[b][1].append(list(q))
    action = bpy.data.actions.new(name)
    try:
        fill(action, bones, values, start)
    except Exception as e:  # never leave a half-written action behind
        bpy.data.actions.remove(action)
        raise rig.RigError(f"writing the action failed: {e}")
    return action


def fill(action, bones, values, start):
    """F-curves of every mapped bone's location and quaternion, one key per frame (linear)."""
    for b in bones:
        locs, quats = values[b]
        for k in range(1, len(quats)):
            if sum(x * y for x, y in zip(quats[k], quats[k - 1])) < 0:
                quats[k] = [-x for x in quats[k]]
        for path, rows, width in (("location", locs, 3), ("rotation_quaternion", quats, 4)):
            for i in range(width):
                fc = action.fcurves.new(f'pose.bones["{b}"].{path}', index=i, action_group=b)
                fc.keyframe_points.add(len(rows))
                co = []
                for t, r in enumerate(rows):
                    co += [start + t, r[i]]
                fc.keyframe_points.foreach_set("co", co)
                fc.keyframe_points.foreach_set("interpolation", [1] * len(rows))  # LINEAR
                fc.update()


class DIFFKFC_OT_generate(bpy.types.Operator):
    bl_idname = "diffkfc.generate"
    bl_label = "Generate"
    bl_description = "Send the prompt and the armature's keyed poses to diffkfc and write the motion as a new action"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        t0 = time.perf_counter()
        obj = context.active_object
        s = context.scene.diffkfc
        try:
            if obj is None or obj.type != "ARMATURE":
                raise rig.RigError("select an armature (the active object is not one)")
            rig_map = None
            path = prefs(context).rig_map
            if path:
                with open(bpy.path.abspath(path)) as fh:
                    rig_map = json.load(fh)
            bones = rig.bone_map([b.name for b in obj.data.bones], rig_map)
            start, end = frame_range(context, s)
            if end - start + 1 > 196 or end < start:
                raise rig.RigError(f"frames {start}-{end}: a motion is 1 to 196 frames")
            body, scale = request_for(context, obj, bones, s, start, end)
            reply = post(prefs(context).server.rstrip("/"), body)
            flat = reply["joints"]
            joints = [[flat[(t * 22 + j) * 3:(t * 22 + j) * 3 + 3] for j in range(22)] for t in range(len(flat) // 66)]
        except (rig.RigError, OSError, ValueError, KeyError) as e:
            self.report({"ERROR"}, str(e).splitlines()[0])
            return {"CANCELLED"}
        try:
            action = write_action(obj, bones, joints, start, scale, f"diffkfc: {s.prompt[:40]}")
        except rig.RigError as e:
            self.report({"ERROR"}, str(e).splitlines()[0])
            return {"CANCELLED"}
        old = obj.animation_data.action if obj.animation_data else None
        if old is not None:
            old.use_fake_user = True
        for b in bones:
            obj.pose.bones[b].rotation_mode = "QUATERNION"
        obj.animation_data_create()
        obj.animation_data.action = action
        context.scene.frame_set(context.scene.frame_current)
        s.last_ms = (time.perf_counter() - t0) * 1e3
        self.report({"INFO"}, f"diffkfc: {len(joints)} frames from {len(body['keyframes']['keyframes'])} keys in {s.last_ms:.0f} ms")
        return {"FINISHED"}


class DIFFKFC_OT_start_server(bpy.types.Operator):
    bl_idname = "diffkfc.start_server"
    bl_label = "Start server"
    bl_description = "Start 'diffkfc serve' with the model in the add-on's preferences"

    def execute(self, context):
        p = prefs(context)
        port = p.server.rstrip("/").rsplit(":", 1)[-1]
        try:
            subprocess.Popen([bpy.path.abspath(p.binary), "serve", "--checkpoint", bpy.path.abspath(p.checkpoint),
                              "--port", port], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        except OSError as e:
            self.report({"ERROR"}, f"diffkfc binary {p.binary}: {e}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"diffkfc serve starting on port {port}")
        return {"FINISHED"}


class DIFFKFC_PT_panel(bpy.types.Panel):
    bl_label = "diffkfc"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "diffkfc"

    def draw(self, context):
        s = context.scene.diffkfc
        col = self.layout.column()
        col.prop(s, "prompt", text="")
        col.prop(s, "use_scene_range")
        if not s.use_scene_range:
            col.prop(s, "length")
        col.prop(s, "seed")
        col.prop(s, "fit")
        col.prop(s, "foot_lock")
        if s.foot_lock:
            col.prop(s, "feet")
        col.prop(s, "selected_only")
        col.operator("diffkfc.generate")
        col.operator("diffkfc.start_server")
        if s.last_ms:
            col.label(text=f"last: {s.last_ms:.0f} ms")


CLASSES = (DiffkfcPreferences, DiffkfcSettings, DIFFKFC_OT_generate, DIFFKFC_OT_start_server, DIFFKFC_PT_panel)


def register():
    for c in CLASSES:
        bpy.utils.register_class(c)
    bpy.types.Scene.diffkfc = bpy.props.PointerProperty(type=DiffkfcSettings)


def unregister():
    del bpy.types.Scene.diffkfc
    for c in reversed(CLASSES):
        bpy.utils.unregister_class(c)
