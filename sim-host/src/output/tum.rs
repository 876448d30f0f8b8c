//! TUM trajectory files (`t x y z qx qy qz qw`, one pose per line, `#` comments), readable by
//! the `evo` tool. Poses are of the rover frame `R` in the world frame `W` (x north, y east,
//! z down); time in seconds since boot.

use crate::sim::Record;
use std::fmt::Write as _;

/// The TUM text of `records`.
pub fn tum_text(header: &str, records: &[Record]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# {header}");
    let _ = writeln!(s, "# frame W: x north, y east, z down (m); q: R to W; t: s");
    for r in records {
        let _ = writeln!(
            s,
            "{:.6} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}",
            r.t_s,
            r.pos_m[0],
            r.pos_m[1],
            r.pos_m[2],
            r.quat_xyzw[0],
            r.quat_xyzw[1],
            r.quat_xyzw[2],
            r.quat_xyzw[3]
        );
    }
    s
}
