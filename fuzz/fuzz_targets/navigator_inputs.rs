//! The navigator's device surface on arbitrary input: the bytes are read as a stream of IMU
//! samples, joint readings and sun readings (raw f64 and u64 values, so NaN, infinities, huge
//! and backwards values all occur) fed to `Navigator` the way the executive does (RG1 every
//! record, RG2 every tenth, RG4 every hundredth). Invariants: no panic; every motor command
//! finite and within the rover's limits.
#![no_main]

use fsw::flight::nav::{NavConfig, Navigator};
use libfuzzer_sys::fuzz_target;
use rover_hal::{ImuSample, JointState, SunReading};

/// Little-endian reader of the fuzz input; yields zeros when it runs out.
struct Bytes<'a>(&'a [u8]);

impl Bytes<'_> {
    fn u64(&mut self) -> u64 {
        let (head, rest) = self.0.split_at(self.0.len().min(8));
        self.0 = rest;
        let mut b = [0u8; 8];
        b[..head.len()].copy_from_slice(head);
        u64::from_le_bytes(b)
    }
    fn f64(&mut self) -> f64 {
        f64::from_bits(self.u64())
    }
    fn byte(&mut self) -> u8 {
        let (head, rest) = self.0.split_at(self.0.len().min(1));
        self.0 = rest;
        head.first().copied().unwrap_or(0)
    }
}

fuzz_target!(|data: &[u8]| {
    let mut config = NavConfig::rocky8([0.0; 3], 0.0);
    config.vo_enabled = false;
    config.align_samples = 4;
    config.align_sun_wait_samples = 0;
    let calib = fsw::vo::rocky8_hazcam();
    let Ok(mut nav) = Navigator::new(config, &[[0.0, 0.0], [5.0, 0.0]], &calib) else {
        return;
    };
    let limits = config.geometry.limits;
    let mut input = Bytes(data);
    let mut k = 0u64;
    while !input.0.is_empty() && k < 10_000 {
        k += 1;
        let imu = ImuSample {
            t_us: input.u64(),
            gyro_rad_s: [input.f64(), input.f64(), input.f64()],
            accel_m_s2: [input.f64(), input.f64(), input.f64()],
            valid: input.byte() & 1 == 1,
        };
        nav.propagate(Some(&imu));
        if k % 10 == 0 {
            let mut j = JointState {
                t_us: input.u64(),
                rocker_rad: input.f64(),
                bogie_rad: [input.f64(), input.f64()],
                wheel_valid: [true; 6],
                suspension_valid: input.byte() & 1 == 1,
                ..JointState::default()
            };
            for w in 0..6 {
                j.drive_angle_rad[w] = input.f64();
                j.drive_rate_rad_s[w] = input.f64();
                j.steer_angle_rad[w] = input.f64();
            }
            nav.kinematic_cycle(Some(&j));
            if let Some(cmd) = nav.guidance_cycle() {
                for w in 0..6 {
                    let (rate, steer) = (cmd.wheel_rate_rad_s[w], cmd.steer_angle_rad[w]);
                    assert!(rate.is_finite() && rate.abs() <= limits.wheel_rate_rad_s + 1e-9);
                    assert!(steer.is_finite() && steer.abs() <= limits.steer_rad + 1e-9);
                }
            }
            // RG2B, half an RG2 period later.
            nav.zero_velocity_cycle();
        }
        if k % 100 == 0 {
            nav.sun(&SunReading {
                t_us: input.u64(),
                sun_dir_rover: [input.f64(), input.f64(), input.f64()],
                sun_in_view: input.byte() & 1 == 1,
            });
        }
    }
});
