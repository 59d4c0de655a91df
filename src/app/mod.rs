//! End-to-end runs behind the CLI commands (library functions, so tests and other programs
//! can call them the way the CLI does), and each command's side of the `vkshade` tool: its
//! clap arguments, the run it starts and the lines it prints. `src/main.rs` only dispatches.

pub mod ao;
pub mod bench;
pub mod btf;
pub mod env;
pub mod frame;
pub mod info;
pub mod scene;
pub mod shaders;
pub mod srbf;
pub mod sss;
pub mod validate;

use crate::error::{Error, Result};
use crate::gpu::{Context, ContextDesc, DeviceSelector, Features, ValidationConfig};
use clap::ValueEnum;
use clap::builder::{PossibleValue, TypedValueParser};
use std::marker::PhantomData;

/// The options every command shares: which device, and whether validation runs. A command
/// makes its context from them once its own arguments are checked (commands that need no
/// GPU never make one).
#[derive(clap::Args, Clone, Debug)]
pub struct Gpu {
    /// Device to use: an index from `vkshade info`, a substring of its name, or "best".
    #[arg(long, global = true, default_value = "best")]
    pub device: DeviceSelector,
    /// Run under the Khronos validation layer (synchronization validation on); any
    /// validation message makes the command fail.
    #[arg(long, global = true)]
    pub validate: bool,
    /// The validation settings to use instead of the default ones (`vkshade validate` sets
    /// them per run: features, and a sink collecting the messages); implies validation.
    #[arg(skip)]
    pub validation: Option<ValidationConfig>,
}

impl Gpu {
    /// A context with the default device features.
    pub fn context(&self) -> Result<Context> {
        self.context_with(Features::default())
    }

    /// A context with optional device features (an error naming a missing one).
    pub fn context_with(&self, features: Features) -> Result<Context> {
        Context::new(&ContextDesc {
            device: self.device.clone(),
            validation: match &self.validation {
                Some(v) => Some(v.clone()),
                None => self.validate.then(ValidationConfig::default),
            },
            features,
            ..ContextDesc::default()
        })
    }
}

/// A count option that must be at least 1 (clap words the refusal around the message,
/// naming the flag: "invalid value '0' for `'--clusters <CLUSTERS>'`: must be at least 1").
pub fn at_least_one(s: &str) -> std::result::Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(format!("not a whole number: {e}")),
    }
}

/// The environment-map loading option of every command that takes `--env`.
#[derive(clap::Args, Clone, Copy, Debug, Default)]
pub struct Hdr {
    /// Refuse environment maps with negative samples below -5% of the map's mean (the
    /// default removes lossy-codec ringing beside a bright sun, keeping each
    /// neighbourhood's energy, and reports what it changed).
    #[arg(long)]
    pub hdr_strict: bool,
}

impl Hdr {
    /// The loader's policy.
    pub fn policy(self) -> crate::scene::envmap::HdrPolicy {
        if self.hdr_strict {
            crate::scene::envmap::HdrPolicy::Strict
        } else {
            crate::scene::envmap::HdrPolicy::Repair
        }
    }
}

/// Loads the environment map `path` under `policy`, saying through `progress` what the
/// ringing repair changed (if anything).
pub fn load_env(
    path: &std::path::Path,
    policy: crate::scene::envmap::HdrPolicy,
    progress: &mut dyn FnMut(&str),
) -> Result<crate::scene::envmap::EnvMap> {
    let map = crate::scene::envmap::EnvMap::load_with(path, policy)?;
    if let Some(r) = &map.repair {
        progress(&format!("{}: {r}", path.display()));
    }
    Ok(map)
}

