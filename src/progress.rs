//! How long work says how far it has got: one trait, [`Progress`], that every bake, transmittance
//! volume and batch run reports to, from worker threads. The library only calls it; each front
//! end draws it its own way (the CLI an indicatif bar, the Python module a callback, a batch run
//! aggregates its tasks), and [`Lines`] prints the progress lines a farm engine reads
//! ([`Engine`]: Open Job Description, ALF/Houdini/Tractor, Deadline).
//!
//! A closure `Fn(u64) + Sync` is a [`Progress`] that hears only [`Progress::advance`], so
//! `&|_| {}` (nothing) and `&|n| bar.inc(n)` still work wherever a `&dyn Progress` is asked for.

use std::io::Write;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

/// The work a [`Progress`] is told about when it starts: how many units in all, and what they
/// are (for a display's labels).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Work {
    /// Units in all: [`Progress::advance`] adds up to this.
    pub units: u64,
    /// What is being done, as a display would label it (`baking`, `baking in parts`,
    /// `transmittance volume`, `batch`).
    pub what: &'static str,
    /// What a unit is when a display may count them (`px`, `voxels`); `None` when units are
    /// weights (a deep map's passes by cost, a batch's tasks by share) that only make sense as a
    /// fraction.
    pub unit: Option<&'static str>,
}

/// What long work reports as it goes. Called from worker threads, in any order; the units of
/// every [`Progress::advance`] add up to the [`Work::units`] of the [`Progress::start`] before
/// them (a failure may stop short).
pub trait Progress: Sync {
    /// The work starts. Called once, before any [`Progress::advance`].
    fn start(&self, _work: &Work) {}
    /// `units` more of the work are done.
    fn advance(&self, _units: u64) {}
}

/// A closure hears the units done (and not the start).
impl<F: Fn(u64) + Sync> Progress for F {
    fn advance(&self, units: u64) {
        self(units);
    }
}

/// A [`Progress`] that reports nothing.
#[derive(Debug, Clone, Copy, Default)]
pub struct Silent;

impl Progress for Silent {}

/// The farm engines whose progress lines [`Lines`] prints.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Engine {
    /// Open Job Description (AWS Deadline Cloud, `openjd run`): `openjd_progress: <percent>`,
    /// a line the session's action filter reads from the action's output (the specification's
    /// "Stdout/Stderr Messages": a number from 0 to 100).
    Openjd,
    /// The Alfred-style line Houdini's ROPs print (`ALF_PROGRESS <n>%`), which Tractor and
    /// Houdini-aware Deadline and HQueue plugins read from stdout.
    Alf,
    /// The `Progress: <n>%` line Deadline plugins' stdout handlers match
    /// (`.*Progress: (\d+)%.*`).
    Deadline,
}

/// Which standard stream an engine's lines go to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stream {
    /// Standard output.
    Stdout,
    /// Standard error.
    Stderr,
}

impl Engine {
    /// The environment variable an Open Job Description session sets for every action it
    /// runs (its working directory; the specification's "Session Environment Variables").
    pub const OPENJD_SESSION: &'static str = "OPENJD_SESSION_WORKING_DIR";

    /// The engine's progress line at `percent` (0 to 100), without the newline.
    #[must_use]
    pub fn line(self, percent: u8) -> String {
        let p = percent.min(100);
        match self {
            Self::Openjd => format!("openjd_progress: {p}"),
            Self::Alf => format!("ALF_PROGRESS {p}%"),
            Self::Deadline => format!("Progress: {p}%"),
        }
    }

    /// Where the engine reads its lines: ALF and Deadline handlers read standard output;
    /// an Open Job Description session reads both streams of an action, and its lines go to
    /// standard error so that standard output stays the command's report (`--json`).
    #[must_use]
    pub fn stream(self) -> Stream {
        match self {
            Self::Openjd => Stream::Stderr,
            Self::Alf | Self::Deadline => Stream::Stdout,
        }
    }

    /// The engine whose session this process runs in, from its environment (`var` looks a
    /// variable up): Open Job Description when [`Engine::OPENJD_SESSION`] is set. ALF and
    /// Deadline plugins set nothing umbra can rely on: name them (`--progress alf|deadline`).
    #[must_use]
    pub fn detect(var: impl Fn(&str) -> Option<std::ffi::OsString>) -> Option<Self> {
        var(Self::OPENJD_SESSION)
            .filter(|v| !v.is_empty())
            .map(|_| Self::Openjd)
    }

