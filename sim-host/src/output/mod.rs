//! Output files of a run: `truth.tum`, `ekf.tum`, `vo.tum`, `kin3d.tum`, `kin2d.tum`,
//! `summary.json`, `report.html`.

pub mod summary;
pub mod tum;

use crate::sim::RunResult;
use std::path::Path;

/// Write every output of `run` into `dir` (created if missing). Returns the summary.
pub fn write_all(dir: &Path, run: &RunResult) -> anyhow::Result<summary::Summary> {
    std::fs::create_dir_all(dir)?;
    std::fs::write(
        dir.join("truth.tum"),
        tum::tum_text(
            &format!("truth of {} seed {}", run.scenario, run.seed),
            &run.records,
        ),
    )?;
    for name in ["ekf", "vo", "kin3d", "kin2d"] {
        std::fs::write(
            dir.join(format!("{name}.tum")),
            tum::tum_text(
                &format!("{name}: no flight estimate yet (the flight code does not produce it)"),
                &[],
            ),
        )?;
    }
    let s = summary::summarise(run);
    std::fs::write(
        dir.join("summary.json"),
        serde_json::to_string_pretty(&s)? + "\n",
    )?;
    std::fs::write(dir.join("report.html"), crate::report::report_html(run, &s))?;
    Ok(s)
}
