//! # Sliced background jobs on a stereo frame
//!
//! Visual odometry ([`crate::vo::VisualOdometry`]), the hazard mapper
//! ([`crate::perception::HazardMapper`]) and the rectification ([`crate::rectify::Rectifier`])
//! are jobs on one stereo frame advanced in the frames' slack, a quantum of work items at a
//! time ([`super::spend_quantum`]). They share one step ([`step_frame_job`]): a job that is not
//! running refuses the step, a frame that is not the one the job started on (another capture,
//! or images the job cannot use) stops it, and the job stops at its result.

use rover_hal::StereoFrame;

/// What one step of a sliced job reports.
// The result is returned by value: there is no heap to box it on.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Progress<T> {
    /// The job is not finished; step it again with the same frame.
    Working {
        /// Work items done so far in this job.
        items: u32,
    },
    /// The job is finished (it is idle again).
    Finished(T),
}

/// The identity of a stereo frame: its capture time (us) and the camera's sequence number.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FrameKey {
    /// Capture time stamp, us since boot.
    pub capture_t_us: u64,
    /// The camera's sequence number of the pair.
    pub sequence: u32,
}

impl FrameKey {
    /// The key of `frame`.
    pub fn of(frame: &StereoFrame) -> Self {
        Self {
            capture_t_us: frame.capture_t_us,
            sequence: frame.sequence,
        }
    }
}

/// A background job on one stereo frame (module doc).
pub trait FrameJob {
    /// The job's error values.
    type Error;
    /// The error of a step while no job runs.
    const NOT_STARTED: Self::Error;
    /// The error of a step on another frame than the job's, or on images it cannot use.
    const FRAME_CHANGED: Self::Error;
    /// A job is running (started and not finished).
    fn running(&self) -> bool;
    /// The frame the running job started on.
    fn frame(&self) -> FrameKey;
    /// The job is over (finished, or stopped by a changed frame): it is idle.
    fn stop(&mut self);
    /// Work items done so far in the running job.
    fn items(&self) -> u32;
}

/// One step of the sliced job `job` on `frame` with a budget of `quantum` cost units: refused
/// ([`FrameJob::NOT_STARTED`]) when no job runs; stopped ([`FrameJob::FRAME_CHANGED`]) when
/// `open` finds nothing the job can use in `frame` (its view of the frame: the images, or a
/// target memory) or the frame is not the job's; otherwise work items (`item`: the cost of
/// the item it ran, in units of about 10 000 rover-CPU instructions, and the job's result when
/// that item finished it) until the costs reach the quantum or the job finishes, which stops
/// it.
pub fn step_frame_job<J: FrameJob, V, R>(
    job: &mut J,
    frame: &StereoFrame,
    quantum: u32,
    open: impl FnOnce() -> Option<V>,
    mut item: impl FnMut(&mut J, &mut V) -> (u16, Option<Result<R, J::Error>>),
) -> Progress<Result<R, J::Error>> {
    if !job.running() {
        return Progress::Finished(Err(J::NOT_STARTED));
    }
    let view = open();
    let (Some(mut view), true) = (view, job.frame() == FrameKey::of(frame)) else {
        job.stop();
        return Progress::Finished(Err(J::FRAME_CHANGED));
    };
    let done = super::spend_quantum(quantum, || item(job, &mut view));
    match done {
        Some(result) => {
            job.stop();
            Progress::Finished(result)
        }
        None => Progress::Working { items: job.items() },
    }
}
