//! The force sensor's bias, averaged over the first cycles (in free space, holding still).

use nalgebra::Vector4;

/// The running average of the wrench while taring, and the bias it gives.
#[derive(Clone, Copy, Debug)]
pub(super) struct SensorTare {
    sum: Vector4<f64>,
    sum_sq: Vector4<f64>,
    samples: u32,
    /// The bias removed from every reading, `[Fx, Fy, Fz, My]` (N, N·mm).
    pub(super) bias: Vector4<f64>,
}

impl SensorTare {
    /// No samples yet, no bias.
    pub(super) fn new() -> Self {
        SensorTare {
            sum: Vector4::zeros(),
            sum_sq: Vector4::zeros(),
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
        self.sum_sq += raw.component_mul(&raw);
        self.samples += 1;
        self.bias = self.sum / f64::from(self.samples);
    }

    /// The standard deviation of the force the sensor showed while taring along the unit
    /// vector `u` (the axes taken as independent), N: its noise as filtered.
    pub(super) fn noise_along(&self, u: &nalgebra::Vector3<f64>) -> f64 {
        if self.samples < 2 {
            return 0.0;
        }
        let n = f64::from(self.samples);
        let mut var = 0.0;
        for i in 0..3 {
            let v = (self.sum_sq[i] / n - self.bias[i] * self.bias[i]).max(0.0) * n / (n - 1.0);
            var += u[i] * u[i] * v;
        }
        var.sqrt()
    }
}
