//! Motions as glTF 2.0 binary (`.glb`): the rig the BVH export fits ([`rig::pose`]: T-pose
//! rest, common joint names, the motion's bone lengths) as a skin of joint nodes in metres, Y
//! up; one animation at the skeleton's rate (the root's translation and every joint's rotation,
//! linear); and a simple body, a box along every bone bound rigidly to it, so that any viewer
//! shows something. The JSON is gltf-json's; the container is the format's two chunks.

use std::collections::BTreeMap;
use std::path::Path;

use gltf_json::accessor::{ComponentType, GenericComponentType, Type};
use gltf_json::animation::{Channel, Interpolation, Property, Sampler, Target};
use gltf_json::buffer::{self, View};
use gltf_json::mesh::{Mode, Primitive, Semantic};
use gltf_json::scene::UnitQuaternion;
use gltf_json::validation::{Checked::Valid, USize64};
use gltf_json::{Accessor, Animation, Index, Mesh, Node, Root, Scene, Skin};
use serde_json::json;

use crate::io::rig;
use crate::motion::quat::{self, Quat, Vec3};
use crate::motion::representation::Joints;
use crate::motion::skeleton::Skeleton;
use crate::DataError;

/// Half the width of a bone's box (metres); leaves (head, hands, toes) get a cube of this size.
const BONE_HALF_WIDTH: f32 = 0.035;

/// The binary buffer as it is filled: views are 4-byte aligned.
struct Bin {
    data: Vec<u8>,
}

