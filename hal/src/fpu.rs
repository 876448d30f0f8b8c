//! FPU glue of the rover CPU: the only `unsafe` code of the flight crates (ARCHITECTURE:
//! "no `unsafe` outside clearly marked HAL glue"). No frame or unit of its own: plain IEEE 754
//! arithmetic on the caller's quantities.
//!
//! `libm::sqrt` is an integer emulation of the square root (about 75 instructions on the
//! Cortex-M7: 21 M instructions over the timing tape, most in the Cholesky factors of
//! the VO and the EKF). The Cortex-M7's double-precision FPU has `vsqrt.f64`. Both are
//! correctly rounded (IEEE 754 requires it of the square root; musl's `sqrt`, which `libm`
//! ports, is correctly rounded in round-to-nearest, the FPSCR's reset mode), so the host (which
//! keeps `libm::sqrt`) and the rover CPU give bit-identical results; `cargo xtask timing`
//! checks it on every run by the replay digests of the flight software.

/// `sqrt(x)`, correctly rounded; NaN for a negative or NaN `x`, `+inf` for `+inf`, `-0` for
/// `-0`. One `vsqrt.f64` on the rover CPU (Arm with the hard-float ABI), `libm::sqrt` elsewhere.
#[inline(always)]
pub fn sqrt(x: f64) -> f64 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    {
        let r: f64;
        // SAFETY: one FPU instruction from a register to a register: no memory access, no
        // stack, no flags (`vsqrt` sets only the FPSCR's cumulative exception bits, which the
        // flight software never reads).
        #[allow(unsafe_code)]
        unsafe {
            core::arch::asm!(
                "vsqrt.f64 {r}, {x}",
                r = lateout(dreg_low16) r,
                x = in(dreg_low16) x,
                options(pure, nomem, nostack, preserves_flags)
            );
        }
        r
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    {
        libm::sqrt(x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    extern crate std;

    /// The premise of the bit-identity: the host's `libm::sqrt` is correctly rounded, as the
    /// FPU's square root is (here checked against the host FPU's, `sqrtsd` on x86-64).
    #[test]
    fn correctly_rounded_and_special_values() {
        let mut x = 1.0e-300_f64;
        for _ in 0..4000 {
            assert_eq!(sqrt(x).to_bits(), x.sqrt().to_bits(), "x = {x:e}");
            // Neighbours of squares, where a faithful but not correctly rounded root differs.
            let y = x * x;
            if y.is_normal() {
                for z in [
                    f64::from_bits(y.to_bits() - 1),
                    y,
                    f64::from_bits(y.to_bits() + 1),
                ] {
                    assert_eq!(sqrt(z).to_bits(), z.sqrt().to_bits(), "z = {z:e}");
                }
            }
            x *= 1.1892;
        }
        assert!(sqrt(-1.0).is_nan() && sqrt(f64::NAN).is_nan());
        assert_eq!(sqrt(f64::INFINITY), f64::INFINITY);
        assert_eq!(sqrt(-0.0).to_bits(), (-0.0f64).to_bits());
        assert_eq!(sqrt(4.0), 2.0);
    }
}
