//! `vkshade spheretree build` and `vkshade mesh info`: the scene tools, and the sphere-tree
//! options `vkshade ao` shares with them.

use crate::error::{Error, Result};
use crate::scene::spheretree::{BuildConfig, Fit, FitReport};
use std::path::{Path, PathBuf};

/// How a sphere tree is built (`spheretree build`, and `ao` without `--tree`).
#[derive(clap::Args, Clone, Debug)]
pub struct TreeOpts {
    /// Levels below the root when building a tree (3 gives 8/64/512 spheres).
    #[arg(long, default_value_t = 3)]
    pub depth: u32,
    /// Branch factor when building a tree.
    #[arg(long, default_value_t = 8)]
    pub branch: u32,
    /// Sphere fit: `volume` (same volume as the cluster) or `bounding` (covers it).
    #[arg(long, default_value = "volume", value_parser = super::choice::<Fit>("fit"))]
    pub fit: Fit,
    /// Interior samples (voxels) to cluster.
    #[arg(long, default_value_t = 200_000)]
    pub samples: usize,
}

impl TreeOpts {
    /// The builder settings these options give.
    pub fn config(&self) -> BuildConfig {
        BuildConfig {
            depth: self.depth,
            branch: self.branch,
            fit: self.fit,
            samples: self.samples,
            ..Default::default()
        }
    }
}

/// The subcommands of `vkshade spheretree`.
#[derive(clap::Subcommand, Clone, Debug)]
pub enum TreeCommand {
    /// Build a sphere tree for a mesh (bind pose) and report how tightly each level fits.
    Build {
        mesh: PathBuf,
        /// Output .sph file.
        #[arg(short, long)]
        out: PathBuf,
        #[command(flatten)]
        opts: TreeOpts,
        /// Also write the fit report as JSON.
        #[arg(long)]
        report: Option<PathBuf>,
    },
}

impl TreeCommand {
    /// Runs `vkshade spheretree build`.
    pub fn run(&self) -> Result<()> {
        match self {
            TreeCommand::Build {
                mesh,
                out,
                opts,
                report,
            } => build_tree(mesh, out, opts, report.as_deref()),
        }
    }
}

/// Builds the tree of `mesh`, writes it to `out` and prints the fit of each level.
fn build_tree(mesh: &Path, out: &Path, opts: &TreeOpts, report: Option<&Path>) -> Result<()> {
    crate::io::check_writable(out)?;
    let c = crate::scene::load(mesh)?;
    let t = std::time::Instant::now();
    let (tree, fit) = crate::scene::SphereTree::build(&c.mesh, &opts.config())?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    // A mesh with huge coordinates can give an infinite radius: never write what
    // `ao --tree` would refuse.
    let bad = tree
        .spheres
        .iter()
        .zip(&tree.importance)
        .enumerate()
        .find_map(|(i, (sp, imp))| {
            let fields = [
                ("centre x", sp.center.x),
                ("centre y", sp.center.y),
                ("centre z", sp.center.z),
                ("radius", sp.radius),
                ("importance", *imp),
            ];
            fields
                .into_iter()
                .find(|(_, v)| !v.is_finite())
                .map(|(what, v)| format!("sphere {i} has a non-finite {what} ({v})"))
        });
    if let Some(m) = bad {
        return Err(Error::input(
            out,
            format!(
                "not written: the tree of {} is not finite: {m}",
                mesh.display()
            ),
        ));
    }
    tree.write_sph(out)?;
    println!(
        "{}: {} levels below the root, branch {}, fit {:?}, from {} ({} cells of {:.4}), {ms:.0} ms",
        mesh.display(),
        tree.levels - 1,
        tree.branch,
        opts.fit,
        fit.samples_from,
        fit.interior_cells,
        fit.cell_size
    );
    print_fit(&fit);
    if let Some(path) = report {
        crate::io::write_json(path, &fit)?;
        println!("wrote {}", path.display());
    }
    println!("wrote {}", out.display());
    Ok(())
}

/// The fit table: per level, spheres and how much of the volume and surface they cover.
fn print_fit(fit: &FitReport) {
    println!("level  spheres  volume coverage  volume excess  surface coverage");
    for l in &fit.levels {
        println!(
            "{:>5}  {:>7}  {:>14.1}%  {:>12.1}%  {:>15.1}%",
            l.level,
            l.spheres,
            100.0 * l.volume_coverage,
            100.0 * l.volume_excess,
            100.0 * l.surface_coverage
        );
    }
}

/// The subcommands of `vkshade mesh`.
#[derive(clap::Subcommand, Clone, Debug)]
pub enum MeshCommand {
    /// Load a mesh, validate it, and report what was found and repaired.
    Info { mesh: PathBuf },
}

impl MeshCommand {
    /// Runs `vkshade mesh info`.
    pub fn run(&self) -> Result<()> {
        match self {
            MeshCommand::Info { mesh } => mesh_info(mesh),
        }
    }
}

/// Prints the loader's report, the rig and the animations of `mesh`, and its bounds.
fn mesh_info(mesh: &Path) -> Result<()> {
    let c = crate::scene::load(mesh)?;
    println!(
        "{}",
        serde_json::to_string_pretty(&c.mesh.report).unwrap_or_default()
    );
    println!("skinned: {}, joints: {}", c.skinned, c.rig.joints.len());
    for a in &c.animations {
        println!(
            "animation '{}': {:.3} s, {} channels",
            a.name,
            a.duration,
            a.channels.len()
        );
    }
    let (lo, hi) = c.mesh.bounds();
    println!("bounds: {lo} .. {hi}");
    Ok(())
}
