//! Motions as glTF 2.0 binary (`.glb`): the rig the BVH export fits ([`rig::pose`]: T-pose
//! rest, common joint names, the motion's bone lengths) as a skin of joint nodes in metres, Y
//! up; one animation at the skeleton's rate (the root's translation and every joint's rotation,
//! linear); and a simple body, a box along every bone bound rigidly to it, so that any viewer
//! shows something. The JSON is built with serde_json; the container is the format's two
//! chunks. tests/gltf.rs checks the files with Khronos's validator and Blender's importer.

use std::path::Path;

use serde_json::{json, Value};

use crate::io::rig;
use crate::motion::quat::{self, Quat, Vec3};
use crate::motion::representation::Joints;
use crate::motion::skeleton::Skeleton;
use crate::DataError;

/// Half the width of a bone's box (metres); leaves (head, hands, toes) get a cube of this size.
const BONE_HALF_WIDTH: f32 = 0.035;

/// glTF's component types (the values of OpenGL's type enumeration).
const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_BYTE: u32 = 5121;
/// Buffer view targets: vertex attributes and triangle indices.
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// The document as it is built: the top-level arrays that refer to each other by index, and
/// the binary buffer (views 4-byte aligned).
#[derive(Default)]
struct Doc {
    accessors: Vec<Value>,
    buffer_views: Vec<Value>,
    nodes: Vec<Value>,
    meshes: Vec<Value>,
    skins: Vec<Value>,
    animations: Vec<Value>,
    bin: Vec<u8>,
}

/// An f32 as JSON in its own shortest form (`json!` would write the f64 it widens to).
fn single(v: f32) -> Value {
    v.to_string().parse::<f64>().map_or(Value::Null, Value::from)
}

/// Push `item` onto `list` and give its index.
fn push(list: &mut Vec<Value>, item: Value) -> usize {
    list.push(item);
    list.len() - 1
}

impl Doc {
    /// Append `values` as a view (with `target` for vertex data) and an accessor over it.
    fn accessor(&mut self, values: Accessed, target: Option<u32>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        let (count, component, type_, bounds) = values.write(&mut self.bin);
        let mut view =
            json!({"buffer": 0, "byteLength": self.bin.len() - offset, "byteOffset": offset});
        if let Some(t) = target {
            view["target"] = json!(t);
        }
        let view = push(&mut self.buffer_views, view);
        let mut acc =
            json!({"bufferView": view, "componentType": component, "count": count, "type": type_});
        if let Some((lo, hi)) = bounds {
            acc["min"] = json!(lo);
            acc["max"] = json!(hi);
        }
        push(&mut self.accessors, acc)
    }
}

/// Values for one accessor.
enum Accessed {
    /// f32 rows of 1, 3, 4 or 16 values; with their per-column bounds when `bounded`.
    Floats { rows: Vec<Vec<f32>>, bounded: bool },
    /// u16 scalars (indices).
    Indices(Vec<u16>),
    /// u8 rows of 4 (joint indices).
    Joints(Vec<[u8; 4]>),
}

type Bounds = Option<(Vec<f32>, Vec<f32>)>;

impl Accessed {
    /// Append the values; give their count, component type, accessor type and bounds.
    fn write(self, out: &mut Vec<u8>) -> (usize, u32, &'static str, Bounds) {
        match self {
            Accessed::Floats { rows, bounded } => {
                let width = rows.first().map_or(1, Vec::len);
                let type_ = match width {
                    1 => "SCALAR",
                    3 => "VEC3",
                    4 => "VEC4",
                    _ => "MAT4",
                };
                let mut lo = vec![f32::INFINITY; width];
                let mut hi = vec![f32::NEG_INFINITY; width];
                for r in &rows {
                    for (c, v) in r.iter().enumerate() {
                        out.extend_from_slice(&v.to_le_bytes());
                        lo[c] = lo[c].min(*v);
                        hi[c] = hi[c].max(*v);
                    }
                }
                (rows.len(), FLOAT, type_, bounded.then_some((lo, hi)))
            }
            Accessed::Indices(ix) => {
                ix.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
                (ix.len(), UNSIGNED_SHORT, "SCALAR", None)
            }
            Accessed::Joints(js) => {
                js.iter().for_each(|j| out.extend_from_slice(j));
                (js.len(), UNSIGNED_BYTE, "VEC4", None)
            }
        }
    }
}

