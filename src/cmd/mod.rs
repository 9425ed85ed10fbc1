//! Subcommands with a module of their own: the arguments and what the command
//! prints, around one library call. (The older commands still live in
//! `main.rs`; they move here as they are touched.)

pub mod cache;
pub mod export;

/// The specular cube's size, mips and samples, as `prefilter` and `export` take
/// them.
#[derive(clap::Args, Clone, Copy)]
pub struct CubeArgs {
    /// Specular face size of mip 0.
    #[arg(long, default_value_t = 128)]
    pub face_size: usize,
    /// Specular mips (roughness i / (mips - 1)).
    #[arg(long, default_value_t = 6)]
    pub mips: usize,
    /// GGX samples per texel.
    #[arg(long, default_value_t = 256)]
    pub samples: usize,
}
