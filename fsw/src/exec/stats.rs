//! Execution-time statistics for a task, a group or the whole frame.

/// Last, minimum, maximum and mean execution time, microseconds, with an overrun count against
/// a budget. Samples whose clock reads failed are not recorded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimingStats {
    /// Budget, microseconds; 0 means no budget (no overruns counted).
    pub budget_us: u32,
    /// Last sample, microseconds.
    pub last_us: u64,
    /// Smallest sample, microseconds (`u64::MAX` before the first sample).
    pub min_us: u64,
    /// Largest sample, microseconds.
    pub max_us: u64,
    /// Sum of all samples, microseconds (saturating).
    pub total_us: u64,
    /// Number of samples.
    pub samples: u64,
    /// Samples above the budget.
    pub overruns: u64,
}

impl TimingStats {
    /// Empty statistics with a budget in microseconds (0: none).
    pub const fn new(budget_us: u32) -> Self {
        Self {
            budget_us,
            last_us: 0,
            min_us: u64::MAX,
            max_us: 0,
            total_us: 0,
            samples: 0,
            overruns: 0,
        }
    }

    /// Add one sample; `None` (clock fault) is ignored.
    pub fn record(&mut self, sample_us: Option<u64>) {
        let Some(us) = sample_us else { return };
        self.last_us = us;
        self.min_us = self.min_us.min(us);
        self.max_us = self.max_us.max(us);
        self.total_us = self.total_us.saturating_add(us);
        self.samples = self.samples.saturating_add(1);
        if self.budget_us > 0 && us > u64::from(self.budget_us) {
            self.overruns = self.overruns.saturating_add(1);
        }
    }

    /// Mean of the samples, microseconds (0 without samples).
    pub fn mean_us(&self) -> u64 {
        self.total_us.checked_div(self.samples).unwrap_or(0)
    }

    /// Smallest sample, or 0 without samples.
    pub fn min_or_zero(&self) -> u64 {
        if self.samples == 0 {
            0
        } else {
            self.min_us
        }
    }
}
