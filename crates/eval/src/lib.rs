//! diffkfc-eval: evaluation. Text-motion metrics (FID, R-precision, MultiModal distance,
//! Diversity, MultiModality) on the embeddings of a contrastively trained evaluator, and
//! keyframe metrics (our definitions; the paper defines them only in words) on joint positions
//! in metres:
//! * K-Err: mean L2 error of the observed joints at keyframe frames, globally and in the
//!   root-relative, facing-normalised frame (the RIC features).
//! * K-TranS: mean acceleration magnitude |x[j+1] - 2x`[j]` + x[j-1]| over frames within l of a
//!   keyframe, averaged over joints and keyframes (real motion gives the reference value).

pub mod error;
pub mod evaluator;
pub mod gait;
pub mod inbetween;
pub mod keyframe_metrics;
pub(crate) mod linalg;
pub mod protocol;
pub mod report;
pub mod rows;
pub mod t2m;
pub mod text_motion;
pub mod train_evaluator;
