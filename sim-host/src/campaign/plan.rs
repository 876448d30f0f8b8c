//! `campaign plan`: expand a spec into `DIR/manifest.json`, every run's index, seeds and drawn
//! parameter values. The manifest holds the spec's and the base scenario's text, so a run
//! needs nothing but the manifest (on a cluster: nothing but the shared `DIR`), and a later
//! edit of `scenarios/` does not change a planned campaign.

use super::params;
use super::spec::{Apply, Distribution, RunSettings, SeedChoice, Seeds, Spec, MAX_REDRAWS};
use crate::scenario::Scenario;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution as _, StandardNormal};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Version of the manifest format.
pub const FORMAT: u32 = 1;

/// How the seeds are derived (written into the manifest).
pub const SEED_RULE: &str = "run seed = SplitMix64 output (index + 1) from base_seed: \
     mix(base_seed + (index + 1) * 0x9E3779B97F4A7C15), mix(z) = z ^= z >> 30; z *= \
     0xBF58476D1CE4E5B9; z ^= z >> 27; z *= 0x94D049BB133111EB; z ^ (z >> 31) (wrapping); \
     dispersion draws: ChaCha8 seeded with mix(run seed + 0x9E3779B97F4A7C15), stream = FNV-1a \
     64 of the dispersion's name; the simulator's noise streams use the run seed";

/// One run of the campaign.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Entry {
    /// Index, 0-based.
    pub index: u64,
    /// Simulator seed (sensor noise, slip, image noise; and terrain and calibration when
    /// `per_run`).
    pub seed: u64,
    /// Terrain seed used.
    pub terrain_seed: u64,
    /// Calibration (rover unit) seed used.
    pub calibration_seed: u64,
    /// The draw of each dispersion, by its name.
    pub draws: BTreeMap<String, f64>,
    /// The value of each dispersed parameter after all draws.
    pub params: BTreeMap<String, f64>,
}

/// `manifest.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Format version ([`FORMAT`]).
    pub format: u32,
    /// Campaign name.
    pub campaign: String,
    /// Description.
    pub description: String,
    /// The spec file as given to `plan`.
    pub spec_file: String,
    /// The spec's text.
    pub spec_text: String,
    /// The base scenario file as named by the spec.
    pub scenario_file: String,
    /// The base scenario's text.
    pub scenario_text: String,
    /// Runs planned.
    pub runs: u64,
    /// Base seed.
    pub base_seed: u64,
    /// How seeds are derived.
    pub seed_rule: String,
    /// Terrain and calibration seeds.
    pub seeds: Seeds,
    /// How each run is executed.
    pub run: RunSettings,
    /// Every run.
    pub entries: Vec<Entry>,
}

impl Manifest {
    /// The spec.
    pub fn spec(&self) -> anyhow::Result<Spec> {
        Spec::from_toml(&self.spec_text)
    }

    /// Read `DIR/manifest.json`.
    pub fn load(dir: &Path) -> anyhow::Result<Self> {
        let path = dir.join("manifest.json");
        let text = std::fs::read_to_string(&path).map_err(|e| {
            anyhow::anyhow!(
                "cannot read {}: {e} (run `sim-host campaign plan` first)",
                path.display()
            )
        })?;
        let m: Manifest =
            serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        anyhow::ensure!(
            m.format == FORMAT,
            "{}: manifest format {} (this sim-host reads {FORMAT})",
            path.display(),
            m.format
        );
        anyhow::ensure!(
            m.entries.len() as u64 == m.runs
                && m.entries
                    .iter()
                    .enumerate()
                    .all(|(i, e)| e.index == i as u64),
            "{}: entries do not match the run count",
            path.display()
        );
        Ok(m)
    }

    /// The entry of run `index`.
    pub fn entry(&self, index: u64) -> anyhow::Result<&Entry> {
        self.entries.get(index as usize).ok_or_else(|| {
            anyhow::anyhow!(
                "run index {index} out of range (the campaign has {} runs)",
                self.runs
            )
        })
    }

    /// The base scenario with the spec's overrides (before any draw).
    pub fn base_scenario(&self) -> anyhow::Result<Scenario> {
        base_scenario(&self.scenario_text, &self.spec()?.scenario_overrides)
    }

