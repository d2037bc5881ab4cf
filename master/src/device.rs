//! The operator's haptic device: the [`HapticDevice`] interface a device's driver
//! implements, and what a reading of it holds ([`DeviceState`]). The simulated H-4 family
//! master arm behind it is `h4_master_sim::arm::SimMasterArm` (docs/drivers.md).

use nalgebra::{Matrix3, Matrix4};
use serde::Serialize;

/// One reading of the device.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct DeviceState {
    /// Time of the reading, ns.
    pub time_ns: u64,
    /// Handle pose `[x_mm, y_mm, z_mm, theta_rad]`, device frame.
    pub pose: [f64; 4],
    /// Handle velocity `[mm/s, mm/s, mm/s, rad/s]`.
    pub velocity: [f64; 4],
    /// The clutch button is held.
    pub clutch: bool,
    /// Smallest effective mass of the handle along any translation at this pose, kg (the
    /// inverse of the largest eigenvalue of the translational block of `M⁻¹`; 0: unknown).
    /// A force that changes with the measured velocity by more than about this mass per
    /// cycle overshoots within one cycle (discrete-time damping limit).
    pub effective_mass_kg: f64,
    /// The handle's effective translational masses along its principal directions, kg
    /// (ascending: the first is `effective_mass_kg`), and those directions (unit vectors,
    /// device frame; the eigenvectors of the translational block of `M⁻¹`): the
    /// discrete-time damping limit along each. A driver that knows only one mass gives it
    /// along the three axes.
    pub principal_masses: PrincipalMasses,
}

/// The handle's effective masses along its principal directions (see
/// [`DeviceState::principal_masses`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PrincipalMasses {
    /// Effective mass along each direction, kg (ascending; 0: unknown).
    pub mass_kg: [f64; 3],
    /// The directions, unit vectors, device frame.
    pub axes: [[f64; 3]; 3],
}

impl Default for PrincipalMasses {
    fn default() -> Self {
        PrincipalMasses::isotropic(0.0)
    }
}

impl PrincipalMasses {
    /// One mass along the three axes.
    pub fn isotropic(mass_kg: f64) -> Self {
        PrincipalMasses {
            mass_kg: [mass_kg; 3],
            axes: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        }
    }

    /// The masses scaled by `factor` (a datasheet's share of the truth).
    pub fn scaled(mut self, factor: f64) -> Self {
        for m in self.mass_kg.iter_mut() {
            *m *= factor;
        }
        self
    }

    /// From the inverse of the mass matrix: the eigen-decomposition of its translational
    /// block, masses `1e3 / λ` kg, ascending; `None` if not computable.
    pub fn from_inverse_mass(inv_mass: &Matrix4<f64>) -> Option<Self> {
        let a: Matrix3<f64> = inv_mass.fixed_view::<3, 3>(0, 0).into_owned();
        let eig = a.symmetric_eigen();
        let mut order = [0usize, 1, 2];
        // Largest eigenvalue of M⁻¹ first: the smallest mass first.
        order.sort_by(|&i, &j| eig.eigenvalues[j].total_cmp(&eig.eigenvalues[i]));
        let mut out = PrincipalMasses::isotropic(0.0);
        for (k, &i) in order.iter().enumerate() {
            let l = eig.eigenvalues[i];
            if !(l.is_finite() && l > 0.0) {
                return None;
            }
            out.mass_kg[k] = 1e3 / l;
            let v = eig.eigenvectors.column(i);
            out.axes[k] = [v[0], v[1], v[2]];
        }
        Some(out)
    }
}

/// What the master needs of a haptic device: a real driver implements this (`read` and
/// `write_wrench`; the rest has defaults a real device keeps).
pub trait HapticDevice {
    /// The latest handle pose, velocity and buttons.
    fn read(&mut self) -> DeviceState;
    /// The wrench `[Fx_n, Fy_n, Fz_n, My_n_mm]` to apply to the operator's hand from now on.
    /// Returns the wrench actually commanded after the device's own force limits.
    fn write_wrench(&mut self, wrench: &[f64; 4]) -> [f64; 4];
    /// A cycle begins at `now_ns` (of `dt_s`), before [`HapticDevice::read`]: the simulated
    /// device's operator acts on the handle here; a real device has nothing to do.
    fn begin_cycle(&mut self, _now_ns: u64, _dt_s: f64) {}
    /// The host did not run the loop for `missed` periods of `period_ns` before the cycle at
    /// `now_ns`: a simulated device lives through them (its hand goes on, its motors hold the
    /// last wrench); a real device lived through them on its own.
    fn stalled(&mut self, _now_ns: u64, _period_ns: u64, _missed: u64) {}
    /// `dt_ns` of the device's own time pass after a cycle: a simulated device integrates
    /// its physics; a real device runs on its own.
    fn advance(&mut self, _dt_ns: u64) {}
    /// Diagnostics (the recording only, never the coupling): the operator's wrench on the
    /// handle now, `[Fx_n, Fy_n, Fz_n, My_n_mm]`, when the device knows it (the simulated
    /// operator); None for a real device.
    fn hand_wrench(&self) -> Option<[f64; 4]> {
        None
    }
}
