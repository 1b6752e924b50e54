//! What the commands share: the estimator help, flag errors, vector parsing, progress bars.

/// A library argument error, with its name spelled as the flag: the library names an option in
/// kebab case (`deep-error`), the command line types `--deep-error`.
pub fn flag_error(e: umbra::Error) -> umbra::Error {
    match e {
        umbra::Error::InvalidArgument { name, reason } => umbra::Error::InvalidArgument {
            name: flag(&name),
            reason,
        },
        umbra::Error::Conflict { names, reason } => umbra::Error::Conflict {
            names: names.iter().map(|n| flag(n)).collect(),
            reason,
        },
        other => other,
    }
}

/// The command line's spelling of the library's option `name` (`deep-error` or `deep_error`
/// to `--deep-error`).
pub fn flag(name: &str) -> String {
    format!("--{}", name.trim_start_matches("--").replace('_', "-"))
}

/// How the command line words an error it prints: an existing output says how to replace it.
pub fn worded(e: &anyhow::Error) -> String {
    // An option the library names in words (a level set's), as the command line spells it.
    let text = format!("{e:#}").replace(
        umbra::error::LEVELSET_OPTION,
        "--levelset solid; levelset = \"solid\" in a job file",
    );
    match e.root_cause().downcast_ref::<umbra::Error>() {
        Some(umbra::Error::Exists { .. }) => format!("{text} (use --force to overwrite)"),
        _ => text,
    }
}

/// `--estimator`'s long help: one line per registered estimator.
pub fn estimator_help() -> String {
    let mut s = String::from("Estimator (default regular, exact). One of:\n");
    for spec in umbra::estimate::REGISTRY {
        let params: Vec<String> = spec
            .params
            .iter()
            .map(|p| format!("--{} (default {}, {})", p.name, p.default, p.unit))
            .collect();
        s.push_str(&format!(
            "  {} [{}] {}{}\n",
            spec.name,
            spec.kind.as_str(),
            spec.summary,
            if params.is_empty() {
                String::new()
            } else {
                format!("; {}", params.join(", "))
            }
        ));
    }
    s
}

pub use umbra::request::parse_vec3;

/// A progress bar on stderr over `len` units with `template` (indicatif syntax), hidden with
/// `--quiet` or when stderr is not a terminal.
pub fn progress_bar(quiet: bool, template: &str, len: u64) -> indicatif::ProgressBar {
    use std::io::IsTerminal;
    if quiet || !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let style = indicatif::ProgressStyle::with_template(template)
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .progress_chars("=> ");
    indicatif::ProgressBar::new(len).with_style(style)
}

/// How a long command shows its progress (`--progress`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum ProgressMode {
    /// Open Job Description's lines when run by an OpenJD session (it sets
    /// OPENJD_SESSION_WORKING_DIR), else a bar on a terminal; nothing with --quiet.
    #[default]
    Auto,
    /// A bar on stderr when it is a terminal (nothing with --quiet).
    Bar,
    /// `openjd_progress: <percent>` lines on stderr (Open Job Description, Deadline Cloud).
    Openjd,
    /// `ALF_PROGRESS <n>%` lines on stdout (Houdini's Alfred-style progress: Tractor, HQueue,
    /// Deadline's Houdini plugins).
    Alf,
    /// `Progress: <n>%` lines on stdout (Deadline plugins' stdout handlers).
    Deadline,
    /// Nothing.
    None,
}

/// `--progress`, shared by the commands that run long work.
#[derive(Debug, Clone, Copy, clap::Args)]
pub struct ProgressArgs {
    /// How progress is shown: `auto` (a bar on a terminal; Open Job Description's lines under
    /// an OpenJD session), `bar`, or a farm engine's lines, printed at each whole percent:
    /// `openjd` (`openjd_progress: N`, stderr), `alf` (`ALF_PROGRESS N%`, stdout), `deadline`
    /// (`Progress: N%`, stdout); `none`. An engine named here prints even with --quiet.
    #[arg(long, value_enum, default_value_t = ProgressMode::Auto, value_name = "HOW")]
    pub progress: ProgressMode,
}