    /// The scenario of run `index`: the base scenario, the run's seeds and its parameters.
    pub fn scenario(&self, index: u64) -> anyhow::Result<Scenario> {
        let entry = self.entry(index)?;
        let mut s = self.base_scenario()?;
        apply_seeds(&mut s, &self.seeds, entry.seed);
        for (name, value) in &entry.params {
            params::set(&mut s, name, *value)?;
        }
        s.check()
            .map_err(|e| anyhow::anyhow!("run {index}: scenario refused: {e}"))?;
        Ok(s)
    }
}

/// The top-level keys of a scenario file (`crate::scenario::Scenario`), which
/// `scenario_overrides` may set.
pub const SCENARIO_KEYS: &[&str] = &[
    "name",
    "description",
    "seed",
    "terrain_seed",
    "calibration_seed",
    "start_offset",
    "duration_s",
    "speed_m_s",
    "goal_tolerance_m",
    "slip_limit",
    "max_position_sigma_m",
    "waypoints",
    "driver",
    "slip",
    "slip_model",
    "terrain",
    "soil",
    "site",
    "sensors",
    "faults",
];

/// Merge `over` into `base`: tables key by key (recursively), other values replaced.
pub fn merge(base: &mut toml::Table, over: &toml::Table) {
    for (k, v) in over {
        match (base.get_mut(k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            _ => {
                base.insert(k.clone(), v.clone());
            }
        }
    }
}

/// The scenario of `text` with `overrides` merged in.
pub fn base_scenario(text: &str, overrides: &toml::Table) -> anyhow::Result<Scenario> {
    for key in overrides.keys() {
        anyhow::ensure!(
            SCENARIO_KEYS.contains(&key.as_str()),
            "scenario_overrides: {key:?} is not a scenario key ({})",
            SCENARIO_KEYS.join(", ")
        );
    }
    let mut table: toml::Table = toml::from_str(text)?;
    merge(&mut table, overrides);
    Scenario::from_toml(&toml::to_string(&table)?)
        .map_err(|e| anyhow::anyhow!("scenario with the spec's overrides: {e}"))
}

/// Set the run's seeds in `s`.
fn apply_seeds(s: &mut Scenario, seeds: &Seeds, seed: u64) {
    s.seed = seed;
    s.terrain_seed = match seeds.terrain {
        SeedChoice::PerRun => None,
        SeedChoice::Fixed(v) => Some(v),
    };
    s.calibration_seed = match seeds.calibration {
        SeedChoice::PerRun => None,
        SeedChoice::Fixed(v) => Some(v),
    };
}

/// One draw of `dist`.
pub fn sample(dist: &Distribution, rng: &mut ChaCha8Rng) -> anyhow::Result<f64> {
    match *dist {
        Distribution::Uniform { min, max } => {
            let u: f64 = rng.random();
            Ok(min + (max - min) * u)
        }
        Distribution::Normal {
            mean,
            sigma,
            min,
            max,
        } => {
            let lo = min.unwrap_or(f64::NEG_INFINITY);
            let hi = max.unwrap_or(f64::INFINITY);
            for _ in 0..MAX_REDRAWS {
                let n: f64 = StandardNormal.sample(rng);
                let v = mean + sigma * n;
                if (lo..=hi).contains(&v) {
                    return Ok(v);
                }
            }
            anyhow::bail!("no draw inside [{lo}, {hi}] in {MAX_REDRAWS} tries")
        }
    }
}

/// Expand `spec` (whose base scenario's text is `scenario_text`) into a manifest of `runs` runs
/// (default: the spec's).
pub fn plan(
    spec: &Spec,
    spec_text: &str,
    spec_file: &str,
    scenario_text: &str,
    runs: Option<u64>,
) -> anyhow::Result<Manifest> {
    let runs = runs.unwrap_or(spec.runs);
    anyhow::ensure!(runs >= 1, "runs must be at least 1");
    let base = base_scenario(scenario_text, &spec.scenario_overrides)?;
    // Every parameter must exist in this scenario (a plane slope on dunes is an error now,
    // not at run 0 on the cluster).
    for d in &spec.dispersions {
        for p in &d.params {
            params::get(&mut base.clone(), p)
                .map_err(|e| anyhow::anyhow!("dispersion {:?}, {p}: {e}", d.key()))?;
        }
    }
    let mut entries = Vec::with_capacity(runs as usize);
    for index in 0..runs {
        let seed = super::run_seed(spec.base_seed, index);
        let mut s = base.clone();
        apply_seeds(&mut s, &spec.seeds, seed);
        let mut draws = BTreeMap::new();
        let mut values = BTreeMap::new();
        for d in &spec.dispersions {
            let key = d.key();
            let mut rng = ChaCha8Rng::seed_from_u64(super::draw_seed(seed));
            rng.set_stream(super::fnv1a64(&key));
            let v = sample(&d.dist, &mut rng)
                .map_err(|e| anyhow::anyhow!("run {index}, dispersion {key:?}: {e}"))?;
            draws.insert(key, v);
            for p in &d.params {
                let current = params::get(&mut s, p)?;
                let new = match d.apply {
                    Apply::Set => v,
                    Apply::Scale => current * v,
                    Apply::Offset => current + v,
                };
                params::set(&mut s, p, new)?;
            }
        }
        for d in &spec.dispersions {
            for p in &d.params {
                values.insert(p.clone(), params::get(&mut s, p)?);
            }
        }
        s.check().map_err(|e| {
            anyhow::anyhow!("run {index}: the drawn scenario is refused: {e} (draws {draws:?})")
        })?;
        entries.push(Entry {
            index,
            seed,
            terrain_seed: s.terrain_seed.unwrap_or(seed),
            calibration_seed: s.calibration_seed.unwrap_or(seed),
            draws,
            params: values,
        });
    }
    Ok(Manifest {
        format: FORMAT,
        campaign: spec.name.clone(),
        description: spec.description.clone(),
        spec_file: spec_file.to_string(),
        spec_text: spec_text.to_string(),
        scenario_file: spec.scenario.clone(),
        scenario_text: scenario_text.to_string(),
        runs,
        base_seed: spec.base_seed,
        seed_rule: SEED_RULE.to_string(),
        seeds: spec.seeds,
        run: spec.run,
        entries,
    })
}

/// The base scenario file of a spec at `spec_path`: relative to the spec's folder.
pub fn scenario_path(spec_path: &Path, scenario: &str) -> PathBuf {
    let p = Path::new(scenario);
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        spec_path.parent().unwrap_or_else(|| Path::new("")).join(p)
    }
}

