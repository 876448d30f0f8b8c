//! Output files of a run: `truth.tum`, `ekf.tum`, `vo.tum`, `kin3d.tum`, `kin2d.tum`, `dr.tum`,
//! `vo_checks.csv`, `summary.json`, `report.html`.

pub mod components;
pub mod report;
pub mod summary;
pub mod tum;

use crate::closed_loop::RunResult;
use std::path::Path;

/// Write every output of `run` into `dir` (created if missing). Returns the summary.
pub fn write_all(dir: &Path, run: &RunResult) -> anyhow::Result<summary::Summary> {
    std::fs::create_dir_all(dir)?;
    std::fs::write(
        dir.join("truth.tum"),
        tum::truth_tum_text(
            &format!(
                "truth of {} seed {} at every estimate stamp (20 Hz records and VO captures)",
                run.scenario, run.seed
            ),
            &run.records,
            &run.vo_checks,
        ),
    )?;
    for which in tum::Trajectory::ESTIMATES {
        let name = which.name();
        let header = format!(
            "{name}: flight estimate of {} seed {} ({} driving)",
            run.scenario, run.seed, run.driver
        );
        let text = if which == tum::Trajectory::Vo {
            tum::vo_tum_text(&header, &run.vo_checks)
        } else {
            tum::tum_text(&header, &run.records, which)
        };
        std::fs::write(dir.join(format!("{name}.tum")), text)?;
    }
    let mut csv = String::from(
        "# flight VO relative poses checked against the truth (rover frame at the first capture)\n\
         t_s,step_m,ex_m,ey_m,ez_m,sx_m,sy_m,sz_m,erx_rad,ery_rad,erz_rad,srx_rad,sry_rad,srz_rad\n",
    );
    for c in &run.vo_checks {
        let v = [
            c.t_s,
            c.step_m,
            c.trans_err_m[0],
            c.trans_err_m[1],
            c.trans_err_m[2],
            c.trans_sigma_m[0],
            c.trans_sigma_m[1],
            c.trans_sigma_m[2],
            c.rot_err_rad[0],
            c.rot_err_rad[1],
            c.rot_err_rad[2],
            c.rot_sigma_rad[0],
            c.rot_sigma_rad[1],
            c.rot_sigma_rad[2],
        ];
        let line: Vec<String> = v.iter().map(|x| format!("{x:.6e}")).collect();
        csv += &line.join(",");
        csv.push('\n');
    }
    std::fs::write(dir.join("vo_checks.csv"), csv)?;
    let s = summary::summarise(run);
    std::fs::write(
        dir.join("summary.json"),
        serde_json::to_string_pretty(&s)? + "\n",
    )?;
    std::fs::write(
        dir.join("report.html"),
        crate::output::report::report_html(run, &s)?,
    )?;
    Ok(s)
}
