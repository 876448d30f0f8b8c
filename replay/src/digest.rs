//! FNV-1a 64 digests over little-endian bit patterns.
//!
//! Floating-point values are hashed by their IEEE 754 bit patterns (`f64::to_bits`), so two
//! values digest equal exactly when they are bit-identical (`0.0` and `-0.0` differ, as do two
//! NaNs with different payloads).

use rover_hal::{ImuSample, JointState, MobilityCommand, PowerReading, SunReading};

/// FNV-1a 64 offset basis.
const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
/// FNV-1a 64 prime.
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

/// A running FNV-1a 64 digest.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Digest(u64);

impl Default for Digest {
    fn default() -> Self {
        Self::new()
    }
}

impl Digest {
    /// An empty digest (the FNV offset basis).
    pub const fn new() -> Self {
        Self(FNV_OFFSET)
    }

    /// The digest value.
    pub fn value(&self) -> u64 {
        self.0
    }

    /// Add bytes.
    pub fn bytes(&mut self, bytes: &[u8]) -> &mut Self {
        for b in bytes {
            self.0 ^= u64::from(*b);
            self.0 = self.0.wrapping_mul(FNV_PRIME);
        }
        self
    }

    /// Add a `u8`.
    pub fn u8(&mut self, v: u8) -> &mut Self {
        self.bytes(&[v])
    }

    /// Add a `bool` (one byte, 0 or 1).
    pub fn bool(&mut self, v: bool) -> &mut Self {
        self.u8(u8::from(v))
    }

    /// Add a `u32`, little-endian.
    pub fn u32(&mut self, v: u32) -> &mut Self {
        self.bytes(&v.to_le_bytes())
    }

    /// Add a `u64`, little-endian.
    pub fn u64(&mut self, v: u64) -> &mut Self {
        self.bytes(&v.to_le_bytes())
    }

    /// Add an `f64` by its bit pattern, little-endian.
    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.u64(v.to_bits())
    }

    /// Add `f64`s in order (for example a nalgebra matrix's `as_slice()`, column-major).
    pub fn f64s(&mut self, v: &[f64]) -> &mut Self {
        for x in v {
            self.f64(*x);
        }
        self
    }

    /// Add anything [`Digestible`].
    pub fn put<T: Digestible + ?Sized>(&mut self, v: &T) -> &mut Self {
        v.digest(self);
        self
    }
}

/// A value with a defined digest (every field, in declaration order).
pub trait Digestible {
    /// Add this value to `h`.
    fn digest(&self, h: &mut Digest);
}

impl Digestible for f64 {
    fn digest(&self, h: &mut Digest) {
        h.f64(*self);
    }
}

impl Digestible for u64 {
    fn digest(&self, h: &mut Digest) {
        h.u64(*self);
    }
}

impl Digestible for u32 {
    fn digest(&self, h: &mut Digest) {
        h.u32(*self);
    }
}

impl Digestible for bool {
    fn digest(&self, h: &mut Digest) {
        h.bool(*self);
    }
}

impl<T: Digestible> Digestible for [T] {
    fn digest(&self, h: &mut Digest) {
        for v in self {
            v.digest(h);
        }
    }
}

impl<T: Digestible, const N: usize> Digestible for [T; N] {
    fn digest(&self, h: &mut Digest) {
        self.as_slice().digest(h);
    }
}

/// `None` adds a 0 byte; `Some(v)` a 1 byte and `v`.
impl<T: Digestible> Digestible for Option<T> {
    fn digest(&self, h: &mut Digest) {
        match self {
            None => {
                h.u8(0);
            }
            Some(v) => {
                h.u8(1);
                v.digest(h);
            }
        }
    }
}

impl Digestible for ImuSample {
    fn digest(&self, h: &mut Digest) {
        h.u64(self.t_us)
            .put(&self.gyro_rad_s)
            .put(&self.accel_m_s2)
            .bool(self.valid);
    }
}

impl Digestible for JointState {
    fn digest(&self, h: &mut Digest) {
        h.u64(self.t_us)
            .put(&self.drive_angle_rad)
            .put(&self.drive_rate_rad_s)
            .put(&self.steer_angle_rad)
            .f64(self.rocker_rad)
            .put(&self.bogie_rad)
            .put(&self.wheel_valid)
            .bool(self.suspension_valid);
    }
}

impl Digestible for SunReading {
    fn digest(&self, h: &mut Digest) {
        h.u64(self.t_us)
            .put(&self.sun_dir_rover)
            .bool(self.sun_in_view);
    }
}

impl Digestible for PowerReading {
    fn digest(&self, h: &mut Digest) {
        h.u64(self.t_us)
            .f64(self.energy_used_j)
            .f64(self.bus_power_w)
            .bool(self.valid);
    }
}

impl Digestible for MobilityCommand {
    fn digest(&self, h: &mut Digest) {
        h.put(&self.steer_angle_rad).put(&self.wheel_rate_rad_s);
    }
}
