//! Metrics that isolate one component of the navigation (`summary.json`): H04 eq. 15
//! kinematics alone, raw VO, slip estimation against the truth, the EKF's consistency (NEES)
//! and signed distance errors. `docs/simulator.md`, "Outputs", defines each.

use crate::closed_loop::{isolated, Record, RunResult};
use serde::Serialize;

/// An interval counts as slipping when its true slip is at least this fraction of its true
/// travel (and at least [`SLIP_EVENT_MIN_M`]): the heavy slip of H05's sand slopes (10-20 %).
pub const SLIP_EVENT_FRACTION: f64 = 0.2;
/// Smallest true slip of a slipping interval, m: 20 % of the 2.5 mm a 50 ms gate interval
/// covers at the nominal 5 cm/s.
pub const SLIP_EVENT_MIN_M: f64 = 0.0005;
/// An interval counts as not slipping when its true slip is at most this fraction of its
/// travel (the per-seed wheel-radius errors alone reach about 1 %).
pub const NO_SLIP_FRACTION: f64 = 0.02;

/// H04 eq. 15 kinematics alone ([`isolated::Eq15Odometry`]).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Eq15Summary {
    /// Final horizontal error / distance driven, %.
    pub error_pct: Option<f64>,
    /// Largest attitude error over the run, deg.
    pub attitude_error_max_deg: Option<f64>,
    /// Encoder readings whose eq. 15 solve was refused.
    pub refused: u32,
}

/// The VO pipeline's relative poses chained raw ([`isolated::VoRawChain`]).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct VoRawSummary {
    /// Final horizontal error (at the last VO capture) / distance driven, %.
    pub error_pct: Option<f64>,
    /// Largest attitude error at a VO capture, deg.
    pub attitude_error_max_deg: Option<f64>,
    /// Relative poses chained.
    pub poses: usize,
    /// Relative poses whose first capture was not chained (bridged with the true motion).
    pub gaps: u32,
}

/// Distance errors with their sign: (estimated path length - true) / true, %.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct SignedDistanceErrors {
    /// Flight 3D kinematic dead reckoning.
    pub kin3d: Option<f64>,
    /// H04 eq. 15 kinematics alone.
    pub kin_eq15: Option<f64>,
    /// Averaged wheel odometry (simulator-side baseline).
    pub wheel_average: f64,
}

/// Slip estimation against the truth.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct SlipTruthSummary {
    /// Kinematic intervals the gate decided.
    pub intervals: usize,
    /// Flight slip vector minus true slip over each interval, `[x, y]` m: rms.
    pub rms_m: Option<[f64; 2]>,
    /// ... and mean (bias).
    pub bias_m: Option<[f64; 2]>,
    /// Yaw slip: rms and mean of flight minus truth, deg.
    pub yaw_rms_deg: Option<f64>,
    /// Yaw slip bias, deg.
    pub yaw_bias_deg: Option<f64>,
    /// Intervals that slip ([`SLIP_EVENT_FRACTION`]) and the fraction of them the gate
    /// rejected (detection probability).
    pub slipping: usize,
    /// Detection probability.
    pub detection: Option<f64>,
    /// Intervals that do not slip ([`NO_SLIP_FRACTION`]) and the fraction of them the gate
    /// rejected (false-alarm rate).
    pub not_slipping: usize,
    /// False-alarm rate.
    pub false_alarm: Option<f64>,
    /// The 1 s slip estimate of the report (EKF travel against the 3D kinematics' over 20
    /// records) minus the truth's mean slip over the same window: slip ratio rms and bias.
    pub window_ratio_rms: Option<f64>,
    /// Slip-ratio bias of the 1 s estimate.
    pub window_ratio_bias: Option<f64>,
    /// Slip-angle rms of the 1 s estimate, deg.
    pub window_angle_rms_deg: Option<f64>,
    /// Slip-angle bias of the 1 s estimate, deg.
    pub window_angle_bias_deg: Option<f64>,
}

/// The EKF's consistency in closed loop over the 20 Hz records after alignment.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct NeesSummary {
    /// Records with an estimate.
    pub samples: usize,
    /// Mean horizontal-position NEES (2 dof: 2 when consistent).
    pub position_mean: Option<f64>,
    /// Fraction of records with the position NEES within the 95 % chi-square bound (5.991).
    pub position_within_95: Option<f64>,
    /// Mean heading NEES (1 dof: 1 when consistent).
    pub heading_mean: Option<f64>,
    /// Fraction of records with the heading NEES within the 95 % bound (3.841).
    pub heading_within_95: Option<f64>,
}

