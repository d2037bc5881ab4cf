//! The force sensor's bias, averaged over the first cycles (in free space, holding still).

use nalgebra::Vector4;

/// The running average of the wrench while taring, and the bias it gives.
#[derive(Clone, Copy, Debug)]
pub(super) struct SensorTare {
    sum: Vector4<f64>,
    samples: u32,
    /// The bias removed from every reading, `[Fx, Fy, Fz, My]` (N, N·mm).
    pub(super) bias: Vector4<f64>,
}

impl SensorTare {
    /// No samples yet, no bias.
    pub(super) fn new() -> Self {
        SensorTare {
            sum: Vector4::zeros(),
            samples: 0,
            bias: Vector4::zeros(),
        }
    }

    /// True until `tare_cycles` samples have been averaged.
    pub(super) fn taring(&self, tare_cycles: u32) -> bool {
        self.samples < tare_cycles
    }

    /// Adds the raw reading `raw` to the average.
    pub(super) fn add(&mut self, raw: Vector4<f64>) {
        self.sum += raw;
        self.samples += 1;
        self.bias = self.sum / f64::from(self.samples);
    }
}
