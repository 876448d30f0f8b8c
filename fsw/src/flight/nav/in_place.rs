//! [`InPlace`]: storage of a large part of the navigator built in place after the navigator.

/// Storage of a large part of the navigator that is built in place after the navigator
/// (visual odometry, hazard navigation): the value always exists (a placeholder until built,
/// so that building it writes into this storage instead of moving a new value in), `built`
/// says whether it is in use. Reads like an `Option`.
pub struct InPlace<T> {
    /// The value (a placeholder until built).
    pub value: T,
    /// The value is built and in use.
    pub built: bool,
}

impl<T> InPlace<T> {
    /// `value` as the placeholder, not built.
    pub const fn unbuilt(value: T) -> Self {
        Self {
            value,
            built: false,
        }
    }

    /// The part when built.
    pub fn as_ref(&self) -> Option<&T> {
        self.built.then_some(&self.value)
    }

    /// The part when built, mutable.
    pub fn as_mut(&mut self) -> Option<&mut T> {
        self.built.then_some(&mut self.value)
    }

    /// True when built.
    pub fn is_some(&self) -> bool {
        self.built
    }
}