/// Shuts the context down; with validation, any message collected is an error.
pub fn finish(ctx: Context) -> Result<()> {
    let validated = ctx.validation_enabled();
    let messages = ctx.shutdown()?;
    if validated {
        if messages.is_empty() {
            eprintln!("validation: clean (0 messages)");
        } else {
            for m in &messages {
                eprintln!("{m}");
            }
            return Err(Error::InvalidArgument(format!(
                "{} validation message(s)",
                messages.len()
            )));
        }
    }
    Ok(())
}

/// A progress line on stderr (without breaking a progress counter being drawn).
pub fn progress(line: &str) {
    crate::progress::message(&format!("  {line}"));
}

/// The value parser of an option taking one of `E`'s values: help lists them, and a value
/// that is none of them is refused as "unknown `what` 'value' (a, b or c)". Honours the
/// argument's `ignore_case`.
pub fn choice<E: ValueEnum>(what: &'static str) -> Choice<E> {
    Choice {
        what,
        values: PhantomData,
    }
}

/// See [`choice`].
pub struct Choice<E> {
    what: &'static str,
    values: PhantomData<fn() -> E>,
}

impl<E> Clone for Choice<E> {
    fn clone(&self) -> Self {
        Choice {
            what: self.what,
            values: PhantomData,
        }
    }
}

/// The names of `E`'s values, as "a, b or c".
fn value_names<E: ValueEnum>() -> String {
    let names: Vec<String> = E::value_variants()
        .iter()
        .filter_map(|v| v.to_possible_value())
        .map(|v| v.get_name().to_string())
        .collect();
    match names.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
        _ => names.join(""),
    }
}

impl<E: ValueEnum + Send + Sync + 'static> TypedValueParser for Choice<E> {
    type Value = E;

    fn parse_ref(
        &self,
        cmd: &clap::Command,
        arg: Option<&clap::Arg>,
        value: &std::ffi::OsStr,
    ) -> std::result::Result<E, clap::Error> {
        let what = self.what;
        let ignore_case = arg.is_some_and(clap::Arg::is_ignore_case_set);
        // A plain parsing function: clap words its refusal ("invalid value 'x' for '--y'")
        // around the message.
        let parse = move |s: &str| {
            E::from_str(s, ignore_case)
                .map_err(|_| format!("unknown {what} '{s}' ({})", value_names::<E>()))
        };
        parse.parse_ref(cmd, arg, value)
    }

    fn possible_values(&self) -> Option<Box<dyn Iterator<Item = PossibleValue> + '_>> {
        // Names only: the option's own help says what each one means.
        Some(Box::new(
            E::value_variants()
                .iter()
                .filter_map(|v| v.to_possible_value())
                .map(|v| v.help(None::<&'static str>)),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::choice;
    use crate::kernels::ao::Blend;
    use crate::kernels::sss::ProfileKind;

    fn command() -> clap::Command {
        clap::Command::new("t")
            .arg(
                clap::Arg::new("blend")
                    .long("blend")
                    .value_parser(choice::<Blend>("blend")),
            )
            .arg(
                clap::Arg::new("profile")
                    .long("profile")
                    .ignore_case(true)
                    .value_parser(choice::<ProfileKind>("profile")),
            )
    }

    #[test]
    fn a_choice_parses_its_values_and_names_what_it_refuses() {
        let m = command()
            .try_get_matches_from(["t", "--blend", "sum", "--profile", "BURLEY"])
            .unwrap();
        assert_eq!(m.get_one::<Blend>("blend"), Some(&Blend::Sum));
        assert_eq!(
            m.get_one::<ProfileKind>("profile"),
            Some(&ProfileKind::Burley)
        );
        let e = command()
            .try_get_matches_from(["t", "--blend", "max"])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("unknown blend 'max' (product, sum or mask)"),
            "{e}"
        );
        // Case matters unless the option says otherwise.
        assert!(
            command()
                .try_get_matches_from(["t", "--blend", "SUM"])
                .is_err()
        );
        let help = command().render_help().to_string();
        assert!(
            help.contains("[possible values: product, sum, mask]"),
            "{help}"
        );
    }
}
