//! TUM trajectory files (`t x y z qx qy qz qw`, one pose per line, `#` comments), readable by
//! the `evo` tool with its default options. Poses are of the rover frame `R` in the world frame
//! `W` (x north, y east, z down); time in seconds since boot.
//!
//! `truth.tum` holds the truth at every stamp of every estimate file (the 20 Hz record times of
//! `ekf`, `kin3d`, `kin2d`, `dr` and the VO capture times of `vo`), so `evo_ape tum truth.tum
//! X.tum` associates every estimate pose with a truth pose of the same stamp (evo's default
//! tolerance is 10 ms; the VO captures are 15 ms off the record times).

use crate::closed_loop::Record;
use std::fmt::Write as _;

/// Which trajectory of a record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Trajectory {
    /// The simulator's truth.
    Truth,
    /// The flight EKF.
    Ekf,
    /// Flight VO relative poses chained (in records: the pose after the last update; the
    /// output files use [`crate::closed_loop::VoCheck`] at each capture time instead).
    Vo,
    /// Flight 3D kinematic dead reckoning.
    Kin3d,
    /// Flight planar wheel odometry (z is the EKF's start height; roll and pitch zero).
    Kin2d,
    /// Flight dead reckoning: wheel odometry with gyro attitude (RB's baseline).
    Dr,
}

impl Trajectory {
    /// The five flight estimates, in output order.
    pub const ESTIMATES: [Trajectory; 5] = [
        Trajectory::Ekf,
        Trajectory::Vo,
        Trajectory::Kin3d,
        Trajectory::Kin2d,
        Trajectory::Dr,
    ];

    /// File stem and summary key.
    pub fn name(self) -> &'static str {
        match self {
            Trajectory::Truth => "truth",
            Trajectory::Ekf => "ekf",
            Trajectory::Vo => "vo",
            Trajectory::Kin3d => "kin3d",
            Trajectory::Kin2d => "kin2d",
            Trajectory::Dr => "dr",
        }
    }

    /// The pose of this trajectory in `r` (position m, quaternion `[x, y, z, w]`), if it
    /// exists at that time.
    pub fn pose(self, r: &Record, start_z_m: f64) -> Option<([f64; 3], [f64; 4])> {
        let e = r.est.as_ref();
        match self {
            Trajectory::Truth => Some((r.pos_m, r.quat_xyzw)),
            Trajectory::Ekf => e.map(|e| (e.ekf_pos_m, e.ekf_quat_xyzw)),
            Trajectory::Vo => e.and_then(|e| e.vo),
            Trajectory::Kin3d => e.map(|e| e.kin3d),
            Trajectory::Dr => e.map(|e| e.dr),
            Trajectory::Kin2d => e.map(|e| {
                let (s, c) = (0.5 * e.kin2d[2]).sin_cos();
                ([e.kin2d[0], e.kin2d[1], start_z_m], [0.0, 0.0, s, c])
            }),
        }
    }
}

/// One TUM line; every file formats its stamps the same way, so equal times give equal text.
fn tum_line(s: &mut String, t_s: f64, p: [f64; 3], q: [f64; 4]) {
    let _ = writeln!(
        s,
        "{:.6} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}",
        t_s, p[0], p[1], p[2], q[0], q[1], q[2], q[3]
    );
}

fn tum_header(s: &mut String, header: &str) {
    let _ = writeln!(s, "# {header}");
    let _ = writeln!(s, "# frame W: x north, y east, z down (m); q: R to W; t: s");
}

/// The TUM text of the truth at every record time and at every VO capture time (the stamps of
/// all estimate files), in time order without repeated stamps.
pub fn truth_tum_text(
    header: &str,
    records: &[Record],
    checks: &[crate::closed_loop::VoCheck],
) -> String {
    let mut poses: Vec<(f64, [f64; 3], [f64; 4])> = records
        .iter()
        .map(|r| (r.t_s, r.pos_m, r.quat_xyzw))
        .chain(
            checks
                .iter()
                .map(|c| (c.t_s, c.truth_pose.0, c.truth_pose.1)),
        )
        .collect();
    // Times are whole microseconds of the simulation clock: compare them as such.
    let key = |t: f64| (t * 1e6).round() as i64;
    poses.sort_by_key(|p| key(p.0));
    poses.dedup_by_key(|p| key(p.0));
    let mut s = String::new();
    tum_header(&mut s, header);
    for (t, p, q) in poses {
        tum_line(&mut s, t, p, q);
    }
    s
}

/// The TUM text of the VO-only trajectory, one pose per VO update at its capture time.
pub fn vo_tum_text(header: &str, checks: &[crate::closed_loop::VoCheck]) -> String {
    let mut s = String::new();
    tum_header(&mut s, header);
    for c in checks {
        if let Some((p, q)) = c.vo_pose {
            tum_line(&mut s, c.t_s, p, q);
        }
    }
    s
}

/// The TUM text of one trajectory of `records`.
pub fn tum_text(header: &str, records: &[Record], which: Trajectory) -> String {
    let mut s = String::new();
    tum_header(&mut s, header);
    let start_z = records.first().map_or(0.0, |r| r.pos_m[2]);
    for r in records {
        if let Some((p, q)) = which.pose(r, start_z) {
            tum_line(&mut s, r.t_s, p, q);
        }
    }
    s
}
