//! The six-axis force/torque sensor: `[Fx, Fy, Fz, My]` of the load on it (the contact
//! wrench plus the payload's weight and inertia, in the sensor's frame) with Gaussian
//! noise, a bias that drifts (a random walk), quantisation and a second-order Butterworth
//! low-pass filter, sampled at its own rate on the simulated clock.

use h4_shared::config::{ConfigError, Section, check_range};
use h4_shared::rng::Rng;
use nalgebra::Vector4;
use serde::{Deserialize, Serialize};

use h4_slave::filter::Butterworth2;

/// What each sample of the sensor's A/D reads of the load.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum AdcAperture {
    /// The load at the sample's instant (a fast A/D: no lag of its own; a load with content
    /// at multiples of the sample rate aliases into the reading: a milling cutter's tooth
    /// pulses, docs/cutting.md "The sensor and the cut").
    #[default]
    Instant,
    /// The load's mean over the sample period (an integrating A/D: nothing at a multiple of
    /// the sample rate aliases; half a period more lag).
    Period,
}

/// The force/torque sensor's imperfections and its digital filter.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SensorConfig {
    /// Standard deviation of the Gaussian noise on each force axis per sample, N.
    pub noise_std_n: f64,
    /// Standard deviation of the Gaussian noise on My per sample, N·mm.
    pub noise_std_n_mm: f64,
    /// Force quantisation step, N (ATI mini45: 1/16 N).
    pub quantization_n: f64,
    /// Moment quantisation step, N·mm (ATI mini45: 1/752 N·m ≈ 1.33 N·mm).
    pub quantization_n_mm: f64,
    /// Constant bias on Fx, Fy, Fz, N.
    pub bias_n: [f64; 3],
    /// Constant bias on My, N·mm.
    pub bias_n_mm: f64,
    /// Bias drift of each force axis: a random walk of this standard deviation per √s, N
    /// (strain-gauge thermal drift).
    pub bias_drift_n_per_sqrt_s: f64,
    /// Bias drift of My, N·mm per √s.
    pub bias_drift_n_mm_per_sqrt_s: f64,
    /// Sample rate of the A/D read-out, Hz.
    pub sample_rate_hz: f64,
    /// Cut-off of the 2nd-order Butterworth low-pass filter, Hz (≥ 0.45 × the sample rate
    /// disables it).
    pub filter_cutoff_hz: f64,
    /// What a sample reads of the load: `instant` or `period` ([`AdcAperture`]).
    pub adc_aperture: AdcAperture,
}

impl Default for SensorConfig {
    fn default() -> Self {
        SensorConfig {
            noise_std_n: 0.1,
            noise_std_n_mm: 2.0,
            quantization_n: 0.0625,
            quantization_n_mm: 1.33,
            bias_n: [0.3, -0.2, 0.4],
            bias_n_mm: 3.0,
            bias_drift_n_per_sqrt_s: 0.0,
            bias_drift_n_mm_per_sqrt_s: 0.0,
            sample_rate_hz: 1000.0,
            filter_cutoff_hz: 80.0,
            adc_aperture: AdcAperture::Instant,
        }
    }
}

impl Section for SensorConfig {
    /// Checks every field, naming it under `prefix` (e.g. `"sensor."`) with its allowed
    /// range and unit.
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let field = |name: &str| format!("{prefix}{name}");
        #[rustfmt::skip]
        let checks: [(&str, f64, f64, f64, &str); 9] = [
            ("noise_std_n", self.noise_std_n, 0.0, 10.0, "N"),
            ("noise_std_n_mm", self.noise_std_n_mm, 0.0, 1000.0, "N·mm"),
            ("quantization_n", self.quantization_n, 0.0, 5.0, "N"),
            ("quantization_n_mm", self.quantization_n_mm, 0.0, 100.0, "N·mm"),
            ("bias_n_mm", self.bias_n_mm, -1e4, 1e4, "N·mm"),
            ("bias_drift_n_per_sqrt_s", self.bias_drift_n_per_sqrt_s, 0.0, 10.0, "N/√s"),
            ("bias_drift_n_mm_per_sqrt_s", self.bias_drift_n_mm_per_sqrt_s, 0.0, 1000.0, "N·mm/√s"),
            ("sample_rate_hz", self.sample_rate_hz, 100.0, 100_000.0, "Hz"),
            ("filter_cutoff_hz", self.filter_cutoff_hz, 1.0, 1e5, "Hz"),
        ];
        for (name, value, min, max, unit) in checks {
            check_range(&field(name), value, min, max, unit)?;
        }
        for (i, b) in self.bias_n.iter().enumerate() {
            check_range(&field(&format!("bias_n[{i}]")), *b, -50.0, 50.0, "N")?;
        }
        Ok(())
    }
}

