//! Files: `.npy` arrays, BVH (parsing, rig import and export), motion and keyframe files a
//! user hands us, caption files, and writing outputs atomically, one file or a whole folder, into folders a command owns.

pub mod atomic;
pub mod bvh;
pub mod gltf;
pub mod keyframe_file;
pub mod motion_file;
pub mod npy;
pub mod output_set;
pub mod ownership;
pub mod rig;
mod rig_names;
pub mod texts;
