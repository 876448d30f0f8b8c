//! The generated page `docs/results/timing.md`: its fixed text is the template `page.md` (next to this
//! file), whose `{name}` placeholders [`document`] fills with the measured figures, the tables
//! and the few sentences that depend on them.

use super::{
    background_slice_insns, flight_stack_ok, fmt_time, groups, margin, pass, response_time, secs,
    stack_headroom_ok, stack_peak, thousands, Group, Measured, CLOCK_HZ, CPI, DESIGN_MARGIN,
    FRAME_S, GOAL_IK, GOAL_PROPAGATE, GOAL_RG2_FRAME, GOAL_STACK, GOAL_STATIC_RAM, GOAL_VO,
    MAX_FLIGHT_STACK, SCENARIO, SECONDS,
};
use crate::cpi::{self, GroupCost};
use crate::elf::ElfReport;
use crate::stack::{self, StackReport, Summary as StackSummary};
use anyhow::{bail, Context, Result};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;

/// The template of the page.
const PAGE: &str = include_str!("page.md");

/// Rows of a deepest path shown in the document.
const STATIC_PATH_ROWS: usize = 14;

/// The image's initialisation functions: the flight software's and the navigation-task
/// bench's construction.
const INIT_FUNCTIONS: [&str; 2] = [
    "fsw_image::target::install_new_fsw",
    "fsw_image::target::bench::Bench::install",
];

/// The deepest path from the image's entry through one of [`INIT_FUNCTIONS`] (the static
/// counterpart of the painted initialisation peak).
fn init_path(sr: &StackReport, ss: &StackSummary) -> Option<stack::DeepPath> {
    let entry = ss.entry.as_ref()?.steps.first()?.func;
    INIT_FUNCTIONS
        .iter()
        .filter_map(|name| sr.find(|n| n == *name))
        .filter_map(|via| sr.deepest_through(entry, via))
        .max_by_key(|p| p.total)
}

const TASK_DOC: [(&str, &str, &str); 17] = [
    (
        "ekf_propagate",
        "`Ekf::propagate`",
        "RG1: one IMU sample (every valid sample of the tape)",
    ),
    (
        "ekf_gate_relative_pose",
        "`Ekf::gate_relative_pose`",
        "RG2: Mahalanobis gate of the kinematic relative pose; and of each VO pose",
    ),
    (
        "ekf_update_relative_pose",
        "`Ekf::update_relative_pose`",
        "RG2: update between two clones (applied ungated, so always whole)",
    ),
    (
        "ekf_clone",
        "`Ekf::clone_at`",
        "RG2 interval start and RG3 capture",
    ),
    (
        "ekf_gate_fuse_without_vo",
        "`Ekf::gate_relative_pose_kept` then `Ekf::fuse_kept_relative_pose` (every other kinematic interval of the tape instead of the gate and the update)",
        "RG2 without VO: the interval gated at its own covariance, then fused with z observed and the slip allowances from the kept innovation (`Navigator::fuse_without_vo`)",
    ),
    (
        "forward_kinematics",
        "`kinematics::forward_kinematics_from_joints`",
        "not called by the flight software (the odometry integrates the joints itself); the body-rate solve of one joint reading, kept as a kinematics benchmark",
    ),
    (
        "kinematic_odometry",
        "`KinematicOdometry::update_with_gyro` (the flight configuration: eq. 15 step with its covariance, and the contact-angle estimator on the tape's gyro rotation since the last reading)",
        "RG2: odometry integration of a joint reading",
    ),
    (
        "inverse_kinematics",
        "`kinematics::inverse_kinematics_contact` (worst case: on the odometry's contact angles without the navigator's 0.1 rad deadband)",
        "RG2: steering and wheel rates of guidance's command",
    ),
    (
        "guidance_step",
        "`Guidance::step`",
        "RG2: carrot, heading and crab loops on the EKF pose",
    ),
    (
        "vo_update",
        "`VisualOdometry::<150>::start`, then `step` per work item",
        "background: one full update on a 640x480 pair in `.extram`",
    ),
    (
        "hazard_map",
        "`HazardMapper::start`, then `step` per work item",
        "background (goal-directed drives): one hazard map of the pair after VO",
    ),
    (
        "roverbug_plan",
        "`Planner::plan_each` with the map's polygons built as it takes them (as `hazard_nav` flies it)",
        "background, after a hazard map: one RoverBug step (the tape's scene: few obstacles)",
    ),
    (
        "rectify_pair",
        "`Rectifier::start`, then `step` per row item (`fsw::rectify`)",
        "background, before VO: rectification of the raw wide-angle pair (2 x 480 rows, \
         fixed-point map every 8 px, integer bilinear)",
    ),
    (
        "rectify_row",
        "one `Rectifier::step` item",
        "one rectified row of 640 pixels (`RectifyConfig::row_cost` should cover its largest)",
    ),
    (
        "localization_map",
        "`GlobalMap::reset_centred`, `insert_point` per point, `finish`",
        "once per uplinked map: a 38.4 m global map of a synthetic field of 392 rocks \
         (`fsw/image/src/target/loc_bench.rs`), with its distance transform",
    ),
    (
        "localize",
        "`Localizer::localize`",
        "background, after a hazard map: one branch-and-bound localization of a hazard grid against that map, prior 0.3 m / \
         0.03 rad, 8 synthetic trials",
    ),
    (
        "sequencer_replan",
        "`Sequencer::replan_committed`",
        "background, on a trigger of the navigator's mission: one replan of 8 \
         targets with windows, energy, a leg penalty and the commitment to one target, 8 random \
         problems",
    ),
];

