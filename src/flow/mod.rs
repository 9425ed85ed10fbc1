//! The flow method: dense optical flow from the SDR frame to its neighbouring probes,
//! motion confidence, and graph-cut fusion of the warped probes.

pub mod dense;
pub mod distant;
pub mod graphcut;
pub mod method;
