//! `vkshade shaders build|check`: the committed SPIR-V in spv/ against the GLSL in glsl/.

use crate::error::{Error, Result};
use crate::shaders::ModuleState as M;
use std::path::PathBuf;

/// The subcommands of `vkshade shaders`.
#[derive(clap::Subcommand, Clone, Debug)]
pub enum Command {
    /// Compile every glsl/**/*.comp into spv/ (rewriting only what changed).
    Build {
        /// Source tree holding glsl/ and spv/ (default: the tree vkshade was built from).
        #[arg(long)]
        root: Option<PathBuf>,
    },
    /// Fail if any spv/ module is missing, stale or orphaned.
    Check {
        #[arg(long)]
        root: Option<PathBuf>,
    },
}

impl Command {
    /// Prints each module's state; fails naming the modules that are out of date.
    pub fn run(&self) -> Result<()> {
        let (root, write) = match self {
            Command::Build { root } => (root, true),
            Command::Check { root } => (root, false),
        };
        let root = root.clone().unwrap_or_else(crate::shaders::source_root);
        let statuses =
            crate::shaders::build_all(&root, write, crate::kernels::generated_includes())?;
        let mut bad = Vec::new();
        for s in &statuses {
            println!("{:<10} {}", format!("{:?}", s.state).to_lowercase(), s.name);
            if matches!(s.state, M::Stale | M::Missing) || (!write && s.state == M::Orphan) {
                bad.push(s.name.clone());
            }
        }
        if bad.is_empty() {
            Ok(())
        } else {
            Err(Error::InvalidArgument(format!(
                "spv/ is out of date for {}; run `vkshade shaders build`",
                bad.join(", ")
            )))
        }
    }
}
