//! Small fixed-size digital filters used by the sensor model and the controller.

/// A second-order Butterworth low-pass filter (bilinear transform with pre-warping), in
/// direct form II transposed. `Copy`, allocation-free.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Butterworth2 {
    b0: f64,
    b1: f64,
    b2: f64,
    a1: f64,
    a2: f64,
    z1: f64,
    z2: f64,
}

impl Butterworth2 {
    /// A filter with cut-off `cutoff_hz` for samples at `sample_rate_hz`. A cut-off at or
    /// above 0.45 × the sample rate gives a pass-through filter.
    pub fn new(cutoff_hz: f64, sample_rate_hz: f64) -> Self {
        if !(cutoff_hz > 0.0 && sample_rate_hz > 0.0) || cutoff_hz >= 0.45 * sample_rate_hz {
            return Butterworth2 {
                b0: 1.0,
                b1: 0.0,
                b2: 0.0,
                a1: 0.0,
                a2: 0.0,
                z1: 0.0,
                z2: 0.0,
            };
        }
        let k = (core::f64::consts::PI * cutoff_hz / sample_rate_hz).tan();
        let q = core::f64::consts::FRAC_1_SQRT_2;
        let norm = 1.0 / (1.0 + k / q + k * k);
        let b0 = k * k * norm;
        Butterworth2 {
            b0,
            b1: 2.0 * b0,
            b2: b0,
            a1: 2.0 * (k * k - 1.0) * norm,
            a2: (1.0 - k / q + k * k) * norm,
            z1: 0.0,
            z2: 0.0,
        }
    }

    /// Sets the state as if the input had been `value` forever.
    pub fn reset(&mut self, value: f64) {
        // Steady state of DF2T with unit DC gain: y = x = value.
        self.z1 = value * (1.0 - self.b0);
        self.z2 = value * (self.b2 - self.a2);
    }

    /// Filters one sample.
    #[inline]
    pub fn update(&mut self, x: f64) -> f64 {
        let y = self.b0 * x + self.z1;
        self.z1 = self.b1 * x - self.a1 * y + self.z2;
        self.z2 = self.b2 * x - self.a2 * y;
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_dc_gain_and_reset() {
        let mut f = Butterworth2::new(50.0, 1000.0);
        let mut y = 0.0;
        for _ in 0..2000 {
            y = f.update(3.0);
        }
        assert!((y - 3.0).abs() < 1e-9);
        let mut g = Butterworth2::new(50.0, 1000.0);
        g.reset(-2.0);
        assert!((g.update(-2.0) + 2.0).abs() < 1e-12);
    }

    #[test]
    fn attenuates_above_cutoff() {
        let mut f = Butterworth2::new(50.0, 1000.0);
        let mut peak: f64 = 0.0;
        for i in 0..4000 {
            let x = (2.0 * core::f64::consts::PI * 400.0 * i as f64 / 1000.0).sin();
            let y = f.update(x);
            if i > 1000 {
                peak = peak.max(y.abs());
            }
        }
        assert!(peak < 0.05, "{peak}");
    }
}