fn mean(v: impl Iterator<Item = f64>) -> Option<f64> {
    let (mut s, mut n) = (0.0, 0usize);
    for x in v {
        s += x;
        n += 1;
    }
    (n > 0).then(|| s / n as f64)
}

fn rms(v: impl Iterator<Item = f64>) -> Option<f64> {
    mean(v.map(|x| x * x)).map(f64::sqrt)
}

fn quat(v: [f64; 4]) -> nalgebra::UnitQuaternion<f64> {
    nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(v[3], v[0], v[1], v[2]))
}

fn yaw(v: [f64; 4]) -> f64 {
    quat(v).euler_angles().2
}

/// Eq. 15 alone.
pub fn eq15(run: &RunResult) -> Eq15Summary {
    let last = run
        .records
        .iter()
        .rev()
        .find_map(|r| r.kin_eq15.map(|k| (r, k)));
    Eq15Summary {
        error_pct: last.map(|(r, (p, _))| {
            100.0 * (p[0] - r.pos_m[0]).hypot(p[1] - r.pos_m[1]) / run.distance_m.max(1e-9)
        }),
        attitude_error_max_deg: run
            .records
            .iter()
            .filter_map(|r| {
                r.kin_eq15
                    .map(|(_, q)| quat(q).angle_to(&quat(r.quat_xyzw)).to_degrees())
            })
            .reduce(f64::max),
        refused: run.eq15_refused,
    }
}

/// Raw VO.
pub fn vo_raw(run: &RunResult) -> VoRawSummary {
    let pairs: Vec<_> = run
        .vo_checks
        .iter()
        .filter_map(|c| c.raw_pose.map(|p| (p, c.truth_pose)))
        .collect();
    VoRawSummary {
        error_pct: pairs.last().map(|((p, _), (t, _))| {
            100.0 * (p[0] - t[0]).hypot(p[1] - t[1]) / run.distance_m.max(1e-9)
        }),
        attitude_error_max_deg: pairs
            .iter()
            .map(|((_, q), (_, t))| quat(*q).angle_to(&quat(*t)).to_degrees())
            .reduce(f64::max),
        poses: pairs.len(),
        gaps: run.vo_raw_gaps,
    }
}

/// Horizontal path length of a trajectory, m.
fn length(points: impl Iterator<Item = [f64; 3]>) -> Option<f64> {
    let mut last: Option<[f64; 3]> = None;
    let mut total = 0.0;
    let mut n = 0;
    for p in points {
        if let Some(l) = last {
            total += (p[0] - l[0]).hypot(p[1] - l[1]);
        }
        last = Some(p);
        n += 1;
    }
    (n > 1).then_some(total)
}

/// Signed distance errors.
pub fn signed_distance(run: &RunResult) -> SignedDistanceErrors {
    let truth = run.distance_m.max(1e-9);
    let pct = |l: f64| 100.0 * (l - truth) / truth;
    SignedDistanceErrors {
        kin3d: length(run.records.iter().filter_map(|r| r.est.map(|e| e.kin3d.0))).map(pct),
        kin_eq15: length(run.records.iter().filter_map(|r| r.kin_eq15.map(|k| k.0))).map(pct),
        wheel_average: pct(run.records.last().map_or(0.0, |r| r.wheel_average_m)),
    }
}

/// Slip against the truth.
pub fn slip_truth(run: &RunResult) -> SlipTruthSummary {
    let iv: &[isolated::SlipInterval] = &run.slip_intervals;
    let d = |k: usize| iv.iter().map(move |i| i.flight[k] - i.truth[k]);
    let true_slip = |i: &isolated::SlipInterval| i.truth[0].hypot(i.truth[1]);
    let slipping: Vec<_> = iv
        .iter()
        .filter(|i| true_slip(i) >= (SLIP_EVENT_FRACTION * i.travel_m).max(SLIP_EVENT_MIN_M))
        .collect();
    let still: Vec<_> = iv
        .iter()
        .filter(|i| i.travel_m > 0.0 && true_slip(i) <= NO_SLIP_FRACTION * i.travel_m)
        .collect();
    let rejected = |v: &[&isolated::SlipInterval]| {
        (!v.is_empty()).then(|| v.iter().filter(|i| !i.accepted).count() as f64 / v.len() as f64)
    };
    let both = |f: fn(Box<dyn Iterator<Item = f64> + '_>) -> Option<f64>| {
        f(Box::new(d(0)))
            .zip(f(Box::new(d(1))))
            .map(|(a, b)| [a, b])
    };
    let est = crate::output::report::estimated_slip(&run.records);
    let truth = crate::output::report::true_slip(&run.records);
    // Both lists end at a record time: pair them by time.
    let paired: Vec<_> = est
        .iter()
        .filter_map(|e| truth.iter().find(|t| t.0 == e.0).map(|t| (e, t)))
        .collect();
    SlipTruthSummary {
        intervals: iv.len(),
        rms_m: both(|v| rms(v)),
        bias_m: both(|v| mean(v)),
        yaw_rms_deg: rms(d(2)).map(f64::to_degrees),
        yaw_bias_deg: mean(d(2)).map(f64::to_degrees),
        slipping: slipping.len(),
        detection: rejected(&slipping),
        not_slipping: still.len(),
        false_alarm: rejected(&still),
        window_ratio_rms: rms(paired.iter().map(|(e, t)| e.1 - t.1)),
        window_ratio_bias: mean(paired.iter().map(|(e, t)| e.1 - t.1)),
        window_angle_rms_deg: rms(paired.iter().map(|(e, t)| isolated::wrap(e.2 - t.2)))
            .map(f64::to_degrees),
        window_angle_bias_deg: mean(paired.iter().map(|(e, t)| isolated::wrap(e.2 - t.2)))
            .map(f64::to_degrees),
    }
}