/// The values of the page's placeholders.
type Values = BTreeMap<&'static str, String>;

/// The page: [`PAGE`] with every placeholder filled.
#[allow(clippy::too_many_arguments)]
pub(super) fn document(
    m: &Measured,
    r: &ElfReport,
    replay: &[&str],
    stack_sizes: &str,
    (sr, ss): (&StackReport, &StackSummary),
    qemu: &str,
    (mca, loops): (&str, &[GroupCost]),
) -> Result<String> {
    let mut v = Values::new();
    let groups = groups(m);
    method_values(&mut v, m, qemu);
    task_values(&mut v, m)?;
    frame_values(&mut v, m)?;
    let u = utilisation_values(&mut v, &groups, loops)?;
    response_values(&mut v, m, &groups)?;
    cpi_values(&mut v, mca, loops)?;
    stack_values(&mut v, m, r, stack_sizes);
    static_values(&mut v, m, sr, ss)?;
    memory_values(&mut v, r)?;
    panic_values(&mut v, r)?;
    replay_values(&mut v, m, replay);
    goal_values(&mut v, m, r, &groups, u);
    fill(PAGE, &v)
}

/// `template` with each `{name}` replaced by its value; fails on a placeholder without a
/// value and on a value without a placeholder.
fn fill(template: &str, values: &Values) -> Result<String> {
    let mut out = String::with_capacity(2 * template.len());
    let mut used = BTreeSet::new();
    let mut rest = template;
    while let Some(i) = rest.find('{') {
        out.push_str(&rest[..i]);
        let after = &rest[i + 1..];
        let end = after.find('}').context("page.md: a `{` without `}`")?;
        let key = &after[..end];
        let value = values
            .get(key)
            .with_context(|| format!("page.md: no value for {{{key}}}"))?;
        out.push_str(value);
        used.insert(key);
        rest = &after[end + 1..];
    }
    out.push_str(rest);
    let unused: Vec<&&str> = values.keys().filter(|k| !used.contains(**k)).collect();
    if !unused.is_empty() {
        bail!("page.md has no placeholder for {unused:?}");
    }
    Ok(out)
}

