//! End-to-end runs behind the CLI commands (library functions, so tests and other programs
//! can call them the way the CLI does).

pub mod ao;
pub mod btf;
pub mod srbf;
pub mod sss;