    /// The engine by its name (`openjd`, `alf`, `deadline`).
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "openjd" => Some(Self::Openjd),
            "alf" => Some(Self::Alf),
            "deadline" => Some(Self::Deadline),
            _ => None,
        }
    }
}

/// The whole percent `done` is of `total` (100 when there is nothing to do).
#[must_use]
pub fn percent(done: u64, total: u64) -> u8 {
    if total == 0 {
        return 100;
    }
    let p = u128::from(done.min(total)) * 100 / u128::from(total);
    u8::try_from(p).unwrap_or(100)
}

/// A [`Progress`] that prints an [`Engine`]'s line to `out` each time the whole percent done
/// rises (0 at the start, 100 at the end), each line flushed, never out of order.
#[derive(Debug)]
pub struct Lines<W> {
    engine: Engine,
    out: Mutex<W>,
    total: AtomicU64,
    done: AtomicU64,
    /// The last percent printed, plus one (0: none yet).
    shown: AtomicU64,
}

impl<W: Write + Send> Lines<W> {
    /// Lines of `engine` written to `out`.
    pub fn new(engine: Engine, out: W) -> Self {
        Self {
            engine,
            out: Mutex::new(out),
            total: AtomicU64::new(0),
            done: AtomicU64::new(0),
            shown: AtomicU64::new(0),
        }
    }

    /// The writer back (what a test reads).
    pub fn into_inner(self) -> W {
        self.out
            .into_inner()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Print the line for `p` unless a percent as high was printed. A write error (a closed
    /// pipe) is ignored: progress never fails the work.
    fn show(&self, p: u8) {
        let next = u64::from(p) + 1;
        if next <= self.shown.load(Ordering::Relaxed) {
            return;
        }
        let mut out = self
            .out
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if next <= self.shown.load(Ordering::Relaxed) {
            return;
        }
        self.shown.store(next, Ordering::Relaxed);
        let _ = writeln!(out, "{}", self.engine.line(p));
        let _ = out.flush();
    }
}

impl<W: Write + Send> Progress for Lines<W> {
    fn start(&self, work: &Work) {
        self.total.store(work.units, Ordering::Relaxed);
        self.show(percent(self.done.load(Ordering::Relaxed), work.units));
    }

    fn advance(&self, units: u64) {
        let done = self.done.fetch_add(units, Ordering::Relaxed) + units;
        let total = self.total.load(Ordering::Relaxed);
        if total > 0 {
            self.show(percent(done, total));
        }
    }
}

/// A share of an outer [`Progress`]: work whose own total is known only when it starts (a
/// batch task's bake) counted as `worth` units of the outer work, in proportion. What a batch
/// run aggregates its tasks with.
#[derive(Debug)]
pub struct Share<'a, P: ?Sized> {
    outer: &'a P,
    worth: u64,
    total: AtomicU64,
    done: AtomicU64,
    given: AtomicU64,
}

impl<'a, P: Progress + ?Sized> Share<'a, P> {
    /// `worth` units of `outer`.
    pub fn new(outer: &'a P, worth: u64) -> Self {
        Self {
            outer,
            worth,
            total: AtomicU64::new(0),
            done: AtomicU64::new(0),
            given: AtomicU64::new(0),
        }
    }

    /// Pass the outer progress up to `target` of `worth` (never back).
    fn give(&self, target: u64) {
        let before = self.given.fetch_max(target, Ordering::Relaxed);
        if target > before {
            self.outer.advance(target - before);
        }
    }

    /// The work is over (done or failed): the rest of the share is passed on.
    pub fn finish(&self) {
        self.give(self.worth);
    }
}

impl<P: Progress + ?Sized> Progress for Share<'_, P> {
    fn start(&self, work: &Work) {
        self.total.store(work.units, Ordering::Relaxed);
    }