/// The run, the method and the stated clock and CPI.
fn method_values(v: &mut Values, m: &Measured, qemu: &str) {
    let calib = |k: &str| m.calib.get(k).copied().unwrap_or(0);
    v.insert("qemu", qemu.to_string());
    v.insert("seconds", SECONDS.to_string());
    v.insert("scenario", SCENARIO.to_string());
    v.insert("tape_frames", m.tape.1.to_string());
    v.insert("tape_bytes", thousands(m.tape.2));
    v.insert("insns_per_count", calib("insns_per_count").to_string());
    v.insert("overhead", calib("overhead").to_string());
    v.insert("loop2", thousands(calib("loop2")));
    v.insert("loop4", thousands(calib("loop4")));
    v.insert("clock_mhz", format!("{:.0}", CLOCK_HZ / 1e6));
    v.insert("cpi_lo", format!("{:.1}", CPI[0]));
    v.insert("cpi_hi", format!("{:.1}", CPI[1]));
    v.insert("design_margin", format!("{:.0}", 100.0 * DESIGN_MARGIN));
}

/// The flight tasks, visual odometry and its work items.
fn task_values(v: &mut Values, m: &Measured) -> std::fmt::Result {
    let mut rows = String::new();
    for (key, func, what) in TASK_DOC {
        let s = m.task(key);
        writeln!(
            rows,
            "| {key} ({what}) | {func} | {} | {} | {} | {} | {} / {} | {} |",
            s.n,
            thousands(s.min),
            thousands(s.max),
            thousands(s.mean),
            fmt_time(secs(s.max, CPI[0])),
            fmt_time(secs(s.max, CPI[1])),
            s.errors
        )?;
    }
    v.insert("task_rows", rows);
    let vo = |k: &str| m.vo.get(k).copied().unwrap_or(0).to_string();
    v.insert("vo_updates", vo("updates"));
    v.insert("vo_poses", vo("poses"));
    v.insert("vo_failures", vo("failures"));
    v.insert("inliers_min", vo("inliers_min"));
    v.insert("inliers_max", vo("inliers_max"));
    v.insert("work_items_max", vo("work_items_max"));
    v.insert("background_quantum", m.background_quantum.to_string());
    let mut rows = String::new();
    for (name, s) in &m.vo_items {
        let cost = m.vo_cost.get(name).copied().unwrap_or(0).max(1) * 10_000;
        writeln!(
            rows,
            "| {name} | {} | {} | {} | {} | {} | {:.2} |",
            s.n,
            thousands(s.min),
            thousands(s.max),
            thousands(s.mean),
            thousands(cost),
            s.max as f64 / cost as f64
        )?;
    }
    v.insert("vo_item_rows", rows);
    Ok(())
}

/// The whole minor frames of the replay and the executive's own timing.
fn frame_values(v: &mut Values, m: &Measured) -> std::fmt::Result {
    let mut rows = String::new();
    for (name, s) in &m.frames {
        writeln!(
            rows,
            "| {name} | {} | {} | {} | {} | {} / {} |",
            s.n,
            thousands(s.min),
            thousands(s.max),
            thousands(s.mean),
            fmt_time(secs(s.max, CPI[0])),
            fmt_time(secs(s.max, CPI[1]))
        )?;
    }
    v.insert("frame_rows", rows);
    v.insert("replay_insns", thousands(m.replay_insns));
    let mut rows = String::new();
    for (name, runs, max, mean) in &m.exec {
        writeln!(rows, "| {name} | {runs} | {max} | {mean} |")?;
    }
    v.insert("exec_rows", rows);
    let mut rows = String::new();
    for (name, max, mean, budget) in &m.exec_tasks {
        writeln!(
            rows,
            "| {name} | {max} | {mean} | {budget} | {:.2} |",
            *max as f64 / (*budget).max(1) as f64
        )?;
    }
    v.insert("exec_task_rows", rows);
    Ok(())
}

/// Total utilisation: at the two stated CPIs, at each group's model CPI, and at the binding
/// figure (each group at the higher of CPI 2.0 and its model CPI).
#[derive(Debug, Clone, Copy)]
struct Utilisation {
    at_cpi: [f64; 2],
    bind: f64,
}

