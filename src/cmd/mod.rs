//! Subcommands with a module of their own: the arguments and what the command
//! prints, around one library call; `args` holds what they share.

pub mod args;
pub mod bench;
pub mod cache;
pub mod calibrate;
pub mod compare;
pub mod composite;
pub mod convert;
pub mod corpus;
pub mod cube;
pub mod demo;
pub mod eval;
pub mod export;
pub mod fisheye;
pub mod init;
pub mod localize;
pub mod prefilter;
pub mod render;
pub mod rotate;
pub mod run;
pub mod tonemap;
pub mod view;

/// The specular cube's size, mips and samples, as `prefilter` and `export` take
/// them.
#[derive(clap::Args, Clone, Copy)]
pub struct CubeArgs {
    /// Specular face size of mip 0.
    #[arg(long, default_value_t = lumiprobe::ibl::SpecularOptions::default().face_size)]
    pub face_size: usize,
    /// Specular mips (roughness i / (mips - 1)).
    #[arg(long, default_value_t = lumiprobe::ibl::SpecularOptions::default().mip_count)]
    pub mips: usize,
    /// GGX samples per texel.
    #[arg(long, default_value_t = lumiprobe::ibl::SpecularOptions::default().samples)]
    pub samples: usize,
}
