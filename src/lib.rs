//! lumiprobe: HDR light probes at every frame of a 360° SDR walk.
//!
//! Data flows one way: a captured scene (sparse HDR probes, SDR frames, poses) is
//! read by [`scene`], a method ([`warp`]) predicts an HDR probe per frame, and
//! [`eval`] scores predictions against ground truth. [`image`] holds the image types
//! and file formats, [`sphere`] the panorama geometry, [`tonemap`] tone mapping and
//! camera responses, [`cv`] the one bridge to the C++/OpenCV layer.

pub mod capture;
pub mod cv;
pub mod error;
pub mod eval;
pub mod ffi;
pub mod flow;
pub mod fsutil;
pub mod fusion;
pub mod ibl;
pub mod image;
pub mod pipeline;
pub mod render;
pub mod scene;
pub mod sphere;
pub mod synth;
pub mod tonemap;
pub mod warp;

pub use error::{Error, Result};
pub use image::{HdrImage, SdrImage};