/// The utilisation table and its totals; returns the totals.
fn utilisation_values(
    v: &mut Values,
    groups: &[Group],
    loops: &[GroupCost],
) -> Result<Utilisation> {
    let mut rows = String::new();
    let mut u = [0.0; 2];
    let mut u_model = 0.0;
    // The binding figure: each group at CPI 2.0 or its model CPI, whichever is higher.
    let mut u_bind = 0.0;
    for g in groups {
        let ui = CPI.map(|c| secs(g.insns, c) / g.period_s);
        u[0] += ui[0];
        u[1] += ui[1];
        let c = model_cpi(g.name, loops);
        let um = secs(g.insns, c) / g.period_s;
        u_model += um;
        u_bind += secs(g.insns, c.max(CPI[1])) / g.period_s;
        writeln!(
            rows,
            "| {} | {} | {} | {} | {:.2} % | {:.2} % | {:.2} | {:.2} % |",
            g.name,
            fmt_time(g.period_s),
            thousands(g.insns),
            g.content,
            100.0 * ui[0],
            100.0 * ui[1],
            c,
            100.0 * um
        )?;
    }
    let rt_u: [f64; 2] = CPI.map(|c| {
        groups
            .iter()
            .filter(|g| g.name != "VO" && g.name != "HAZ")
            .map(|g| secs(g.insns, c) / g.period_s)
            .sum()
    });
    v.insert("group_rows", rows);
    v.insert("u_lo", format!("{:.2}", 100.0 * u[0]));
    v.insert("u_hi", format!("{:.2}", 100.0 * u[1]));
    v.insert("u_model", format!("{:.2}", 100.0 * u_model));
    v.insert("rt_u_lo", format!("{:.2}", 100.0 * rt_u[0]));
    v.insert("rt_u_hi", format!("{:.2}", 100.0 * rt_u[1]));
    v.insert("u_bind", format!("{:.2}", 100.0 * u_bind));
    v.insert(
        "margin_lo",
        format!("{:+.1}", 100.0 * (DESIGN_MARGIN - u[0])),
    );
    v.insert(
        "margin_hi",
        format!("{:+.1}", 100.0 * (DESIGN_MARGIN - u[1])),
    );
    Ok(Utilisation {
        at_cpi: u,
        bind: u_bind,
    })
}

/// The response times and the worst minor frame with its background slice.
fn response_values(v: &mut Values, m: &Measured, groups: &[Group]) -> std::fmt::Result {
    let mut rows = String::new();
    for (i, g) in groups.iter().enumerate() {
        let cells: Vec<String> = CPI
            .iter()
            .map(|c| match response_time(groups, i, *c) {
                Some(rt) => format!("{} | {:.1} %", fmt_time(rt), 100.0 * rt / g.period_s),
                None => "misses its deadline | > 100 %".into(),
            })
            .collect();
        writeln!(
            rows,
            "| {} | {} | {} | {} |",
            g.name,
            fmt_time(g.period_s),
            cells[0],
            cells[1]
        )?;
    }
    v.insert("response_rows", rows);
    let worst_frame = groups[0].insns + groups[1].insns;
    let slice = background_slice_insns(m);
    let pct = |insns: u64, cpi: f64| format!("{:.1}", 100.0 * secs(insns, cpi) / 0.005);
    v.insert("worst_frame", thousands(worst_frame));
    v.insert("worst_frame_t_lo", fmt_time(secs(worst_frame, CPI[0])));
    v.insert("worst_frame_t_hi", fmt_time(secs(worst_frame, CPI[1])));
    v.insert("worst_frame_pct_lo", pct(worst_frame, CPI[0]));
    v.insert("worst_frame_pct_hi", pct(worst_frame, CPI[1]));
    v.insert("slice", thousands(slice));
    v.insert("slice_t_lo", fmt_time(secs(slice, CPI[0])));
    v.insert("slice_t_hi", fmt_time(secs(slice, CPI[1])));
    v.insert("with_slice_pct_lo", pct(worst_frame + slice, CPI[0]));
    v.insert("with_slice_pct_hi", pct(worst_frame + slice, CPI[1]));
    Ok(())
}

