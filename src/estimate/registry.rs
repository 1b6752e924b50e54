//! The estimator registry: the one place where an estimator's identity lives.
//!
//! Every estimator umbra knows is one [`Spec`] in [`REGISTRY`]: its name, its [`Kind`] (exact,
//! biased, unbiased, signed), its parameters with defaults and valid ranges, a one-line summary,
//! and how `umbra compare` spends a budget on it. [`Estimator::from_name`], [`Estimator::name`],
//! the CLI help and `umbra estimators`, the compare ladder, the EXR `umbra:estimator` attribute
//! and the job-file keys are all derived from it, so a name always round-trips:
//! `Estimator::from_name(e.name())` has the same algorithm as `e`.
//!
//! An [`Estimator`] can only be made through the registry, which validates every parameter
//! against its range: a zero or negative ray-marching step (which would never finish) is an
//! [`Error::InvalidArgument`], never a hang.

use crate::error::{Error, Result};
use serde::ser::SerializeMap;

/// What an estimator's expectation is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// Zero variance, exactly `T` (regular tracking).
    Exact,
    /// Converges to `T` only as its parameter goes to 0 (step, kernel) or its sample count grows.
    Biased,
    /// `E[X] = T`, every single estimate in `[0, 1]`.
    Unbiased,
    /// `E[X] = T`, but single estimates may leave `[0, 1]` (above 1, or below 0): averages
    /// converge, single values are reported raw.
    Signed,
}

impl Kind {
    /// The lowercase name used in `umbra estimators` and reports.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Exact => "exact",
            Self::Biased => "biased",
            Self::Unbiased => "unbiased",
            Self::Signed => "signed",
        }
    }
}

/// One numeric parameter of an estimator: valid values are `min <= v <= max` (whole numbers if
/// `integer`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Param {
    /// Name, as `--NAME` on the command line and a key in job files.
    pub name: &'static str,
    /// Value when not given.
    pub default: f64,
    /// Smallest valid value.
    pub min: f64,
    /// Largest valid value.
    pub max: f64,
    /// Whether only whole numbers are valid.
    pub integer: bool,
    /// Unit of the value (`voxels`, `world units`, `points`).
    pub unit: &'static str,
    /// The values `umbra compare` runs when this parameter is the budget (coarse to fine).
    #[serde(skip)]
    pub ladder: &'static [f64],
}

impl Param {
    /// Check `v` against the range.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the parameter when `v` is not finite, out of
    /// `[min, max]`, or not whole for an integer parameter.
    pub fn check(&self, v: f64) -> Result<f64> {
        let whole = !self.integer || v.fract() == 0.0;
        if v.is_finite() && v >= self.min && v <= self.max && whole {
            return Ok(v);
        }
        Err(Error::InvalidArgument {
            name: self.name.into(),
            reason: format!(
                "{v} is out of range: expected {} in [{}, {}] {}",
                if self.integer {
                    "a whole number"
                } else {
                    "a number"
                },
                self.min,
                self.max,
                self.unit
            ),
        })
    }
}

/// How `umbra compare` spends more budget on an estimator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Budget {
    /// One exact run.
    Exact,
    /// Its first parameter runs through [`Param::ladder`].
    Param,
    /// Samples per ray 1, 4, 16, 64 at default parameters.
    Samples,
}

/// The algorithm behind a registry entry (crate-private: estimators are made through the
/// registry only).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Algo {
    Regular,
    Riemann,
    Mc,
    Jittered,
    TrackLength,
    Collision,
    Ratio,
    ResidualRatio(super::Control),
    NextFlight,
    UnbiasedRaymarch,
    Decomposition,
    Jackknife,
}

/// One registered estimator.
#[derive(Debug, serde::Serialize)]
pub struct Spec {
    /// Name (`--estimator NAME`).
    pub name: &'static str,
    /// What its expectation is.
    pub kind: Kind,
    /// One estimate says everything (no random numbers): samples are not repeated.
    pub deterministic: bool,
    /// Parameters, in order.
    pub params: &'static [Param],
    /// One-line description.
    pub summary: &'static str,
    /// How `umbra compare` varies its cost.
    pub budget: Budget,
    /// The walk a coloured medium gets by default ([`super::ColourWalk::Auto`]): whichever
    /// `umbra compare --sigma-t` measured as more efficient (docs/colour.md).
    pub colour: super::ColourChoice,
    #[serde(skip)]
    pub(crate) algo: Algo,
}

