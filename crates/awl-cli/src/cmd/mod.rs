//! One module per subcommand.

pub mod calibrate;
pub mod common;
pub mod demo;
pub mod evaluate;
pub mod fuse;
pub mod import;
pub mod info;
pub mod pierce;
pub mod plan_views;
pub mod register;
pub mod send;
pub mod simulate;
pub mod tags;
pub mod trial;