    fn advance(&self, units: u64) {
        let done = self.done.fetch_add(units, Ordering::Relaxed) + units;
        let total = self.total.load(Ordering::Relaxed);
        if total == 0 {
            return;
        }
        let scaled = u128::from(done.min(total)) * u128::from(self.worth) / u128::from(total);
        self.give(u64::try_from(scaled).unwrap_or(self.worth));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn work(units: u64) -> Work {
        Work {
            units,
            what: "test",
            unit: None,
        }
    }

    #[test]
    fn engines_print_their_own_lines() {
        assert_eq!(Engine::Openjd.line(42), "openjd_progress: 42");
        assert_eq!(Engine::Alf.line(7), "ALF_PROGRESS 7%");
        assert_eq!(Engine::Deadline.line(100), "Progress: 100%");
        assert_eq!(Engine::Deadline.line(250), "Progress: 100%");
        for e in [Engine::Openjd, Engine::Alf, Engine::Deadline] {
            let name = format!("{e:?}").to_lowercase();
            assert_eq!(Engine::from_name(&name), Some(e));
        }
        assert_eq!(Engine::from_name("tractor"), None);
    }

    #[test]
    fn an_openjd_session_is_detected_from_its_variable() {
        let none = |_: &str| None;
        assert_eq!(Engine::detect(none), None);
        let openjd = |k: &str| (k == "OPENJD_SESSION_WORKING_DIR").then(|| "/tmp/s".into());
        assert_eq!(Engine::detect(openjd), Some(Engine::Openjd));
        let empty = |_: &str| Some(std::ffi::OsString::new());
        assert_eq!(Engine::detect(empty), None);
    }

    #[test]
    fn lines_print_each_whole_percent_once_in_order() {
        let lines = Lines::new(Engine::Alf, Vec::new());
        lines.start(&work(1000));
        for _ in 0..1000 {
            lines.advance(1);
        }
        let text = String::from_utf8(lines.into_inner()).unwrap_or_default();
        let got: Vec<&str> = text.lines().collect();
        let want: Vec<String> = (0..=100).map(|p| format!("ALF_PROGRESS {p}%")).collect();
        assert_eq!(got, want);
        // Coarse steps skip percents, and a line is never repeated.
        let lines = Lines::new(Engine::Openjd, Vec::new());
        lines.start(&work(3));
        (0..3).for_each(|_| lines.advance(1));
        lines.advance(0);
        let text = String::from_utf8(lines.into_inner()).unwrap_or_default();
        assert_eq!(
            text,
            "openjd_progress: 0\nopenjd_progress: 33\nopenjd_progress: 66\nopenjd_progress: 100\n"
        );
    }

    #[test]
    fn lines_from_many_threads_rise() {
        let lines = Lines::new(Engine::Deadline, Vec::new());
        lines.start(&work(64 * 1000));
        std::thread::scope(|s| {
            for _ in 0..8 {
                s.spawn(|| (0..8000).for_each(|_| lines.advance(1)));
            }
        });
        let text = String::from_utf8(lines.into_inner()).unwrap_or_default();
        let got: Vec<u32> = text
            .lines()
            .filter_map(|l| {
                l.strip_prefix("Progress: ")?
                    .strip_suffix('%')?
                    .parse()
                    .ok()
            })
            .collect();
        assert!(got.windows(2).all(|w| w[0] < w[1]), "{got:?}");
        assert_eq!((got.first(), got.last()), (Some(&0), Some(&100)));
    }

    #[test]
    fn shares_add_up_to_their_worth() {
        let seen = AtomicU64::new(0);
        let outer = |n: u64| {
            seen.fetch_add(n, Ordering::Relaxed);
        };
        let share = Share::new(&outer, 1920);
        share.start(&work(7));
        (0..7).for_each(|_| share.advance(1));
        assert_eq!(seen.load(Ordering::Relaxed), 1920);
        share.finish();
        assert_eq!(seen.load(Ordering::Relaxed), 1920);
        // A failed task's share is passed on whole when it finishes.
        let failed = Share::new(&outer, 100);
        failed.start(&work(10));
        failed.advance(3);
        assert_eq!(seen.load(Ordering::Relaxed), 1950);
        failed.finish();
        assert_eq!(seen.load(Ordering::Relaxed), 2020);
    }

    #[test]
    fn closures_are_progress() {
        let seen = AtomicU64::new(0);
        let f = |n: u64| {
            seen.fetch_add(n, Ordering::Relaxed);
        };
        let p: &dyn Progress = &f;
        p.start(&work(5));
        p.advance(5);
        assert_eq!(seen.load(Ordering::Relaxed), 5);
        let silent: &dyn Progress = &|_| {};
        silent.advance(1);
    }
}