impl Bin {
    /// Append `values` as a view (with `target` for vertex data) and an accessor over it.
    fn accessor(
        &mut self,
        root: &mut Root,
        values: Accessed,
        target: Option<buffer::Target>,
    ) -> Index<Accessor> {
        while !self.data.len().is_multiple_of(4) {
            self.data.push(0);
        }
        let offset = self.data.len();
        let (count, component, type_, bounds) = values.write(&mut self.data);
        let view = root.push(View {
            buffer: Index::new(0),
            byte_length: USize64::from(self.data.len() - offset),
            byte_offset: Some(USize64::from(offset)),
            byte_stride: None,
            name: None,
            target: target.map(Valid),
            extensions: None,
            extras: Default::default(),
        });
        root.push(Accessor {
            buffer_view: Some(view),
            byte_offset: None,
            count: USize64::from(count),
            component_type: Valid(GenericComponentType(component)),
            extensions: None,
            extras: Default::default(),
            type_: Valid(type_),
            min: bounds.as_ref().map(|b| json!(b.0)),
            max: bounds.map(|b| json!(b.1)),
            name: None,
            normalized: false,
            sparse: None,
        })
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
    fn write(self, out: &mut Vec<u8>) -> (usize, ComponentType, Type, Bounds) {
        match self {
            Accessed::Floats { rows, bounded } => {
                let width = rows.first().map_or(1, Vec::len);
                let type_ = match width {
                    1 => Type::Scalar,
                    3 => Type::Vec3,
                    4 => Type::Vec4,
                    _ => Type::Mat4,
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
                (rows.len(), ComponentType::F32, type_, bounded.then_some((lo, hi)))
            }
            Accessed::Indices(ix) => {
                ix.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
                (ix.len(), ComponentType::U16, Type::Scalar, None)
            }
            Accessed::Joints(js) => {
                js.iter().for_each(|j| out.extend_from_slice(j));
                (js.len(), ComponentType::U8, Type::Vec4, None)
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
struct Body {
    pos: Vec<Vec<f32>>,
    nrm: Vec<Vec<f32>>,
    jnt: Vec<[u8; 4]>,
    idx: Vec<u16>,
}

/// The body: a box from each joint's parent to it, bound to the parent, and a cube at each leaf
/// bound to it (positions, normals, joints, indices), in the bind pose `at` (metres).
fn body(parents: &[i64], at: &[Vec3]) -> Body {
    let mut body = Body { pos: Vec::new(), nrm: Vec::new(), jnt: Vec::new(), idx: Vec::new() };
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

impl Body {
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
fn body_mesh(root: &mut Root, bin: &mut Bin, b: Body) -> Index<Mesh> {
    let weights: Vec<Vec<f32>> = (0..b.pos.len()).map(|_| vec![1.0, 0.0, 0.0, 0.0]).collect();
    let vertex = Some(buffer::Target::ArrayBuffer);
    let floats = |rows, bounded| Accessed::Floats { rows, bounded };
    let mut attributes = BTreeMap::new();
    for (semantic, values) in [
        (Semantic::Positions, floats(b.pos, true)),
        (Semantic::Normals, floats(b.nrm, false)),
        (Semantic::Joints(0), Accessed::Joints(b.jnt)),
        (Semantic::Weights(0), floats(weights, false)),
    ] {
        attributes.insert(Valid(semantic), bin.accessor(root, values, vertex));
    }
    let indices =
        bin.accessor(root, Accessed::Indices(b.idx), Some(buffer::Target::ElementArrayBuffer));
    root.push(Mesh {
        extensions: None,
        extras: Default::default(),
        name: Some("body".into()),
        primitives: vec![Primitive {
            attributes,
            extensions: None,
            extras: Default::default(),
            indices: Some(indices),
            material: None,
            mode: Valid(Mode::Triangles),
            targets: None,
        }],
        weights: None,
    })
}

/// The motion as a `.glb` (see the module's documentation); `name` names the animation.
pub fn to_glb(skel: &Skeleton, joints: &Joints, name: &str) -> Result<Vec<u8>, DataError> {
    if joints.is_empty() || skel.num_joints() > 255 {
        return Err(DataError::Invalid("glTF: a motion of at least one frame is needed".into()));
    }
    let posed = rig::pose(skel, joints);
    let mut root = Root {
        asset: gltf_json::Asset {
            copyright: None,
            extensions: None,
            extras: Default::default(),
            generator: Some(format!("diffkfc {}", env!("CARGO_PKG_VERSION"))),
            min_version: None,
            version: "2.0".into(),
        },
        ..Default::default()
    };
    let mut bin = Bin { data: Vec::new() };
    let (skel_root, at) = joint_nodes(&mut root, &posed, skel.metres_per_unit);
    let skin = skin(&mut root, &mut bin, &at, skel_root);
    let mesh = body_mesh(&mut root, &mut bin, body(&posed.parents, &at));
    let body_node = root.push(Node {
        name: Some("body".into()),
        mesh: Some(mesh),
        skin: Some(skin),
        ..Default::default()
    });
    animate(&mut root, &mut bin, &posed, skel, name);
    let scene = root.push(Scene {
        extensions: None,
        extras: Default::default(),
        name: Some(name.into()),
        nodes: vec![skel_root, body_node],
    });
    root.scene = Some(scene);
    while !bin.data.len().is_multiple_of(4) {
        bin.data.push(0);
    }
    root.push(gltf_json::Buffer {
        byte_length: USize64::from(bin.data.len()),
        name: None,
        uri: None,
        extensions: None,
        extras: Default::default(),
    });
    let text = root.to_vec().map_err(|e| DataError::Invalid(format!("glTF: {e}")))?;
    Ok(container(text, bin.data))
}

/// One node per joint in the skeleton's order (rest offsets in metres, frame 0's pose), and
/// the root joint's node and every joint's bind position: the rest pose with the root at the
/// origin (rest rotations are the identity).
fn joint_nodes(root: &mut Root, posed: &rig::PosedRig, m: f64) -> (Index<Node>, Vec<Vec3>) {
    let n = posed.parents.len();
    let metres = |v: Vec3| -> [f32; 3] { v.map(|x| (x * m) as f32) };
    let mut at = vec![[0.0; 3]; n];
    for j in rig::topological(&posed.parents) {
        let p = posed.parents[j];
        at[j] = if p < 0 { [0.0; 3] } else { quat::add(at[p as usize], posed.rest[j]) };
    }
    for j in 0..n {
        let kids: Vec<Index<Node>> = (0..n)
            .filter(|&c| posed.parents[c] == j as i64)
            .map(|c| Index::new(c as u32))
            .collect();
        let t = if posed.parents[j] < 0 { posed.root[0] } else { posed.rest[j] };
        let q = xyzw(posed.local[0][j]);
        root.push(Node {
            name: Some(posed.names[j].to_string()),
            translation: Some(metres(t)),
            rotation: Some(UnitQuaternion([q[0], q[1], q[2], q[3]])),
            children: (!kids.is_empty()).then_some(kids),
            ..Default::default()
        });
    }
    let skel_root = (0..n).find(|&j| posed.parents[j] < 0).unwrap_or(0);
    (Index::new(skel_root as u32), at.iter().map(|v| quat::scale(*v, m)).collect())
}

/// The skin over the joint nodes: their inverse bind matrices (translations to the bind
/// positions `at`).
fn skin(root: &mut Root, bin: &mut Bin, at: &[Vec3], skel_root: Index<Node>) -> Index<Skin> {
    let ibm: Vec<Vec<f32>> = at
        .iter()
        .map(|g| {
            let mut mat = vec![0.0f32; 16];
            (0..4).for_each(|k| mat[k * 5] = 1.0);
            (0..3).for_each(|k| mat[12 + k] = -g[k] as f32);
            mat
        })
        .collect();
    let ibm = bin.accessor(root, Accessed::Floats { rows: ibm, bounded: false }, None);
    root.push(Skin {
        extensions: None,
        extras: Default::default(),
        inverse_bind_matrices: Some(ibm),
        joints: (0..at.len()).map(|j| Index::new(j as u32)).collect(),
        name: Some("diffkfc".into()),
        skeleton: Some(skel_root),
    })
}

/// The animation: the root's translation and every joint's rotation per frame, linear.
fn animate(root: &mut Root, bin: &mut Bin, posed: &rig::PosedRig, skel: &Skeleton, name: &str) {
    let m = skel.metres_per_unit;
    let times: Vec<Vec<f32>> =
        (0..posed.root.len()).map(|f| vec![(f as f64 / skel.fps) as f32]).collect();
    let input = bin.accessor(root, Accessed::Floats { rows: times, bounded: true }, None);
    let mut samplers = Vec::new();
    let mut channels = Vec::new();
    let mut add =
        |rows: Vec<Vec<f32>>, node: usize, path: Property, bin: &mut Bin, root: &mut Root| {
            let output = bin.accessor(root, Accessed::Floats { rows, bounded: false }, None);
            samplers.push(Sampler {
                extensions: None,
                extras: Default::default(),
                input,
                interpolation: Valid(Interpolation::Linear),
                output,
            });
            channels.push(Channel {
                sampler: Index::new(samplers.len() as u32 - 1),
                target: Target {
                    extensions: None,
                    extras: Default::default(),
                    node: Index::new(node as u32),
                    path: Valid(path),
                },
                extensions: None,
                extras: Default::default(),
            });
        };
    for j in 0..posed.parents.len() {
        let rows = rotation_rows(posed, j);
        add(rows, j, Property::Rotation, bin, root);
        if posed.parents[j] < 0 {
            let rows =
                posed.root.iter().map(|r| r.iter().map(|x| (x * m) as f32).collect()).collect();
            add(rows, j, Property::Translation, bin, root);
        }
    }
    root.push(Animation {
        extensions: None,
        extras: Default::default(),
        channels,
        name: Some(name.into()),
        samplers,
    });
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