/// glTF's (x, y, z, w) of our (w, x, y, z), normalised in single precision.
fn xyzw(q: Quat) -> Vec<f32> {
    let q = quat::qnormalize(q);
    let v = [q[1] as f32, q[2] as f32, q[3] as f32, q[0] as f32];
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    v.iter().map(|x| x / n).collect()
}

/// A box face: its four corners (end of the bone, side along u, side along v) and its normal.
type Face = ([(usize, f64, f64); 4], Vec3);

/// The body's vertex attributes (positions, normals, joints) and triangle indices.
struct Mesh {
    pos: Vec<Vec<f32>>,
    nrm: Vec<Vec<f32>>,
    jnt: Vec<[u8; 4]>,
    idx: Vec<u16>,
}

/// The body: a box from each joint's parent to it, bound to the parent, and a cube at each leaf
/// bound to it (positions, normals, joints, indices), in the bind pose `at` (metres).
fn body(parents: &[i64], at: &[Vec3]) -> Mesh {
    let mut body = Mesh { pos: Vec::new(), nrm: Vec::new(), jnt: Vec::new(), idx: Vec::new() };
    let w = BONE_HALF_WIDTH as f64;
    for (j, &p) in parents.iter().enumerate() {
        if p >= 0 {
            body.push_box(at[p as usize], at[j], p as usize);
        }
        if !parents.contains(&(j as i64)) {
            body.push_box(at[j], quat::add(at[j], [0.0, 2.0 * w, 0.0]), j);
        }
    }
    body
}

impl Mesh {
    /// A box of half-width [`BONE_HALF_WIDTH`] from `from` to `to`, bound to joint `bone`.
    fn push_box(&mut self, from: Vec3, to: Vec3, bone: usize) {
        let w = BONE_HALF_WIDTH as f64;
        let dir = quat::normalize(quat::sub(to, from));
        let helper = if dir[1].abs() < 0.9 { [0.0, 1.0, 0.0] } else { [1.0, 0.0, 0.0] };
        let u = quat::scale(quat::normalize(quat::cross(dir, helper)), w);
        let v = quat::scale(quat::normalize(quat::cross(dir, u)), w);
        // Corner (a, b, c): along the bone (0 or 1), then -/+ u and -/+ v.
        let corner = |(a, b, c): (usize, f64, f64)| {
            quat::add(
                quat::add(if a == 0 { from } else { to }, quat::scale(u, b)),
                quat::scale(v, c),
            )
        };
        let neg = |x: Vec3| quat::scale(x, -1.0);
        let faces: [Face; 6] = [
            ([(0, -1.0, -1.0), (0, -1.0, 1.0), (0, 1.0, 1.0), (0, 1.0, -1.0)], neg(dir)),
            ([(1, -1.0, -1.0), (1, 1.0, -1.0), (1, 1.0, 1.0), (1, -1.0, 1.0)], dir),
            ([(0, 1.0, -1.0), (0, 1.0, 1.0), (1, 1.0, 1.0), (1, 1.0, -1.0)], u),
            ([(0, -1.0, -1.0), (1, -1.0, -1.0), (1, -1.0, 1.0), (0, -1.0, 1.0)], neg(u)),
            ([(0, -1.0, 1.0), (1, -1.0, 1.0), (1, 1.0, 1.0), (0, 1.0, 1.0)], v),
            ([(0, -1.0, -1.0), (0, 1.0, -1.0), (1, 1.0, -1.0), (1, -1.0, -1.0)], neg(v)),
        ];
        for (quad, normal) in faces {
            let base = self.pos.len() as u16;
            let n = quat::normalize(normal);
            for c in quad {
                self.pos.push(corner(c).iter().map(|&x| x as f32).collect());
                self.nrm.push(n.iter().map(|&x| x as f32).collect());
                // Unused slots stay 0 with weight 0, as the validator asks.
                self.jnt.push([bone as u8, 0, 0, 0]);
            }
            // Counter-clockwise seen from outside, whatever the corners' handedness.
            let (p0, p1, p2) = (corner(quad[0]), corner(quad[1]), corner(quad[2]));
            let outward = quat::dot(quat::cross(quat::sub(p1, p0), quat::sub(p2, p0)), n) > 0.0;
            let tri: [u16; 6] = if outward { [0, 1, 2, 0, 2, 3] } else { [0, 2, 1, 0, 3, 2] };
            self.idx.extend(tri.iter().map(|t| base + t));
        }
    }
}

