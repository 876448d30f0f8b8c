//! The campaign spec (TOML): base scenario, runs, seeds, dispersions, criteria. The format is
//! documented in `docs/campaigns.md`; every table rejects unknown keys so a typo is an error,
//! not a silently ignored line.

use super::params;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A campaign.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Spec {
    /// Name (outputs, Slurm job names).
    pub name: String,
    /// One-line description.
    #[serde(default)]
    pub description: String,
    /// Base scenario file, relative to the spec file (or absolute).
    pub scenario: String,
    /// Number of runs.
    pub runs: u64,
    /// Base seed: run `i` has the seed `campaign::run_seed(base_seed, i)`.
    pub base_seed: u64,
    /// Terrain and calibration seeds.
    #[serde(default)]
    pub seeds: Seeds,
    /// How each run is executed.
    #[serde(default)]
    pub run: RunSettings,
    /// Values merged into the scenario's TOML before the draws (tables merge key by key).
    #[serde(default)]
    pub scenario_overrides: toml::Table,
    /// Dispersions, each one draw per run applied to one or more parameters.
    #[serde(default, rename = "dispersion")]
    pub dispersions: Vec<Dispersion>,
    /// Acceptance criteria.
    #[serde(default, rename = "criterion")]
    pub criteria: Vec<Criterion>,
    /// Extra metrics for the statistics besides the default list and the criteria's.
    #[serde(default)]
    pub metrics: Vec<String>,
    /// Worst runs listed per criterion in the report (default 5).
    #[serde(default = "default_worst")]
    pub worst_runs: usize,
}

fn default_worst() -> usize {
    5
}

/// Where a run's terrain or rover unit comes from: `"per_run"` or an integer seed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SeedChoice {
    /// `"per_run"`: from the run seed (as `sim-host run --seed` does).
    #[default]
    PerRun,
    /// A fixed seed for every run.
    Fixed(u64),
}

impl Serialize for SeedChoice {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            SeedChoice::PerRun => s.serialize_str("per_run"),
            SeedChoice::Fixed(v) => s.serialize_u64(*v),
        }
    }
}

impl<'de> Deserialize<'de> for SeedChoice {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Seed(u64),
            Text(String),
        }
        match Raw::deserialize(d)? {
            Raw::Seed(v) => Ok(SeedChoice::Fixed(v)),
            Raw::Text(t) if t == "per_run" => Ok(SeedChoice::PerRun),
            Raw::Text(t) => Err(serde::de::Error::custom(format!(
                "expected \"per_run\" or an integer seed, found {t:?}"
            ))),
        }
    }
}

/// The `[seeds]` table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Seeds {
    /// Terrain (roughness, rock field, ground texture of the rendered images).
    pub terrain: SeedChoice,
    /// Calibration and manufacturing errors of the rover unit.
    pub calibration: SeedChoice,
}

/// The `[run]` table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunSettings {
    /// Rendered stereo images (VO tracks them); `false`: uniform grey frames.
    pub render: bool,
    /// Slip compensation of the flight software.
    pub slip_compensation: bool,
    /// Visual odometry in the flight software.
    pub vo: bool,
}

impl Default for RunSettings {
    fn default() -> Self {
        Self {
            render: true,
            slip_compensation: true,
            vo: true,
        }
    }
}

/// How a drawn value changes a parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Apply {
    /// The parameter becomes the drawn value.
    #[default]
    Set,
    /// The parameter is multiplied by the drawn value.
    Scale,
    /// The drawn value is added to the parameter.
    Offset,
}

/// A distribution.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Distribution {
    /// Uniform on `[min, max)`.
    Uniform {
        /// Lower end.
        min: f64,
        /// Upper end.
        max: f64,
    },
    /// Normal `N(mean, sigma^2)`, truncated to `[min, max]` by redrawing (at most
    /// [`MAX_REDRAWS`] times; the spec is refused when the bounds keep less than 1 % of the
    /// probability, so that limit is never reached in practice).
    Normal {
        /// Mean.
        mean: f64,
        /// Standard deviation.
        sigma: f64,
        /// Lower bound (default none).
        #[serde(default)]
        min: Option<f64>,
        /// Upper bound (default none).
        #[serde(default)]
        max: Option<f64>,
    },
}

/// Redraws of a truncated normal before the draw fails.
pub const MAX_REDRAWS: u32 = 10_000;

/// A dispersion: one draw per run, applied to each of `params`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Dispersion {
    /// Name (the key of the draw in the manifest; default: the parameters joined by `+`).
    #[serde(default)]
    pub name: Option<String>,
    /// Parameters ([`params::PARAMS`]).
    pub params: Vec<String>,
    /// How the draw changes them.
    #[serde(default)]
    pub apply: Apply,
    /// The distribution of the draw.
    pub dist: Distribution,
}

