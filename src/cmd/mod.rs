//! Subcommands with a module of their own: the arguments and what the command
//! prints, around one library call. (The older commands still live in
//! `main.rs`; they move here as they are touched.)

pub mod cache;
pub mod export;