/// The body as a mesh primitive, every vertex bound wholly to one joint.
fn body_mesh(doc: &mut Doc, b: Mesh) -> usize {
    let weights: Vec<Vec<f32>> = (0..b.pos.len()).map(|_| vec![1.0, 0.0, 0.0, 0.0]).collect();
    let floats = |rows, bounded| Accessed::Floats { rows, bounded };
    let positions = doc.accessor(floats(b.pos, true), Some(ARRAY_BUFFER));
    let normals = doc.accessor(floats(b.nrm, false), Some(ARRAY_BUFFER));
    let joints = doc.accessor(Accessed::Joints(b.jnt), Some(ARRAY_BUFFER));
    let weights = doc.accessor(floats(weights, false), Some(ARRAY_BUFFER));
    let indices = doc.accessor(Accessed::Indices(b.idx), Some(ELEMENT_ARRAY_BUFFER));
    let attributes = json!({
        "POSITION": positions, "NORMAL": normals, "JOINTS_0": joints, "WEIGHTS_0": weights
    });
    // Mode left out: triangles, the default.
    let primitive = json!({"attributes": attributes, "indices": indices});
    push(&mut doc.meshes, json!({"name": "body", "primitives": [primitive]}))
}

/// The motion as a `.glb` (see the module's documentation); `name` names the animation.
pub fn to_glb(skel: &Skeleton, joints: &Joints, name: &str) -> Result<Vec<u8>, DataError> {
    if joints.is_empty() || skel.num_joints() > 255 {
        return Err(DataError::Invalid("glTF: a motion of at least one frame is needed".into()));
    }
    let posed = rig::pose(skel, joints);
    let mut doc = Doc::default();
    let (skel_root, at) = joint_nodes(&mut doc, &posed, skel.metres_per_unit);
    let skin = skin(&mut doc, &at, skel_root);
    let mesh = body_mesh(&mut doc, body(&posed.parents, &at));
    let body_node = push(&mut doc.nodes, json!({"name": "body", "mesh": mesh, "skin": skin}));
    animate(&mut doc, &posed, skel, name);
    while !doc.bin.len().is_multiple_of(4) {
        doc.bin.push(0);
    }
    let root = json!({
        "asset": {"generator": format!("diffkfc {}", env!("CARGO_PKG_VERSION")), "version": "2.0"},
        "scene": 0,
        "scenes": [{"name": name, "nodes": [skel_root, body_node]}],
        "nodes": doc.nodes,
        "meshes": doc.meshes,
        "skins": doc.skins,
        "animations": doc.animations,
        "accessors": doc.accessors,
        "bufferViews": doc.buffer_views,
        "buffers": [{"byteLength": doc.bin.len()}],
    });
    let text = serde_json::to_vec(&root).map_err(|e| DataError::Invalid(format!("glTF: {e}")))?;
    Ok(container(text, doc.bin))
}

