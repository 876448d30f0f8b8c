//! # The stereo stage: capture trigger, polling, rectification and the background slices
//!
//! RG3 `stereo` triggers a capture when the navigator's capture policy says one is due
//! ([`super::nav::Navigator::capture_due`]); a capture not completed within
//! [`CAPTURE_TIMEOUT_FRAMES`] is timed out. In the background the stereo stage polls the
//! camera, checks the frame (time stamp of the capture, image sizes, order), rectifies a raw
//! pair into the image memory ([`crate::rectify`]) and hands the pair to the navigator, which
//! runs VO, a hazard map or a localization search on it in slices
//! ([`super::nav::Navigator::vo_step`]). A replan of the day's targets and the replay of a
//! late VO update take the slice first.

use super::devices::{check_order, count_error, count_invalid};
use super::{DeviceId, Platform, Work};
use crate::rectify::{Rectifier, RectifyMemory, RectifyProgress};
use rover_hal::{CaptureStatus, ErrorKind, StereoCamera};

/// Minor frames a stereo capture may take to complete before it is counted as a camera
/// timeout and dropped (1 s).
pub const CAPTURE_TIMEOUT_FRAMES: u64 = 200;

/// The rectification stage between the camera and the navigator.
#[derive(Debug, Clone, Copy)]
pub(super) struct RectStage {
    pub(super) rectifier: Rectifier,
    /// Capture time and sequence of the raw pair being rectified.
    pub(super) pending: Option<(u64, u32)>,
    /// Capture time and sequence of the rectified pair in the image memory that VO or the
    /// hazard mapper is working on.
    pub(super) frame: Option<(u64, u32)>,
}