/// The section "Cycles per instruction": the CPI of the image's code on the Cortex-M7
/// pipeline model ([`cpi`]), weighted by the tape's block counts.
fn cpi_values(v: &mut Values, mca: &str, loops: &[GroupCost]) -> std::fmt::Result {
    v.insert("mca", mca.to_string());
    v.insert("cpi_iterations", cpi::ITERATIONS.to_string());
    v.insert("cpi_coverage", format!("{:.1}", 100.0 * cpi::COVERAGE));
    v.insert("cpi_max_blocks", cpi::MAX_BLOCKS.to_string());
    let mut rows = String::new();
    for (g, c) in cpi::GROUPS.iter().zip(loops.iter()) {
        let (lo, hi) = c.range().unwrap_or((f64::NAN, f64::NAN));
        let p = c.profile.clone().unwrap_or_default();
        let f = |v: Option<f64>| v.map(|v| format!("{v:.2}")).unwrap_or_else(|| "-".into());
        writeln!(
            rows,
            "| {} | {} | {} / {} | {:.1} % | **{}** | {} | {} ({}) | {:.2} - {:.2} |",
            g.label,
            thousands(p.executed),
            p.blocks,
            p.simulated_blocks,
            100.0 * p.coverage(),
            f(p.cpi()),
            f(c.loop_cpi()),
            c.loops.len(),
            c.skipped,
            lo,
            hi,
        )?;
    }
    v.insert("cpi_rows", rows);
    Ok(())
}

/// The painted stack of each phase and the stack region.
fn stack_values(v: &mut Values, m: &Measured, r: &ElfReport, stack_sizes: &str) {
    let stack = |k: &str| m.stack.get(k).copied().unwrap_or(0);
    v.insert("stack_init", thousands(stack("init")));
    v.insert("stack_flight", thousands(stack("flight")));
    v.insert("stack_bench", thousands(stack("bench")));
    v.insert("stack_region", thousands(stack("region")));
    v.insert("stack_region_start", format!("{:08x}", r.stack_region.1));
    v.insert("stack_region_end", format!("{:08x}", r.stack_region.0));
    let vo_kib = r
        .statics
        .iter()
        .find(|s| s.name.contains("vo_static"))
        .map(|s| s.size / 1024)
        .unwrap_or(0);
    v.insert("vo_kib", vo_kib.to_string());
    v.insert("stack_sizes", stack_sizes.to_string());
}

/// The "Static analysis" part of the Stack section ([`crate::stack`]).
fn static_values(
    v: &mut Values,
    m: &Measured,
    sr: &StackReport,
    ss: &StackSummary,
) -> std::fmt::Result {
    let painted = |k: &str| m.stack.get(k).copied().unwrap_or(0);
    v.insert("static_functions", sr.funcs.len().to_string());
    let init = init_path(sr, ss);
    let roots: [(&str, &Option<stack::DeepPath>, String); 4] = [
        (
            "image entry (`Reset`): every phase",
            &ss.entry,
            format!("{} B (deepest phase)", thousands(stack_peak(m))),
        ),
        (
            "image entry through the initialisation (`install_new_fsw`, `Bench::install`)",
            &init,
            format!("{} B (initialisation)", thousands(painted("init"))),
        ),
        ("`Fsw::tick` alone", &ss.tick, "-".into()),
        (
            "image entry through `Fsw::tick` (flight phase)",
            &ss.flight,
            format!("{} B (flight)", thousands(painted("flight"))),
        ),
    ];
    let mut rows = String::new();
    for (name, p, painted) in roots {
        match p {
            Some(p) => writeln!(
                rows,
                "| {name} | {} B | {painted} | {} | {} |",
                thousands(p.total),
                p.reachable,
                p.reachable_indirect
            )?,
            None => writeln!(
                rows,
                "| {name} | not found in the image | {painted} | - | - |"
            )?,
        }
    }
    v.insert("static_root_rows", rows);
    let mut paths = String::new();
    if let Some(p) = &ss.flight {
        writeln!(
            paths,
            "Deepest path from the entry through `Fsw::tick` (the flight phase's static bound; the painted figure also covers the replay harness around `tick` and reads up to 256 B high, see above):\n"
        )?;
        path_table(&mut paths, sr, p)?;
    }
    if let Some(p) = &init {
        writeln!(
            paths,
            "Deepest path from the entry through the initialisation (everything built in place, see above):\n"
        )?;
        path_table(&mut paths, sr, p)?;
    }
    if let Some(p) = &ss.entry {
        writeln!(paths, "Deepest path from the entry (every phase):\n")?;
        path_table(&mut paths, sr, p)?;
    }
    v.insert("static_paths", paths);
    indirect_values(v, sr, ss);
    v.insert("cycles", cycles_sentence(sr));
    Ok(())
}