/// Most parameters any estimator has.
const MAX_PARAMS: usize = 1;

const STEP: Param = Param {
    name: "step",
    default: 1.0,
    min: 1e-3,
    max: 1e6,
    integer: false,
    unit: "voxels",
    ladder: &[4.0, 2.0, 1.0, 0.5],
};

const KERNEL: Param = Param {
    name: "kernel",
    default: 1.0,
    min: 0.0,
    max: 1e6,
    integer: false,
    unit: "voxels",
    ladder: &[],
};

const POINTS: Param = Param {
    name: "points",
    default: 10.0,
    min: 1.0,
    max: 65_536.0,
    integer: true,
    unit: "points",
    ladder: &[4.0, 8.0, 16.0, 32.0],
};

/// Every estimator, in the order reports list them.
pub static REGISTRY: &[Spec] = &[
    Spec {
        name: "regular",
        kind: Kind::Exact,
        deterministic: true,
        params: &[],
        summary: "regular tracking: closed form per tile, per voxel (nearest) or exact cubic per dual cell (trilinear)",
        budget: Budget::Exact,
        colour: super::ColourChoice::Shared,
        algo: Algo::Regular,
    },
    Spec {
        name: "riemann",
        kind: Kind::Biased,
        deterministic: true,
        params: &[STEP],
        summary: "ray marching, midpoint rule at a fixed step (error O(step^2) in smooth media)",
        budget: Budget::Param,
        colour: super::ColourChoice::Shared,
        algo: Algo::Riemann,
    },
    Spec {
        name: "mc",
        kind: Kind::Biased,
        deterministic: false,
        params: &[STEP],
        summary: "ray marching at uniform random points, one per step length (overestimates T)",
        budget: Budget::Param,
        colour: super::ColourChoice::Shared,
        algo: Algo::Mc,
    },
    Spec {
        name: "jittered",
        kind: Kind::Biased,
        deterministic: false,
        params: &[STEP],
        summary: "ray marching, one jittered point per step (stratified; overestimates T)",
        budget: Budget::Param,
        colour: super::ColourChoice::Shared,
        algo: Algo::Jittered,
    },
    Spec {
        name: "track-length",
        kind: Kind::Unbiased,
        deterministic: false,
        params: &[],
        summary: "delta tracking on per-node majorants: 1 if the free flight passes the end (binary)",
        budget: Budget::Samples,
        colour: super::ColourChoice::SplitBelow(0.75),
        algo: Algo::TrackLength,
    },
    Spec {
        name: "collision",
        kind: Kind::Biased,
        deterministic: false,
        params: &[KERNEL],
        summary: "delta tracking scored with a ramp kernel before the end (bias O(kernel))",
        budget: Budget::Samples,
        colour: super::ColourChoice::SplitBelow(0.75),
        algo: Algo::Collision,
    },
    Spec {
        name: "ratio",
        kind: Kind::Unbiased,
        deterministic: false,
        params: &[],
        summary: "ratio tracking (Novak 2014): product of 1 - mu/mu_maj at tentative collisions",
        budget: Budget::Samples,
        colour: super::ColourChoice::Shared,
        algo: Algo::Ratio,
    },
    Spec {
        name: "residual-ratio",
        kind: Kind::Unbiased,
        deterministic: false,
        params: &[],
        summary: "residual ratio tracking, control = per-node minorant integrated exactly",
        budget: Budget::Samples,
        colour: super::ColourChoice::Shared,
        algo: Algo::ResidualRatio(super::Control::Minorant),
    },
    Spec {
        name: "residual-ratio-midpoint",
        kind: Kind::Signed,
        deterministic: false,
        params: &[],
        summary: "residual ratio tracking, control = (minorant + majorant) / 2 (weights up to 2)",
        budget: Budget::Samples,
        colour: super::ColourChoice::Split,
        algo: Algo::ResidualRatio(super::Control::Midpoint),
    },
    Spec {
        name: "next-flight",
        kind: Kind::Signed,
        deterministic: false,
        params: &[],
        summary: "next-flight ratio tracking (Cramer 1978; Novak 2018); single estimates can exceed 1",
        budget: Budget::Samples,
        colour: super::ColourChoice::Split,
        algo: Algo::NextFlight,
    },
    Spec {
        name: "unbiased-raymarch",
        kind: Kind::Signed,
        deterministic: false,
        params: &[],
        summary: "unbiased ray marching (Kettunen 2021): power series around ray-marched optical depths",
        budget: Budget::Samples,
        colour: super::ColourChoice::Shared,
        algo: Algo::UnbiasedRaymarch,
    },
    Spec {
        name: "decomposition",
        kind: Kind::Unbiased,
        deterministic: false,
        params: &[],
        summary: "decomposition tracking (Kutz 2017): minorant in closed form, delta tracking on the residual",
        budget: Budget::Samples,
        colour: super::ColourChoice::SplitBelow(0.75),
        algo: Algo::Decomposition,
    },
    Spec {
        name: "jackknife",
        kind: Kind::Biased,
        deterministic: false,
        params: &[POINTS],
        summary: "jackknife transmittance (Peters 2025): cos(|X1 - X2| / 2) exp(-(X1 + X2) / 2), fixed cost",
        budget: Budget::Param,
        colour: super::ColourChoice::Split,
        algo: Algo::Jackknife,
    },
];