impl Dispersion {
    /// The draw's key: its name, or the parameters joined by `+`.
    pub fn key(&self) -> String {
        self.name.clone().unwrap_or_else(|| self.params.join("+"))
    }
}

/// Comparison of a criterion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Op {
    /// At most.
    #[serde(rename = "<=")]
    Le,
    /// Less than.
    #[serde(rename = "<")]
    Lt,
    /// At least.
    #[serde(rename = ">=")]
    Ge,
    /// More than.
    #[serde(rename = ">")]
    Gt,
}

impl Op {
    /// `value op threshold`.
    pub fn holds(self, value: f64, threshold: f64) -> bool {
        match self {
            Op::Le => value <= threshold,
            Op::Lt => value < threshold,
            Op::Ge => value >= threshold,
            Op::Gt => value > threshold,
        }
    }

    /// The symbol.
    pub fn symbol(self) -> &'static str {
        match self {
            Op::Le => "<=",
            Op::Lt => "<",
            Op::Ge => ">=",
            Op::Gt => ">",
        }
    }

    /// Large values are bad (`<=`, `<`): the worst runs are the largest.
    pub fn large_is_bad(self) -> bool {
        matches!(self, Op::Le | Op::Lt)
    }
}

/// The statistic a criterion checks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum Stat {
    /// Nearest-rank percentile `p` (0 < p <= 100).
    Percentile(f64),
    /// Mean (of a true/false metric: the fraction of runs where it is true).
    Mean,
    /// Smallest value.
    Min,
    /// Largest value.
    Max,
}

impl Stat {
    /// Parse `p99`, `p99.9`, `p5`, `mean`, `fraction` (the mean), `min`, `max`, `median` (p50).
    pub fn parse(text: &str) -> anyhow::Result<Self> {
        match text {
            "mean" | "fraction" => return Ok(Stat::Mean),
            "min" => return Ok(Stat::Min),
            "max" => return Ok(Stat::Max),
            "median" => return Ok(Stat::Percentile(50.0)),
            _ => {}
        }
        let p: f64 = text
            .strip_prefix('p')
            .or_else(|| text.strip_prefix('P'))
            .and_then(|n| n.parse().ok())
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "unknown statistic {text:?} (pNN such as p99 or p99.9, mean, fraction, min, \
                     max, median)"
                )
            })?;
        anyhow::ensure!(
            p > 0.0 && p <= 100.0,
            "percentile {text:?} must be in (0, 100]"
        );
        Ok(Stat::Percentile(p))
    }

    /// A short label: `P99`, `mean`, `min`, `max`.
    pub fn label(self) -> String {
        match self {
            Stat::Percentile(p) => format!("P{p}"),
            Stat::Mean => "mean".into(),
            Stat::Min => "min".into(),
            Stat::Max => "max".into(),
        }
    }
}

/// An acceptance criterion: `stat(metric) op threshold` over all runs.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Criterion {
    /// Name.
    pub name: String,
    /// Metric: a dotted path into `summary.json` ([`super::stats::METRICS`]).
    pub metric: String,
    /// Statistic: `p99`, `mean`, ... ([`Stat::parse`]).
    pub stat: String,
    /// Comparison.
    pub op: Op,
    /// Threshold, in the metric's unit.
    pub threshold: f64,
    /// Where the threshold comes from.
    #[serde(default)]
    pub source: String,
}

impl Criterion {
    /// The parsed statistic.
    pub fn stat(&self) -> anyhow::Result<Stat> {
        Stat::parse(&self.stat)
    }
}

impl Spec {
    /// Parse and check a spec.
    pub fn from_toml(text: &str) -> anyhow::Result<Self> {
        let spec: Spec = toml::from_str(text)?;
        spec.check()?;
        Ok(spec)
    }