/// The indirect calls and jumps of the image and how many the roots reach.
fn indirect_values(v: &mut Values, sr: &StackReport, ss: &StackSummary) {
    let with_indirect: Vec<String> = sr
        .funcs
        .iter()
        .filter(|f| f.indirect > 0)
        .map(|f| format!("`{}` ({})", stack::short(&f.name), f.indirect))
        .collect();
    let unresolved: usize = sr.funcs.iter().map(|f| f.unresolved).sum();
    let tick_indirect = ss.tick.as_ref().map_or(0, |p| p.reachable_indirect);
    let entry_indirect = ss.entry.as_ref().map_or(0, |p| p.reachable_indirect);
    v.insert("indirect_total", sr.indirect_total().to_string());
    v.insert("indirect_functions", with_indirect.len().to_string());
    v.insert(
        "indirect_list",
        format!(
            "{}{}",
            if with_indirect.is_empty() { "" } else { ": " },
            with_indirect.join(", ")
        ),
    );
    v.insert("tick_indirect", tick_indirect.to_string());
    v.insert(
        "tick_indirect_note",
        if tick_indirect == 0 {
            " (its figure covers everything it can call)"
        } else {
            " (its figure leaves out what they call)"
        }
        .to_string(),
    );
    v.insert("entry_indirect", entry_indirect.to_string());
    v.insert(
        "entry_indirect_note",
        if entry_indirect == 0 {
            ""
        } else {
            " (the entry's figure leaves out what they call: when they are all in `core::fmt`, the number formatting of the semihosting reports printed between the phases, through trait objects)"
        }
        .to_string(),
    );
    v.insert("unresolved", unresolved.to_string());
}

/// The cycles (recursion) of the call graph.
fn cycles_sentence(sr: &StackReport) -> String {
    if sr.cycles.is_empty() {
        return "Cycles (recursion) in the call graph: none.".into();
    }
    let list: Vec<String> = sr
        .cycles
        .iter()
        .map(|c| {
            let names: Vec<String> = c
                .iter()
                .map(|&i| format!("`{}`", stack::short(&sr.funcs[i].name)))
                .collect();
            names.join(" / ")
        })
        .collect();
    format!(
        "Cycles (recursion) in the call graph: {} ({} closing edges cut): {}.",
        sr.cycles.len(),
        sr.cut_edges,
        list.join("; ")
    )
}

/// One deepest path as a table, [`STATIC_PATH_ROWS`] rows at most.
fn path_table(d: &mut String, sr: &StackReport, p: &stack::DeepPath) -> std::fmt::Result {
    writeln!(d, "| stack in use at entry | frame | function |")?;
    writeln!(d, "|---:|---:|---|")?;
    for st in p.steps.iter().take(STATIC_PATH_ROWS) {
        let f = &sr.funcs[st.func];
        writeln!(
            d,
            "| {} B | {} B | {}`{}` |",
            thousands(st.depth_at_entry),
            thousands(f.frame),
            if st.tail { "(tail call) " } else { "" },
            stack::short(&f.name).replace('|', "\\|")
        )?;
    }
    if p.steps.len() > STATIC_PATH_ROWS {
        writeln!(d, "| | | ... {} more |", p.steps.len() - STATIC_PATH_ROWS)?;
    }
    writeln!(d)?;
    Ok(())
}