/// Plan the spec file `spec_path` into `dir` (created): writes `dir/manifest.json`. A `dir`
/// that already holds the same manifest is kept (its finished runs stay); one that holds
/// another campaign is refused.
pub fn plan_to_dir(spec_path: &Path, dir: &Path, runs: Option<u64>) -> anyhow::Result<Manifest> {
    let spec_text = std::fs::read_to_string(spec_path)
        .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", spec_path.display()))?;
    let spec =
        Spec::from_toml(&spec_text).map_err(|e| anyhow::anyhow!("{}: {e}", spec_path.display()))?;
    let scenario_file = scenario_path(spec_path, &spec.scenario);
    let scenario_text = std::fs::read_to_string(&scenario_file)
        .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", scenario_file.display()))?;
    let manifest = plan(
        &spec,
        &spec_text,
        &spec_path.display().to_string(),
        &scenario_text,
        runs,
    )
    .map_err(|e| anyhow::anyhow!("{}: {e}", spec_path.display()))?;
    write_manifest(dir, &manifest)?;
    // Every step reads the manifest from the folder, as a run on a cluster node does.
    let read = Manifest::load(dir)?;
    anyhow::ensure!(
        read == manifest,
        "{}: the manifest does not read back as written",
        dir.display()
    );
    Ok(read)
}

/// The manifest as written (pretty JSON, a final newline).
pub fn manifest_text(m: &Manifest) -> anyhow::Result<String> {
    Ok(serde_json::to_string_pretty(m)? + "\n")
}

/// Write `dir/manifest.json` (see [`plan_to_dir`]).
pub fn write_manifest(dir: &Path, m: &Manifest) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir.join("runs"))?;
    let path = dir.join("manifest.json");
    let text = manifest_text(m)?;
    if let Ok(old) = std::fs::read_to_string(&path) {
        if old == text {
            return Ok(());
        }
        anyhow::bail!(
            "{} holds another campaign plan (a different spec, scenario or run count): choose \
             another --out or delete it",
            dir.display()
        );
    }
    super::exec::write_atomic(&path, &text)
}