/// One node per joint in the skeleton's order (rest offsets in metres, frame 0's pose), and
/// the root joint's node and every joint's bind position: the rest pose with the root at the
/// origin (rest rotations are the identity).
fn joint_nodes(doc: &mut Doc, posed: &rig::PosedRig, m: f64) -> (usize, Vec<Vec3>) {
    let n = posed.parents.len();
    let metres = |v: Vec3| -> [f32; 3] { v.map(|x| (x * m) as f32) };
    let mut at = vec![[0.0; 3]; n];
    for j in rig::topological(&posed.parents) {
        let p = posed.parents[j];
        at[j] = if p < 0 { [0.0; 3] } else { quat::add(at[p as usize], posed.rest[j]) };
    }
    for j in 0..n {
        let kids: Vec<usize> = (0..n).filter(|&c| posed.parents[c] == j as i64).collect();
        let t = if posed.parents[j] < 0 { posed.root[0] } else { posed.rest[j] };
        let mut node = json!({
            "name": posed.names[j],
            "translation": metres(t).map(single),
            "rotation": xyzw(posed.local[0][j]).into_iter().map(single).collect::<Vec<_>>(),
        });
        if !kids.is_empty() {
            node["children"] = json!(kids);
        }
        push(&mut doc.nodes, node);
    }
    let skel_root = (0..n).find(|&j| posed.parents[j] < 0).unwrap_or(0);
    (skel_root, at.iter().map(|v| quat::scale(*v, m)).collect())
}

/// The skin over the joint nodes: their inverse bind matrices (translations to the bind
/// positions `at`).
fn skin(doc: &mut Doc, at: &[Vec3], skel_root: usize) -> usize {
    let ibm: Vec<Vec<f32>> = at
        .iter()
        .map(|g| {
            let mut mat = vec![0.0f32; 16];
            (0..4).for_each(|k| mat[k * 5] = 1.0);
            (0..3).for_each(|k| mat[12 + k] = -g[k] as f32);
            mat
        })
        .collect();
    let ibm = doc.accessor(Accessed::Floats { rows: ibm, bounded: false }, None);
    let joints: Vec<usize> = (0..at.len()).collect();
    let skin = json!({
        "name": "diffkfc", "inverseBindMatrices": ibm, "joints": joints, "skeleton": skel_root
    });
    push(&mut doc.skins, skin)
}

/// The animation: the root's translation and every joint's rotation per frame, linear.
fn animate(doc: &mut Doc, posed: &rig::PosedRig, skel: &Skeleton, name: &str) {
    let m = skel.metres_per_unit;
    let times: Vec<Vec<f32>> =
        (0..posed.root.len()).map(|f| vec![(f as f64 / skel.fps) as f32]).collect();
    let input = doc.accessor(Accessed::Floats { rows: times, bounded: true }, None);
    let (mut samplers, mut channels) = (Vec::new(), Vec::new());
    let mut add = |rows: Vec<Vec<f32>>, node: usize, path: &str, doc: &mut Doc| {
        let output = doc.accessor(Accessed::Floats { rows, bounded: false }, None);
        let sampler = push(
            &mut samplers,
            json!({"input": input, "interpolation": "LINEAR", "output": output}),
        );
        channels.push(json!({"sampler": sampler, "target": {"node": node, "path": path}}));
    };
    for j in 0..posed.parents.len() {
        add(rotation_rows(posed, j), j, "rotation", doc);
        if posed.parents[j] < 0 {
            let rows =
                posed.root.iter().map(|r| r.iter().map(|x| (x * m) as f32).collect()).collect();
            add(rows, j, "translation", doc);
        }
    }
    let anim = json!({"name": name, "channels": channels, "samplers": samplers});
    push(&mut doc.animations, anim);
}

/// Joint `j`'s rotation per frame as glTF's (x, y, z, w), sign-continuous so that
/// interpolating between frames takes the short way.
fn rotation_rows(posed: &rig::PosedRig, j: usize) -> Vec<Vec<f32>> {
    let mut prev: Option<Vec<f32>> = None;
    posed
        .local
        .iter()
        .map(|l| {
            let mut q = xyzw(l[j]);
            if prev
                .as_ref()
                .is_some_and(|p| p.iter().zip(&q).map(|(a, b)| a * b).sum::<f32>() < 0.0)
            {
                q.iter_mut().for_each(|x| *x = -*x);
            }
            prev = Some(q.clone());
            q
        })
        .collect()
}