/// The sections, the memory budgets and the largest statics.
fn memory_values(v: &mut Values, r: &ElfReport) -> std::fmt::Result {
    let mut rows = String::new();
    for s in &r.sections {
        writeln!(
            rows,
            "| {} | 0x{:08x} | {} B |",
            s.name,
            s.addr,
            thousands(s.size)
        )?;
    }
    v.insert("section_rows", rows);
    let flash =
        r.section(".vector_table") + r.section(".text") + r.section(".rodata") + r.section(".data");
    let ram = r.section(".data") + r.section(".bss") + r.section(".uninit");
    let extram = r.section(".extram");
    v.insert("flash", thousands(flash));
    v.insert(
        "flash_pct",
        format!("{:.1}", 100.0 * flash as f64 / (4.0 * 1024.0 * 1024.0)),
    );
    v.insert("ram", thousands(ram));
    v.insert(
        "ram_pct",
        format!("{:.1}", 100.0 * ram as f64 / (512.0 * 1024.0)),
    );
    v.insert("extram", thousands(extram));
    v.insert(
        "extram_pct",
        format!("{:.1}", 100.0 * extram as f64 / (16.0 * 1024.0 * 1024.0)),
    );
    let mut rows = String::new();
    for s in &r.statics {
        writeln!(
            rows,
            "| `{}` | 0x{:08x} | {} B |",
            s.name,
            s.addr,
            thousands(s.size)
        )?;
    }
    v.insert("statics_rows", rows);
    Ok(())
}

/// The allocator check and the panic sites.
fn panic_values(v: &mut Values, r: &ElfReport) -> std::fmt::Result {
    v.insert(
        "allocator",
        if r.allocator_symbols.is_empty() {
            "**No allocator**: the image's symbol table has none of `__rust_alloc`, `__rust_dealloc`, `__rust_realloc`, `__rust_alloc_zeroed`, `__rg_alloc`, `__rdl_alloc`, `__rust_alloc_error_handler` or any `alloc::alloc::` function (and the flight crates are `no_std` without `extern crate alloc`)."
                .to_string()
        } else {
            format!(
                "**Allocator symbols found**: {}",
                r.allocator_symbols.join(", ")
            )
        },
    );
    v.insert("panic_total", r.panic_total().to_string());
    v.insert("decoded", thousands(r.decoded_instructions as u64));
    let flight_panics: usize = r.flight_panic_sites().iter().map(|(_, n)| n).sum();
    v.insert("flight_panics", flight_panics.to_string());
    let mut rows = String::new();
    for (name, n) in &r.panic_sites {
        writeln!(rows, "| `{name}` | {n} |")?;
    }
    v.insert("panic_function_rows", rows);
    let mut rows = String::new();
    for (name, n) in &r.panic_sites_by_crate {
        writeln!(rows, "| `{name}` | {n} |")?;
    }
    v.insert("panic_crate_rows", rows);
    let mut rows = String::new();
    for (name, n) in r.panic_sites_by_function.iter().take(15) {
        writeln!(rows, "| `{name}` | {n} |")?;
    }
    v.insert("panic_site_function_rows", rows);
    Ok(())
}

/// The replay's digest lines and its end line.
fn replay_values(v: &mut Values, m: &Measured, replay: &[&str]) {
    let lines: String = replay.iter().map(|l| format!("{l}\n")).collect();
    v.insert("replay_lines", lines);
    v.insert(
        "replay_result",
        if replay_ok(m) {
            "bit-identical"
        } else {
            "MISMATCH"
        }
        .to_string(),
    );
    v.insert("replay_end", m.replay_end.clone());
}

/// The replay ended with no mismatch and no divergence.
fn replay_ok(m: &Measured) -> bool {
    m.replay_end.contains("mismatches 0") && m.replay_end.contains("divergence none")
}

