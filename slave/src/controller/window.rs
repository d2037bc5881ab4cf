//! The motion window: the last [`WINDOW_MAX`] cycles of the measured position (filtered
//! like the force sensor's signal, so that both lag alike) and of the measured force. The
//! contact-normal estimate reads the motion over the window, the stiffness estimator the
//! force and position increments over `estimator_window_cycles`, the touch-down estimate
//! the force build-up before contact.

use h4_shared::kinematics::Pose;
use nalgebra::Vector3;

use crate::filter::Butterworth2;

/// Cycles of history kept.
pub(super) const WINDOW_MAX: usize = 64;

/// The position filter and the ring buffers.
#[derive(Clone, Debug)]
pub(super) struct MotionWindow {
    filters: [Butterworth2; 3],
    cutoff_hz: f64,
    /// The sample period the filters are designed for, s.
    period_s: f64,
    /// Filtered positions `[x, y, z]`, mm; newest at `head`.
    pub(super) x: [[f64; 3]; WINDOW_MAX],
    /// Bias-corrected forces, N; newest at `head`.
    pub(super) f: [Vector3<f64>; WINDOW_MAX],
    /// Index of the newest entry.
    pub(super) head: usize,
}

impl MotionWindow {
    /// An empty window whose position filter has the cut-off `cutoff_hz` (the sensor
    /// filter's), designed for 1 ms cycles until [`MotionWindow::follow_period`] says
    /// otherwise.
    pub(super) fn new(cutoff_hz: f64) -> Self {
        let period_s = 1e-3;
        MotionWindow {
            filters: [Butterworth2::new(cutoff_hz, 1.0 / period_s); 3],
            cutoff_hz,
            period_s,
            x: [[0.0; 3]; WINDOW_MAX],
            f: [Vector3::zeros(); WINDOW_MAX],
            head: 0,
        }
    }

    /// Fills the position history with `x` and settles the filters there.
    pub(super) fn reset(&mut self, x: [f64; 3]) {
        for (i, f) in self.filters.iter_mut().enumerate() {
            f.reset(x[i]);
        }
        for h in self.x.iter_mut() {
            *h = x;
        }
    }

    /// Designs the position filter for the sample period `period_s` when the period
    /// changed (no allocation); the filters then restart settled on the newest filtered
    /// position. The first design is for 1 ms, so at 1 ms nothing changes.
    pub(super) fn follow_period(&mut self, period_s: f64) {
        if period_s != self.period_s {
            self.period_s = period_s;
            let x = self.x[self.head];
            for (i, f) in self.filters.iter_mut().enumerate() {
                *f = Butterworth2::new(self.cutoff_hz, 1.0 / period_s);
                f.reset(x[i]);
            }
        }
    }

    /// Pushes this cycle's position (filtered) and force; returns the filtered position.
    pub(super) fn push(&mut self, pose_fk: &Pose, f3: Vector3<f64>) -> [f64; 3] {
        let xf = [
            self.filters[0].update(pose_fk[0]),
            self.filters[1].update(pose_fk[1]),
            self.filters[2].update(pose_fk[2]),
        ];
        self.head = (self.head + 1) % WINDOW_MAX;
        self.x[self.head] = xf;
        self.f[self.head] = f3;
        xf
    }

    /// Index of the entry `back` cycles before the newest.
    pub(super) fn back(&self, back: usize) -> usize {
        (self.head + WINDOW_MAX - back) % WINDOW_MAX
    }

    /// Index of the oldest entry.
    pub(super) fn oldest(&self) -> usize {
        (self.head + 1) % WINDOW_MAX
    }
}