/// The names of every registered estimator, in registry order.
pub fn names() -> impl Iterator<Item = &'static str> {
    REGISTRY.iter().map(|s| s.name)
}

/// The registry entry called `name`.
///
/// # Errors
/// [`Error::InvalidArgument`] (name `estimator`) listing the known names.
pub fn spec(name: &str) -> Result<&'static Spec> {
    REGISTRY
        .iter()
        .find(|s| s.name == name)
        .ok_or_else(|| Error::InvalidArgument {
            name: "estimator".into(),
            reason: format!(
                "unknown estimator '{name}' (known: {})",
                names().collect::<Vec<_>>().join(", ")
            ),
        })
}

impl Spec {
    /// The parameter called `name`, if this estimator has one.
    #[must_use]
    pub fn param(&self, name: &str) -> Option<&'static Param> {
        self.params.iter().find(|p| p.name == name)
    }

    /// This estimator with default parameters.
    #[must_use]
    pub fn default_estimator(&'static self) -> Estimator {
        let mut values = [0.0; MAX_PARAMS];
        for (v, p) in values.iter_mut().zip(self.params) {
            *v = p.default;
        }
        Estimator {
            id: self.index(),
            values,
        }
    }

    fn index(&'static self) -> u8 {
        let i = REGISTRY
            .iter()
            .position(|s| std::ptr::eq(s, self))
            .unwrap_or(0);
        i as u8
    }
}

/// A transmittance estimator with validated parameters. Made only through the registry:
/// [`Estimator::from_name`], [`Estimator::with_params`], [`Estimator::set`] (or the
/// [`Estimator::REGULAR`] constant), so its parameters are always within their ranges.
///
/// ```
/// use umbra::estimate::Estimator;
/// let e = Estimator::with_params("riemann", &[("step", 0.5)])?;
/// assert_eq!((e.name(), e.param("step")), ("riemann", Some(0.5)));
/// assert!(Estimator::with_params("riemann", &[("step", 0.0)]).is_err()); // would never end
/// assert_eq!(Estimator::from_name(e.name())?.name(), "riemann");
/// # Ok::<(), umbra::Error>(())
/// ```
///
/// ```compile_fail
/// // No way around the registry: the fields are private.
/// let e = umbra::estimate::Estimator { id: 1, values: [0.0] };
/// ```
#[derive(Clone, Copy, PartialEq)]
pub struct Estimator {
    /// Index into [`REGISTRY`].
    id: u8,
    /// Parameter values, in [`Spec::params`] order.
    values: [f64; MAX_PARAMS],
}

impl std::fmt::Debug for Estimator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Estimator({self})")
    }
}

impl std::fmt::Display for Estimator {
    /// `name` or `name(param=value, ...)`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())?;
        let params: Vec<String> = self.params().map(|(n, v)| format!("{n}={v}")).collect();
        if !params.is_empty() {
            write!(f, "({})", params.join(", "))?;
        }
        Ok(())
    }
}

impl serde::Serialize for Estimator {
    /// `{"name": NAME, PARAM: VALUE, ...}` (whole-number parameters as integers).
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        let spec = self.spec();
        let mut m = s.serialize_map(Some(1 + spec.params.len()))?;
        m.serialize_entry("name", spec.name)?;
        for (p, v) in spec.params.iter().zip(self.values) {
            if p.integer {
                m.serialize_entry(p.name, &(v as u64))?;
            } else {
                m.serialize_entry(p.name, &v)?;
            }
        }
        m.end()
    }
}

impl Default for Estimator {
    fn default() -> Self {
        Self::REGULAR
    }
}