    /// Load a spec file.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
        Self::from_toml(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    /// Check everything that does not need the scenario.
    pub fn check(&self) -> anyhow::Result<()> {
        anyhow::ensure!(!self.name.is_empty(), "name must not be empty");
        anyhow::ensure!(
            self.name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.'),
            "name {:?}: letters, digits, '-', '_', '.' only (it names files and jobs)",
            self.name
        );
        anyhow::ensure!(self.runs >= 1, "runs must be at least 1");
        let mut keys = std::collections::BTreeSet::new();
        for d in &self.dispersions {
            let key = d.key();
            anyhow::ensure!(!d.params.is_empty(), "dispersion {key:?}: no params");
            anyhow::ensure!(keys.insert(key.clone()), "two dispersions named {key:?}");
            for p in &d.params {
                params::find(p).map_err(|e| anyhow::anyhow!("dispersion {key:?}: {e}"))?;
            }
            check_distribution(&d.dist).map_err(|e| anyhow::anyhow!("dispersion {key:?}: {e}"))?;
        }
        for c in &self.criteria {
            c.stat()
                .map_err(|e| anyhow::anyhow!("criterion {:?}: {e}", c.name))?;
            super::stats::check_metric(&c.metric)
                .map_err(|e| anyhow::anyhow!("criterion {:?}: {e}", c.name))?;
            anyhow::ensure!(
                c.threshold.is_finite(),
                "criterion {:?}: threshold must be finite",
                c.name
            );
        }
        for m in &self.metrics {
            super::stats::check_metric(m)?;
        }
        Ok(())
    }
}

/// Standard normal CDF by the Abramowitz-Stegun 7.1.26 erf approximation (error below 1.5e-7):
/// enough to refuse bounds that keep almost no probability.
fn normal_cdf(z: f64) -> f64 {
    let x = z.abs() / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.327_591_1 * x);
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let erf = 1.0 - poly * (-x * x).exp();
    if z >= 0.0 {
        0.5 * (1.0 + erf)
    } else {
        0.5 * (1.0 - erf)
    }
}

fn check_distribution(d: &Distribution) -> anyhow::Result<()> {
    match *d {
        Distribution::Uniform { min, max } => {
            anyhow::ensure!(
                min.is_finite() && max.is_finite() && min < max,
                "uniform: need finite min < max"
            );
        }
        Distribution::Normal {
            mean,
            sigma,
            min,
            max,
        } => {
            anyhow::ensure!(
                mean.is_finite() && sigma.is_finite() && sigma > 0.0,
                "normal: need a finite mean and sigma > 0"
            );
            let lo = min.unwrap_or(f64::NEG_INFINITY);
            let hi = max.unwrap_or(f64::INFINITY);
            anyhow::ensure!(
                !lo.is_nan() && !hi.is_nan() && lo < hi,
                "normal: need min < max"
            );
            let kept = normal_cdf((hi - mean) / sigma) - normal_cdf((lo - mean) / sigma);
            anyhow::ensure!(
                kept >= 0.01,
                "normal: the bounds keep {:.2e} of the probability (at least 1 % needed)",
                kept
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn campaign_spec_stat_parse() {
        assert_eq!(Stat::parse("p99").unwrap(), Stat::Percentile(99.0));
        assert_eq!(Stat::parse("p99.9").unwrap(), Stat::Percentile(99.9));
        assert_eq!(Stat::parse("fraction").unwrap(), Stat::Mean);
        assert_eq!(Stat::parse("median").unwrap(), Stat::Percentile(50.0));
        assert!(Stat::parse("p0").is_err());
        assert!(Stat::parse("p101").is_err());
        assert!(Stat::parse("q5").is_err());
    }

    #[test]
    fn campaign_spec_normal_cdf_and_bounds() {
        assert!((normal_cdf(0.0) - 0.5).abs() < 1e-7);
        assert!((normal_cdf(1.959_964) - 0.975).abs() < 1e-6);
        assert!((normal_cdf(-1.0) - 0.158_655_25).abs() < 1e-6);
        let tight = Distribution::Normal {
            mean: 0.0,
            sigma: 1.0,
            min: Some(5.0),
            max: Some(6.0),
        };
        assert!(check_distribution(&tight).is_err());
        let ok = Distribution::Normal {
            mean: 0.0,
            sigma: 1.0,
            min: Some(-2.0),
            max: Some(2.0),
        };
        assert!(check_distribution(&ok).is_ok());
    }

    #[test]
    fn campaign_spec_rejects_typos() {
        let base = "name='x'\nscenario='s.toml'\nruns=3\nbase_seed=1\n";
        assert!(Spec::from_toml(base).is_ok());
        assert!(Spec::from_toml(&format!("{base}rnus=4\n")).is_err());
        let bad_param = format!(
            "{base}[[dispersion]]\nparams=['soil.frictoin']\ndist={{kind='uniform',min=0,max=1}}\n"
        );
        assert!(Spec::from_toml(&bad_param).is_err());
        let bad_metric = format!(
            "{base}[[criterion]]\nname='c'\nmetric='cross_track.max'\nstat='p99'\nop='<='\nthreshold=1\n"
        );
        assert!(Spec::from_toml(&bad_metric).is_err());
        let seeds = format!("{base}[seeds]\nterrain=7\ncalibration='per_run'\n");
        let s = Spec::from_toml(&seeds).unwrap();
        assert_eq!(s.seeds.terrain, SeedChoice::Fixed(7));
        assert_eq!(s.seeds.calibration, SeedChoice::PerRun);
        assert!(Spec::from_toml(&format!("{base}[seeds]\nterrain='each'\n")).is_err());
    }
}