/// The GLB container: a 12-byte header, the JSON chunk (space-padded) and the binary chunk.
fn container(mut text: Vec<u8>, bin: Vec<u8>) -> Vec<u8> {
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

/// Write the motion as `.glb` to `path` (atomically).
pub fn write(path: &Path, skel: &Skeleton, joints: &Joints) -> Result<(), DataError> {
    let name = path.file_stem().map_or("motion".into(), |s| s.to_string_lossy().into_owned());
    crate::write_atomic(path, &to_glb(skel, joints, &name)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::T2M;

    fn walk() -> Joints {
        diffkfc_synth::clip(diffkfc_synth::Body::Legacy, 0, 0).0.joints[..40].to_vec()
    }

    /// Forward kinematics of the file's own nodes and animation at frame `f` (metres).
    fn joints_at(doc: &serde_json::Value, bin: &[u8], f: usize) -> Vec<Vec3> {
        let read = |acc: usize, width: usize, row: usize| -> Vec<f64> {
            let a = &doc["accessors"][acc];
            let v = &doc["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
            let off = v["byteOffset"].as_u64().unwrap() as usize + row * width * 4;
            (0..width)
                .map(|k| {
                    f32::from_le_bytes(bin[off + 4 * k..off + 4 * k + 4].try_into().unwrap()) as f64
                })
                .collect()
        };
        let nodes = doc["nodes"].as_array().unwrap();
        let anim = &doc["animations"][0];
        let mut rot = vec![quat::IDENTITY; 22];
        let mut trans: Vec<Vec3> = (0..22)
            .map(|j| {
                let t = &nodes[j]["translation"];
                [0, 1, 2].map(|k| t[k].as_f64().unwrap())
            })
            .collect();
        for ch in anim["channels"].as_array().unwrap() {
            let node = ch["target"]["node"].as_u64().unwrap() as usize;
            let out = anim["samplers"][ch["sampler"].as_u64().unwrap() as usize]["output"]
                .as_u64()
                .unwrap() as usize;
            if ch["target"]["path"] == "rotation" {
                let q = read(out, 4, f);
                rot[node] = [q[3], q[0], q[1], q[2]];
            } else {
                let t = read(out, 3, f);
                trans[node] = [t[0], t[1], t[2]];
            }
        }
        let parents = T2M.parents();
        let (mut g, mut p) = (vec![quat::IDENTITY; 22], vec![[0.0; 3]; 22]);
        for j in rig::topological(&parents) {
            match parents[j] {
                q if q < 0 => {
                    g[j] = rot[j];
                    p[j] = trans[j];
                }
                q => {
                    let q = q as usize;
                    g[j] = quat::qmul(g[q], rot[j]);
                    p[j] = quat::add(p[q], quat::qrot(g[q], trans[j]));
                }
            }
        }
        p
    }

    #[test]
    fn the_glb_replays_the_motion_and_is_well_formed() {
        let j = walk();
        let glb = to_glb(&T2M, &j, "walk").unwrap();
        assert_eq!(&glb[..4], b"glTF");
        assert_eq!(u32::from_le_bytes(glb[8..12].try_into().unwrap()) as usize, glb.len());
        let json_len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
        let doc: serde_json::Value = serde_json::from_slice(&glb[20..20 + json_len]).unwrap();
        let bin = &glb[20 + json_len + 8..];
        assert_eq!(doc["nodes"].as_array().unwrap().len(), 23);
        assert_eq!(doc["nodes"][7]["name"], "LeftFoot");
        assert_eq!(doc["animations"][0]["channels"].as_array().unwrap().len(), 23);
        // The rig is the BVH's, so a rigid walk comes back to float precision.
        let mut worst: f64 = 0.0;
        for f in [0, 17, 39] {
            for (a, b) in joints_at(&doc, bin, f).iter().zip(&j[f]) {
                worst = worst.max(quat::norm(quat::sub(*a, *b)));
            }
        }
        assert!(worst < 1e-4, "joints off by {worst} m");
        assert!(to_glb(&T2M, &vec![], "x").is_err());
    }
}
