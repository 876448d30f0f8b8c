//! TUM trajectory files (`t x y z qx qy qz qw`, one pose per line, `#` comments), readable by
//! the `evo` tool. Poses are of the rover frame `R` in the world frame `W` (x north, y east,
//! z down); time in seconds since boot.

use crate::sim::Record;
use std::fmt::Write as _;

/// Which trajectory of a record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Trajectory {
    /// The simulator's truth.
    Truth,
    /// The flight EKF.
    Ekf,
    /// Flight VO relative poses chained (in records: the pose after the last update; the
    /// output files use [`crate::sim::VoCheck`] at each capture time instead).
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

/// The TUM text of the VO-only trajectory, one pose per VO update at its capture time.
pub fn vo_tum_text(header: &str, checks: &[crate::sim::VoCheck]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# {header}");
    let _ = writeln!(s, "# frame W: x north, y east, z down (m); q: R to W; t: s");
    for c in checks {
        if let Some((p, q)) = c.vo_pose {
            let _ = writeln!(
                s,
                "{:.6} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}",
                c.t_s, p[0], p[1], p[2], q[0], q[1], q[2], q[3]
            );
        }
    }
    s
}

/// The TUM text of one trajectory of `records`.
pub fn tum_text(header: &str, records: &[Record], which: Trajectory) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# {header}");
    let _ = writeln!(s, "# frame W: x north, y east, z down (m); q: R to W; t: s");
    let start_z = records.first().map_or(0.0, |r| r.pos_m[2]);
    for r in records {
        let Some((p, q)) = which.pose(r, start_z) else {
            continue;
        };
        let _ = writeln!(
            s,
            "{:.6} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}",
            r.t_s, p[0], p[1], p[2], q[0], q[1], q[2], q[3]
        );
    }
    s
}