/// Position (2 dof) and heading (1 dof) NEES of one record.
fn record_nees(r: &Record) -> Option<(f64, f64)> {
    let e = r.est?;
    let [nn, ne, ee] = e.ekf_pos_cov_ne;
    let det = nn * ee - ne * ne;
    let (dn, de) = (e.ekf_pos_m[0] - r.pos_m[0], e.ekf_pos_m[1] - r.pos_m[1]);
    let pos = (det > 0.0).then(|| (ee * dn * dn - 2.0 * ne * dn * de + nn * de * de) / det)?;
    let dh = isolated::wrap(yaw(e.ekf_quat_xyzw) - yaw(r.quat_xyzw));
    let s2 = e.ekf_heading_sigma_rad.powi(2);
    let heading = (s2 > 0.0).then(|| dh * dh / s2)?;
    Some((pos, heading))
}

/// The EKF's NEES.
pub fn nees(run: &RunResult) -> NeesSummary {
    let v: Vec<(f64, f64)> = run.records.iter().filter_map(record_nees).collect();
    let b2 = fsw::estimation::gate::chi2_95(2).unwrap_or(f64::INFINITY);
    let b1 = fsw::estimation::gate::chi2_95(1).unwrap_or(f64::INFINITY);
    let frac = |f: &dyn Fn(&(f64, f64)) -> bool| {
        (!v.is_empty()).then(|| v.iter().filter(|x| f(x)).count() as f64 / v.len() as f64)
    };
    NeesSummary {
        samples: v.len(),
        position_mean: mean(v.iter().map(|x| x.0)),
        position_within_95: frac(&|x| x.0 <= b2),
        heading_mean: mean(v.iter().map(|x| x.1)),
        heading_within_95: frac(&|x| x.1 <= b1),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An error of one sigma along each axis has a NEES of one per axis.
    #[test]
    fn nees_of_a_one_sigma_error() {
        let mut r = Record {
            t_s: 0.0,
            pos_m: [0.0; 3],
            quat_xyzw: [0.0, 0.0, 0.0, 1.0],
            rpy_rad: [0.0; 3],
            suspension_rad: [0.0; 3],
            slip_ratio: 0.0,
            slip_angle_rad: 0.0,
            cross_track_m: 0.0,
            distance_m: 0.0,
            wheel_average_m: 0.0,
            est: None,
            kin_eq15: None,
        };
        assert!(record_nees(&r).is_none());
        let h = 0.02_f64;
        r.est = Some(crate::closed_loop::Estimates {
            ekf_pos_m: [0.1, 0.2, 0.0],
            ekf_quat_xyzw: [0.0, 0.0, (0.5 * h).sin(), (0.5 * h).cos()],
            ekf_pos_sigma_m: [0.1, 0.2, 0.1],
            ekf_heading_sigma_rad: 0.01,
            ekf_pos_cov_ne: [0.01, 0.0, 0.04],
            vo: None,
            kin3d: ([0.0; 3], [0.0, 0.0, 0.0, 1.0]),
            kin2d: [0.0; 3],
            dr: ([0.0; 3], [0.0, 0.0, 0.0, 1.0]),
            slip: [0.0; 3],
            gate_accepted: true,
            kin_tested: 0,
            gate_d2: 0.0,
            gate_dof: 0,
        });
        let (p, hd) = record_nees(&r).unwrap();
        assert!((p - 2.0).abs() < 1e-12, "{p}");
        assert!((hd - 4.0).abs() < 1e-9, "{hd}");
    }
}