/// The goals table.
fn goal_values(v: &mut Values, m: &Measured, r: &ElfReport, groups: &[Group], u: Utilisation) {
    let stack = |k: &str| m.stack.get(k).copied().unwrap_or(0);
    let prop = m.task("ekf_propagate").max;
    v.insert("goal_propagate", thousands(GOAL_PROPAGATE));
    v.insert("propagate", thousands(prop));
    v.insert("propagate_ok", pass(prop <= GOAL_PROPAGATE).into());
    let ik = m.task("inverse_kinematics").max;
    v.insert("goal_ik", thousands(GOAL_IK));
    v.insert("ik", thousands(ik));
    v.insert("ik_ok", pass(ik <= GOAL_IK).into());
    let rg2 = groups[1].insns;
    v.insert("goal_rg2", thousands(GOAL_RG2_FRAME));
    v.insert("rg2", thousands(rg2));
    v.insert("rg2_ok", pass(rg2 <= GOAL_RG2_FRAME).into());
    // The largest frame measured on the replay (any groups, with its background slice) against
    // the 5 ms minor frame at CPI 2: a frame over it is a cycle slip on a CPU at that CPI.
    let (worst_name, worst) = m
        .frames
        .iter()
        .map(|(name, s)| (name.as_str(), s.max))
        .max_by_key(|(_, v)| *v)
        .unwrap_or(("none", 0));
    let worst_pct = 100.0 * secs(worst, CPI[1]) / FRAME_S;
    v.insert("worst_name", worst_name.to_string());
    v.insert("worst", thousands(worst));
    v.insert("worst_pct", format!("{worst_pct:.1}"));
    v.insert("worst_ok", pass(worst_pct <= 100.0).into());
    let vo = m.task("vo_update").max;
    v.insert("goal_vo", thousands(GOAL_VO));
    v.insert("vo", thousands(vo));
    v.insert("vo_ok", pass(vo <= GOAL_VO).into());
    v.insert("u_lo_goal", format!("{:.1}", 100.0 * u.at_cpi[0]));
    v.insert("u_lo_ok", pass(u.at_cpi[0] <= DESIGN_MARGIN).into());
    v.insert("u_hi_goal", format!("{:.1}", 100.0 * u.at_cpi[1]));
    v.insert("u_hi_ok", pass(u.at_cpi[1] <= DESIGN_MARGIN).into());
    v.insert("u_bind_goal", format!("{:.1}", 100.0 * u.bind));
    v.insert("u_bind_ok", pass(u.bind <= DESIGN_MARGIN).into());
    let st = stack("flight").max(stack("bench"));
    v.insert("stack_max", thousands(st));
    v.insert("stack_ok", pass(st <= GOAL_STACK).into());
    v.insert("stack_margin", margin(MAX_FLIGHT_STACK, stack("flight")));
    v.insert("flight_stack_ok", pass(flight_stack_ok(m)).into());
    v.insert("init_stack_ok", pass(stack("init") <= GOAL_STACK).into());
    v.insert("stack_peak", thousands(stack_peak(m)));
    v.insert("headroom_ok", pass(stack_headroom_ok(m)).into());
    let ram = r.section(".data") + r.section(".bss") + r.section(".uninit");
    v.insert("ram_ok", pass(ram <= GOAL_STATIC_RAM).into());
    v.insert("replay_ok", pass(replay_ok(m)).into());
    let flight_panics: usize = r.flight_panic_sites().iter().map(|(_, n)| n).sum();
    v.insert("panics_ok", pass(flight_panics == 0).into());
}

/// The model CPI of a utilisation group: the largest of the code groups ([`cpi::GROUPS`], by
/// index) its tasks run; 2.0 when a code group has neither a profile nor loops.
fn model_cpi(group: &str, loops: &[GroupCost]) -> f64 {
    // Indices into `cpi::GROUPS`: 0 VO, 1 rectification, 2 perception, 3 localization, 4 EKF,
    // 5 kinematics, 6 executive and navigation, 7 libm, 8 runtime (every group copies).
    let parts: &[usize] = match group {
        "RG1" => &[4, 6, 8],
        "RG2" => &[4, 5, 6, 7, 8],
        "RG2B" => &[4, 6, 8],
        "RG3" | "SEQ" => &[4, 6, 8],
        "RG4" => &[4, 6, 7, 8],
        "VO" => &[0, 1, 8],
        "HAZ" => &[0, 2, 6, 8],
        "LOC" => &[3, 8],
        _ => &[0, 1, 2, 3, 4, 5, 6, 7, 8],
    };
    parts
        .iter()
        .map(|&i| loops.get(i).and_then(GroupCost::cpi).unwrap_or(CPI[1]))
        .fold(0.0, f64::max)
}
