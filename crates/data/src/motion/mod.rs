//! Human motion in the HumanML3D representation: skeletons, rotations, the 263-feature
//! representation and its inverse, single poses, the root's place and heading (keys, absolute
//! angles and places, paths, dense tracks), and physical plausibility and size checks.

pub mod magnitude;
pub mod plausibility;
pub(crate) mod pose;
pub mod quat;
pub mod representation;
pub mod root_key;
pub mod root_track;
pub mod skeleton;
pub mod travel;