/// The sensor's state: its noise source, its filters and the latest filtered reading.
#[derive(Clone, Debug)]
pub(super) struct ForceSensor {
    pub(super) cfg: SensorConfig,
    rng: Rng,
    filters: [Butterworth2; 4],
    /// The drift of the bias so far, N and N·mm.
    drift: [f64; 4],
    /// The latest filtered reading `[Fx, Fy, Fz, My]`, bias included, N and N·mm.
    pub(super) filtered: [f64; 4],
    /// Sample period, ns.
    pub(super) period_ns: u64,
    /// Time of the next sample, ns.
    pub(super) next_sample_ns: u64,
}

impl ForceSensor {
    /// A sensor at rest under the load `load` (its filters settled on it plus the bias),
    /// its noise drawn from `seed`. `cfg.sample_rate_hz` must be positive.
    pub(super) fn new(cfg: SensorConfig, seed: u64, load: &Vector4<f64>) -> Self {
        let period_ns = (1e9 / cfg.sample_rate_hz).round().max(1.0) as u64;
        let mut sensor = ForceSensor {
            cfg,
            rng: Rng::fork(seed, 0x5E45),
            filters: [Butterworth2::new(cfg.filter_cutoff_hz, cfg.sample_rate_hz); 4],
            filtered: [0.0; 4],
            drift: [0.0; 4],
            period_ns,
            next_sample_ns: 0,
        };
        for (i, f) in sensor.filters.iter_mut().enumerate() {
            let b = if i < 3 { cfg.bias_n[i] } else { cfg.bias_n_mm } + load[i];
            f.reset(b);
            sensor.filtered[i] = b;
        }
        sensor
    }

    /// Restarts the clock at 0 with the filters settled on `load` plus the bias (drift so
    /// far kept).
    pub(super) fn restart(&mut self, load: &Vector4<f64>) {
        let cfg = self.cfg;
        for (i, f) in self.filters.iter_mut().enumerate() {
            let b = if i < 3 { cfg.bias_n[i] } else { cfg.bias_n_mm } + load[i] + self.drift[i];
            f.reset(b);
            self.filtered[i] = b;
        }
        self.next_sample_ns = 0;
    }

    /// One sample of the true `load` (`[Fx, Fy, Fz, My]` in the sensor's frame).
    pub(super) fn sample(&mut self, load: &Vector4<f64>) {
        let s = &self.cfg;
        let sqrt_period_s = (self.period_ns as f64 * 1e-9).sqrt();
        for i in 0..4 {
            let (bias, std, quant, drift) = if i < 3 {
                (
                    s.bias_n[i],
                    s.noise_std_n,
                    s.quantization_n,
                    s.bias_drift_n_per_sqrt_s,
                )
            } else {
                (
                    s.bias_n_mm,
                    s.noise_std_n_mm,
                    s.quantization_n_mm,
                    s.bias_drift_n_mm_per_sqrt_s,
                )
            };
            if drift > 0.0 {
                self.drift[i] += drift * sqrt_period_s * self.rng.normal();
            }
            let bias = bias + self.drift[i];
            let noise = if std > 0.0 {
                std * self.rng.normal()
            } else {
                0.0
            };
            let mut raw = load[i] + bias + noise;
            if quant > 0.0 {
                raw = quantize(raw, quant);
            }
            self.filtered[i] = self.filters[i].update(raw);
        }
    }
}

/// subtracting 1.5 × 2⁵² rounds any |x| < 2⁵¹ exactly, the same on every platform.
#[inline]
pub(super) fn quantize(value: f64, step: f64) -> f64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0;
    let x = value / step;
    if x.abs() < 1e15 {
        ((x + MAGIC) - MAGIC) * step
    } else {
        value
    }
}

#[cfg(test)]
impl SensorConfig {
    /// A sensor without noise, quantisation or bias (the plant's own unit tests).
    pub(crate) fn quiet() -> Self {
        SensorConfig {
            noise_std_n: 0.0,
            noise_std_n_mm: 0.0,
            quantization_n: 0.0,
            quantization_n_mm: 0.0,
            bias_n: [0.0; 3],
            bias_n_mm: 0.0,
            bias_drift_n_per_sqrt_s: 0.0,
            bias_drift_n_mm_per_sqrt_s: 0.0,
            ..SensorConfig::default()
        }
    }
}