/// What a command draws its progress with.
enum Shown {
    /// An indicatif bar on stderr, made when the work starts (its length and labels are the
    /// library's).
    Bar(std::sync::OnceLock<indicatif::ProgressBar>),
    /// A farm engine's lines.
    Lines(umbra::progress::Lines<Box<dyn std::io::Write + Send>>),
    /// Nothing.
    Nothing,
}

/// The CLI's [`umbra::progress::Progress`]: a bar or a farm engine's lines, as `--progress`
/// and `--quiet` say. `template` makes the bar's indicatif template from the work.
pub struct CliProgress {
    shown: Shown,
    template: fn(&umbra::progress::Work) -> String,
}

/// The bar of a bake: `{what} [bar] percent`, with the units counted when they are pixels or
/// voxels.
pub fn bake_template(w: &umbra::progress::Work) -> String {
    match w.unit {
        Some(u) => format!(
            "{{spinner}} {} [{{bar:30}}] {{percent:>3}}% {{human_pos}}/{{human_len}} {u}, eta {{eta}}",
            w.what
        ),
        None => format!("{{spinner}} {} [{{bar:30}}] {{percent:>3}}%, eta {{eta}}", w.what),
    }
}

impl CliProgress {
    /// The progress `mode` asks for (`quiet`: no bar, and no lines unless an engine is named).
    pub fn new(
        mode: ProgressMode,
        quiet: bool,
        template: fn(&umbra::progress::Work) -> String,
    ) -> Self {
        use umbra::progress::{Engine, Lines, Stream};
        let engine = match mode {
            ProgressMode::Auto if quiet => None,
            ProgressMode::Auto => Engine::detect(|k| std::env::var_os(k)),
            ProgressMode::Openjd => Some(Engine::Openjd),
            ProgressMode::Alf => Some(Engine::Alf),
            ProgressMode::Deadline => Some(Engine::Deadline),
            ProgressMode::Bar | ProgressMode::None => None,
        };
        let shown = match (engine, mode) {
            (Some(e), _) => {
                let out: Box<dyn std::io::Write + Send> = match e.stream() {
                    Stream::Stdout => Box::new(std::io::stdout()),
                    Stream::Stderr => Box::new(std::io::stderr()),
                };
                Shown::Lines(Lines::new(e, out))
            }
            (None, ProgressMode::Auto | ProgressMode::Bar) if !quiet => {
                Shown::Bar(std::sync::OnceLock::new())
            }
            _ => Shown::Nothing,
        };
        Self { shown, template }
    }

    /// The bar, once the work started (to print above it, or set its message).
    pub fn bar(&self) -> Option<&indicatif::ProgressBar> {
        match &self.shown {
            Shown::Bar(b) => b.get(),
            _ => None,
        }
    }

    /// The work is over: the bar is cleared (lines stay).
    pub fn finish(&self) {
        if let Some(b) = self.bar() {
            b.finish_and_clear();
        }
    }
}

impl umbra::progress::Progress for CliProgress {
    fn start(&self, work: &umbra::progress::Work) {
        match &self.shown {
            Shown::Bar(b) => {
                let _ = b.set(progress_bar(false, &(self.template)(work), work.units));
            }
            Shown::Lines(l) => l.start(work),
            Shown::Nothing => {}
        }
    }

    fn advance(&self, units: u64) {
        match &self.shown {
            Shown::Bar(b) => {
                if let Some(b) = b.get() {
                    b.inc(units);
                }
            }
            Shown::Lines(l) => l.advance(units),
            Shown::Nothing => {}
        }
    }
}

/// A number as a person reads it: integers plainly, others with 6 significant digits
/// (scientific where that is shorter), `inf`/`nan` as words.
pub fn num(v: f64) -> String {
    if v.is_nan() {
        return "nan".into();
    }
    if v.is_infinite() {
        return if v > 0.0 { "inf" } else { "-inf" }.into();
    }
    if v == v.trunc() && v.abs() < 1e15 {
        return format!("{v:.0}");
    }
    let a = v.abs();
    if !(1e-4..1e6).contains(&a) {
        return format!("{v:.5e}");
    }
    let s = format!("{v:.6}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}