impl<P: Platform> Work<'_, P> {
    #[inline(never)]
    pub(super) fn trigger_stereo(&mut self, tick: u64) {
        let health = &mut self.state.health[DeviceId::Camera as usize];
        if self.state.capture_pending_t_us.is_some() {
            if tick.saturating_sub(self.state.capture_pending_tick) < CAPTURE_TIMEOUT_FRAMES {
                return;
            }
            // The capture has not completed within the timeout: count, drop and retry when due.
            count_error(health, ErrorKind::Timeout);
            if self.devices.camera.release().is_err() {
                count_error(health, ErrorKind::Hardware);
            }
            self.state.capture_pending_t_us = None;
            self.nav.capture_lost();
        }
        // The navigator decides (capture policy). No capture is triggered that VO cannot use:
        // while VO works on the last frame (held) or its result is replayed, a due capture
        // waits (the condition persists) and starts at the first RG3 after VO is idle.
        let Some(reason) = self.nav.capture_due() else {
            return;
        };
        match self.devices.camera.trigger() {
            Ok(t_us) => {
                self.state.capture_pending_t_us = Some(t_us);
                self.state.capture_pending_tick = tick;
                self.nav.capture_started(t_us, reason);
            }
            Err(e) => count_error(health, rover_hal::Error::kind(&e)),
        }
    }

    fn release_frame(&mut self) {
        if self.devices.camera.release().is_err() {
            let health = &mut self.state.health[DeviceId::Camera as usize];
            count_error(health, ErrorKind::Hardware);
        }
    }

    /// Background: rectify rows of the raw pair in the camera's buffers into the image
    /// memory ([`crate::rectify`]); when the pair is done the camera frame is released and VO
    /// (or the hazard mapper) starts on the rectified pair. Returns the units used.
    #[inline(never)]
    fn rectify_step(&mut self, quantum: u32) -> u32 {
        let progress = match self.devices.camera.frame() {
            Ok(frame) => self
                .rect
                .rectifier
                .step(&frame, &mut self.devices.image_memory, quantum),
            Err(e) => {
                let health = &mut self.state.health[DeviceId::Camera as usize];
                count_error(health, rover_hal::Error::kind(&e));
                RectifyProgress::Finished(Err(crate::rectify::RectifyError::FrameChanged))
            }
        };
        let result = match progress {
            RectifyProgress::Working { .. } => return quantum.max(1),
            RectifyProgress::Finished(result) => result,
        };
        // The raw pair is no longer needed either way.
        self.release_frame();
        let pending = self.rect.pending.take();
        match (result, pending) {
            (Ok(()), Some((t_us, sequence))) => {
                self.state.rectified_pairs = self.state.rectified_pairs.saturating_add(1);
                let (left, right) = self.devices.image_memory.images();
                let frame = rover_hal::StereoFrame {
                    left,
                    right,
                    capture_t_us: t_us,
                    sequence,
                };
                if self.nav.vo_start(&frame) {
                    self.rect.frame = Some((t_us, sequence));
                } else {
                    self.nav.capture_lost();
                }
            }
            _ => {
                self.rect.rectifier.reset();
                self.state.rectify_failures = self.state.rectify_failures.saturating_add(1);
                self.nav.capture_lost();
            }
        }
        quantum.max(1)
    }

    pub(super) fn poll_stereo(&mut self, quantum: u32) -> u32 {
        // A replan of the day's targets takes the slice (V99 sec. 3).
        if self.nav.mission_replan_due() {
            return self.nav.mission_background(quantum);
        }
        if self.nav.replaying() {
            return self.nav.replay_step();
        }
        if self.rect.rectifier.is_busy() {
            return self.rectify_step(quantum);
        }
        if self.nav.vo_busy() {
            if let Some((t_us, sequence)) = self.rect.frame {
                // VO or the hazard mapper on the rectified pair in the image memory (the raw
                // pair was released when it was rectified).
                let (left, right) = self.devices.image_memory.images();
                let frame = rover_hal::StereoFrame {
                    left,
                    right,
                    capture_t_us: t_us,
                    sequence,
                };
                let (used, done) = self.nav.vo_step(&frame, quantum);
                if done {
                    self.rect.frame = None;
                }
                return used;
            }
            let (used, done) = match self.devices.camera.frame() {
                Ok(frame) => self.nav.vo_step(&frame, quantum),
                Err(e) => {
                    let health = &mut self.state.health[DeviceId::Camera as usize];
                    count_error(health, rover_hal::Error::kind(&e));
                    self.nav.capture_lost();
                    (1, true)
                }
            };
            if done {
                self.release_frame();
            }
            return used;
        }
        // VO went idle without finishing on the rectified pair (capture lost): forget it.
        self.rect.frame = None;
        let Some(t_us) = self.state.capture_pending_t_us else {
            return 0;
        };
        let health = &mut self.state.health[DeviceId::Camera as usize];
        match self.devices.camera.poll() {
            Ok(CaptureStatus::Ready) => {
                self.capture_ready(t_us);
                1
            }
            Ok(CaptureStatus::InProgress) => 1,
            Ok(CaptureStatus::Idle) => {
                // The camera lost the capture.
                count_error(health, ErrorKind::Other);
                self.state.capture_pending_t_us = None;
                self.nav.capture_lost();
                1
            }
            Err(e) => {
                count_error(health, rover_hal::Error::kind(&e));
                1
            }
        }
    }

    /// The camera reports the capture of `t_us` ready: a frame of the right time, size and
    /// order is counted good and handed to the rectification (raw pairs) or to VO; otherwise
    /// the capture is lost and the frame released.
    #[inline(never)]
    fn capture_ready(&mut self, t_us: u64) {
        let health = &mut self.state.health[DeviceId::Camera as usize];
        self.state.capture_pending_t_us = None;
        let mut vo_started = false;
        match self.devices.camera.frame() {
            Ok(frame) if frame.capture_t_us == t_us => {
                let size_ok = frame.left.len() == rover_hal::IMAGE_PIXELS
                    && frame.right.len() == rover_hal::IMAGE_PIXELS;
                if size_ok && check_order(health, self.state.last_capture_t_us, t_us) {
                    health.good = health.good.saturating_add(1);
                    self.state.stereo_frames = self.state.stereo_frames.saturating_add(1);
                    self.state.last_capture_t_us = Some(t_us);
                    if self.nav.capture_pending() {
                        if self.state.rectifying {
                            // Raw pair: rectified in the next background slices,
                            // then handed to VO (rectify_step).
                            vo_started = self.rect.rectifier.start(&frame).is_ok();
                            if vo_started {
                                self.rect.pending = Some((t_us, frame.sequence));
                            } else {
                                self.state.rectify_failures =
                                    self.state.rectify_failures.saturating_add(1);
                            }
                        } else {
                            vo_started = self.nav.vo_start(&frame);
                        }
                    }
                } else if !size_ok {
                    count_invalid(health);
                }
            }
            Ok(_) => count_invalid(health),
            Err(e) => count_error(health, rover_hal::Error::kind(&e)),
        }
        if !vo_started {
            self.nav.capture_lost();
            self.release_frame();
        }
    }
}