impl Estimator {
    /// Exact regular tracking, umbra's reference (and default) estimator.
    pub const REGULAR: Self = Self {
        id: 0,
        values: [0.0; MAX_PARAMS],
    };

    /// The estimator called `name` with default parameters.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for an unknown name (the message lists the known ones).
    pub fn from_name(name: &str) -> Result<Self> {
        Ok(spec(name)?.default_estimator())
    }

    /// The estimator called `name` with some parameters set (the others at their defaults).
    ///
    /// # Errors
    /// An unknown name, a parameter the estimator does not have, or a value out of range.
    pub fn with_params(name: &str, params: &[(&str, f64)]) -> Result<Self> {
        params
            .iter()
            .try_fold(Self::from_name(name)?, |e, &(p, v)| e.set(p, v))
    }

    /// This estimator with parameter `param` set to `value`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] when the estimator has no such parameter or `value` is out
    /// of the parameter's range.
    pub fn set(mut self, param: &str, value: f64) -> Result<Self> {
        let spec = self.spec();
        let Some(i) = spec.params.iter().position(|p| p.name == param) else {
            let has = if spec.params.is_empty() {
                "none".to_string()
            } else {
                spec.params
                    .iter()
                    .map(|p| p.name)
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            return Err(Error::InvalidArgument {
                name: param.into(),
                reason: format!(
                    "estimator '{}' has no parameter '{param}' (its parameters: {has})",
                    spec.name
                ),
            });
        };
        self.values[i] = spec.params[i].check(value)?;
        Ok(self)
    }

    /// The registry entry of this estimator.
    #[must_use]
    pub fn spec(&self) -> &'static Spec {
        &REGISTRY[usize::from(self.id)]
    }

    /// The registered name (round-trips through [`Estimator::from_name`]).
    #[must_use]
    pub fn name(&self) -> &'static str {
        self.spec().name
    }

    /// What its expectation is.
    #[must_use]
    pub fn kind(&self) -> Kind {
        self.spec().kind
    }

    /// The value of parameter `name`, if the estimator has it.
    #[must_use]
    pub fn param(&self, name: &str) -> Option<f64> {
        let spec = self.spec();
        spec.params
            .iter()
            .position(|p| p.name == name)
            .map(|i| self.values[i])
    }

    /// `(name, value)` of every parameter, in registry order.
    pub fn params(&self) -> impl Iterator<Item = (&'static str, f64)> + '_ {
        self.spec()
            .params
            .iter()
            .zip(self.values)
            .map(|(p, v)| (p.name, v))
    }

    /// True for estimators whose expectation is exactly `T` (kinds exact, unbiased, signed).
    #[must_use]
    pub fn is_unbiased(&self) -> bool {
        self.kind() != Kind::Biased
    }

    /// True for estimators whose single-sample estimates can fall outside `[0, 1]` (kind
    /// signed).
    #[must_use]
    pub fn may_leave_unit_interval(&self) -> bool {
        self.kind() == Kind::Signed
    }

    /// True for deterministic estimators (one sample says everything).
    #[must_use]
    pub fn is_deterministic(&self) -> bool {
        self.spec().deterministic
    }

    /// The algorithm and the first parameter value (crate-private dispatch).
    /// True for the ray marchers (`riemann`, `mc`, `jittered`): point lookups on a grid of
    /// pieces per block chord, no majorants.
    #[must_use]
    pub fn marches(&self) -> bool {
        matches!(self.spec().algo, Algo::Riemann | Algo::Mc | Algo::Jittered)
    }

    pub(crate) fn algo(&self) -> (Algo, f64) {
        (self.spec().algo, self.values[0])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn registry_entries_are_consistent() {
        assert!(REGISTRY.len() < 256);
        for (i, s) in REGISTRY.iter().enumerate() {
            assert!(s.params.len() <= MAX_PARAMS, "{}", s.name);
            assert_eq!(usize::from(s.index()), i);
            assert_eq!(
                REGISTRY.iter().filter(|o| o.name == s.name).count(),
                1,
                "duplicate {}",
                s.name
            );
            for p in s.params {
                assert!(p.check(p.default).is_ok(), "{}.{}", s.name, p.name);
                for &v in p.ladder {
                    assert!(p.check(v).is_ok(), "{}.{} ladder {v}", s.name, p.name);
                }
            }
            if s.budget == Budget::Param {
                assert!(!s.params.is_empty() && !s.params[0].ladder.is_empty());
            }
        }
        assert_eq!(Estimator::REGULAR.name(), "regular");
    }
}
