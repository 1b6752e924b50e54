//! Shadow links: which prims a light's shadows see, as USD's `CollectionAPI` decides
//! membership.
//!
//! A collection (here a light's `collection:shadowLink`) is a map from paths to rules
//! ([`Rule`]), built from its properties as `UsdCollectionAPI::ComputeMembershipQuery` builds
//! it: `includeRoot` adds `/` (not with `explicitOnly`), every `includes` target its path
//! with the collection's `expansionRule`, an included collection (`/prim.collection:name`)
//! its own map merged in (later targets stronger), then every `excludes` target `exclude`.
//! A prim path is a member when the nearest of itself and its ancestors that has a rule is
//! not `exclude`, and is not an `explicitOnly` ancestor (`explicitOnly` counts only for the
//! exact path; an `explicitOnly` ancestor is passed over): `UsdCollectionMembershipQuery::
//! IsPathIncluded` for prim paths. UsdLux's `LightAPI` gives the light's `shadowLink` (and
//! `lightLink`) an `includeRoot` fallback of `true`, so an unauthored link holds every prim.

use std::collections::BTreeMap;

/// What a collection says about one path and, by expansion, its descendants.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rule {
    /// `explicitOnly`: the path itself, not its descendants.
    ExplicitOnly,
    /// `expandPrims`: the path and every prim below it.
    ExpandPrims,
    /// `expandPrimsAndProperties`: as `expandPrims`, and their properties.
    ExpandPrimsAndProperties,
    /// An `excludes` target: the path and everything below it, unless a nearer rule says
    /// otherwise.
    Exclude,
}

impl Rule {
    /// The rule an `expansionRule` token names (`None`: not one of USD's three).
    #[must_use]
    pub fn from_token(t: &str) -> Option<Self> {
        match t {
            "explicitOnly" => Some(Self::ExplicitOnly),
            "expandPrims" => Some(Self::ExpandPrims),
            "expandPrimsAndProperties" => Some(Self::ExpandPrimsAndProperties),
            _ => None,
        }
    }

    /// The token USD spells it with (`exclude` for an exclusion).
    #[must_use]
    pub fn token(self) -> &'static str {
        match self {
            Self::ExplicitOnly => "explicitOnly",
            Self::ExpandPrims => "expandPrims",
            Self::ExpandPrimsAndProperties => "expandPrimsAndProperties",
            Self::Exclude => "exclude",
        }
    }
}

/// A collection's membership: its path-to-rule map (USD's `PathExpansionRuleMap`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Link {
    /// Every path the collection names, with its rule.
    pub rules: BTreeMap<String, Rule>,
}

impl Link {
    /// A collection that holds every prim (`includeRoot`, nothing else): an unauthored
    /// light link.
    #[must_use]
    pub fn everything() -> Self {
        let mut rules = BTreeMap::new();
        rules.insert("/".to_string(), Rule::ExpandPrims);
        Self { rules }
    }

    /// Whether the prim at `path` (absolute, `/a/b`) is a member.
    #[must_use]
    pub fn includes(&self, path: &str) -> bool {
        let mut cur = Some(path);
        while let Some(p) = cur {
            match self.rules.get(p) {
                Some(Rule::Exclude) => return false,
                Some(Rule::ExplicitOnly) if p != path => {}
                Some(_) => return true,
                None => {}
            }
            cur = parent(p);
        }
        false
    }

    /// Whether it holds every prim: `/` included by an expanding rule and nothing excluded.
    #[must_use]
    pub fn is_everything(&self) -> bool {
        matches!(
            self.rules.get("/"),
            Some(Rule::ExpandPrims | Rule::ExpandPrimsAndProperties)
        ) && !self.rules.values().any(|r| *r == Rule::Exclude)
    }
}

/// The parent of an absolute prim path (`/a/b` -> `/a`, `/a` -> `/`, `/` -> none).
fn parent(p: &str) -> Option<&str> {
    if p == "/" || p.is_empty() {
        return None;
    }
    match p.rfind('/') {
        Some(0) => Some("/"),
        Some(i) => Some(&p[..i]),
        None => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn link(rules: &[(&str, Rule)]) -> Link {
        Link {
            rules: rules.iter().map(|(p, r)| ((*p).to_string(), *r)).collect(),
        }
    }

    /// The cases `usd-core`'s `ComputeMembershipQuery().IsPathIncluded` answers (26.11).
    #[test]
    fn membership_follows_usd() {
        use Rule::*;
        let all = Link::everything();
        assert!(all.includes("/W/a") && all.includes("/W/b/c") && all.is_everything());
        let excl = link(&[("/", ExpandPrims), ("/W/b", Exclude)]);
        assert!(excl.includes("/W/a") && excl.includes("/X/d"));
        assert!(!excl.includes("/W/b") && !excl.includes("/W/b/c") && !excl.is_everything());
        let only = link(&[("/W/b", Exclude)]);
        assert!(!only.includes("/W/a") && !only.includes("/X/d"));
        let inc = link(&[("/W", ExpandPrims), ("/W/b", Exclude)]);
        assert!(inc.includes("/W/a") && !inc.includes("/W/b/c") && !inc.includes("/X/d"));
        let exp = link(&[
            ("/W", ExplicitOnly),
            ("/W/b", Exclude),
            ("/W/b/c", ExplicitOnly),
        ]);
        assert!(exp.includes("/W") && !exp.includes("/W/a") && !exp.includes("/W/b"));
        assert!(exp.includes("/W/b/c"));
        // An explicitOnly ancestor is passed over: a farther expanding one still counts.
        let both = link(&[("/", ExpandPrims), ("/W", ExplicitOnly)]);
        assert!(both.includes("/W/a"));
        assert!(!Link::default().includes("/W"));
        assert_eq!(parent("/a/b"), Some("/a"));
        assert_eq!(parent("/a"), Some("/"));
        assert_eq!(parent("/"), None);
    }
}
