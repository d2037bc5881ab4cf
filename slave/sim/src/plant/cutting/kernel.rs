//! The servo periods of an arm that cuts: the generic kernel's servos, structure and
//! platform, with the contact replaced by the cut ([`CutState::contact`]).

use nalgebra::Vector4;

use super::CutState;
use crate::plant::SimArm;
use crate::plant::kernel::Substep;

/// The rubbing contact's constants (the surface's material).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Rubbing {
    /// Contact stiffness, N/mm.
    pub k_n_per_mm: f64,
    /// Contact damping, N·s/mm.
    pub b_n_s_per_mm: f64,
    /// Coulomb friction coefficient.
    pub mu: f64,
    /// Friction's regularisation speed, mm/s.
    pub reg_mm_per_s: f64,
}

impl CutState {
    /// One servo period of contact between the tool (tip `tip_mm`, velocity before the
    /// contact `vs`, mass `dt / dt_over_m`) and the stock: with the spindle turning the
    /// cutting force, solved implicitly with the velocity (backward Euler: stable however
    /// hard the material); stopped or stalled, rubbing. Updates `vs`; returns the force on
    /// the tool, N.
    #[inline]
    pub(crate) fn contact(
        &mut self,
        vs: &mut [f64; 3],
        vel_before: &[f64; 3],
        tip_mm: &[f64; 3],
        dt_s: f64,
        dt_over_m: f64,
        rub: &Rubbing,
    ) -> [f64; 3] {
        self.since_update_s += dt_s;
        let n = self.rev_per_s();
        if n > 0.0 {
            if self.engagement.elements == 0 {
                return [0.0; 3];
            }
            let phase = self.phase_rev - n * self.since_update_s - self.table_rev;
            let (m, v) = self
                .engagement
                .solve(phase, self.tool.flutes, vs, dt_over_m);
            let f = [
                -(m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2]),
                -(m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2]),
                -(m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2]),
            ];
            *vs = v;
            return f;
        }
        // Rubbing: the stock pushes the tool back along its way out (Kelvin–Voigt along
        // `rub_dir`, explicit as the other kernels), with the regularised Coulomb friction
        // across it solved for the end of the period, as the plant's other kernels.
        let (p0, e) = (self.engagement.rub_mm, self.engagement.rub_dir);
        if p0 <= 0.0 {
            return [0.0; 3];
        }
        let t0 = self.rub_tip0_mm;
        let moved_in =
            -((tip_mm[0] - t0[0]) * e[0] + (tip_mm[1] - t0[1]) * e[1] + (tip_mm[2] - t0[2]) * e[2]);
        let depth = p0 + moved_in;
        if depth <= 0.0 {
            return [0.0; 3];
        }
        let v_in = -(vel_before[0] * e[0] + vel_before[1] * e[1] + vel_before[2] * e[2]);
        let f_n = (rub.k_n_per_mm * depth + rub.b_n_s_per_mm * v_in).max(0.0);
        let dv_n = f_n * dt_over_m;
        for (v, ec) in vs.iter_mut().zip(e) {
            *v += dv_n * ec;
        }
        let v_n = vs[0] * e[0] + vs[1] * e[1] + vs[2] * e[2];
        let vt = [vs[0] - v_n * e[0], vs[1] - v_n * e[1], vs[2] - v_n * e[2]];
        let s2 = vt[0] * vt[0] + vt[1] * vt[1] + vt[2] * vt[2];
        let reach = rub.mu * dv_n;
        let edge = rub.reg_mm_per_s + reach;
        let removed = if s2 >= edge * edge {
            (reach / s2) * s2.sqrt()
        } else {
            reach / edge
        };
        let mut f = [0.0; 3];
        for i in 0..3 {
            f[i] = f_n * e[i] - vt[i] * removed / dt_over_m;
            vs[i] -= vt[i] * removed;
        }
        f
    }
}

impl CutState {
    /// [`CutState::contact`] on a turning workpiece, in the base frame: the turntable
    /// advances one servo period, then the tool's tip and its velocity relative to the
    /// turning stock (`v − ω ẑ × (p − c)`) are taken into the workpiece frame at the
    /// table's true angle, the contact is solved there, and the force and the velocity are
    /// turned back. Without a turntable, [`CutState::contact`] itself.
    #[inline]
    pub(crate) fn contact_base(
        &mut self,
        vs: &mut [f64; 3],
        vel_before: &[f64; 3],
        tip_mm: &[f64; 3],
        dt_s: f64,
        dt_over_m: f64,
        rub: &Rubbing,
    ) -> [f64; 3] {
        let Some(table) = self.table.as_mut() else {
            return self.contact(vs, vel_before, tip_mm, dt_s, dt_over_m, rub);
        };
        table.step(dt_s);
        let th = table.angle_rad();
        let om = table.speed_rad_per_s();
        let [ax, ay] = table.config().axis_mm;
        let tip_wp = table.to_workpiece(*tip_mm);
        self.table_rev = th / (2.0 * std::f64::consts::PI);
        let (s, c) = table.sin_cos();
        // The stock's velocity under the tip, base frame.
        let u = [-om * (tip_mm[1] - ay), om * (tip_mm[0] - ax), 0.0];
        let into_wp = |v: &[f64; 3]| {
            let (x, y) = (v[0] - u[0], v[1] - u[1]);
            [c * x + s * y, -s * x + c * y, v[2]]
        };
        let mut w = into_wp(&*vs);
        let before = into_wp(vel_before);
        let f = self.contact(&mut w, &before, &tip_wp, dt_s, dt_over_m, rub);
        *vs = [c * w[0] - s * w[1] + u[0], s * w[0] + c * w[1] + u[1], w[2]];
        [c * f[0] - s * f[1], s * f[0] + c * f[1], f[2]]
    }
}

impl SimArm {
    /// `n` servo periods with the Jacobian held, cutting: [`SimArm::substeps_with`]'s
    /// servos, structure and platform, the contact the cut's.
    pub(in crate::plant) fn substeps_cutting(&mut self, n: u32) {
        let Some(mut cut) = self.cut.take() else {
            return;
        };
        let mut st = Substep::new(self);
        let (dt, dt_over_m_tool) = (st.dt, st.dt_over_m_tool);
        let cfg = self.cfg;
        let rub = Rubbing {
            k_n_per_mm: self.surface.material.stiffness_n_per_mm,
            b_n_s_per_mm: self.contact_damping,
            mu: self.surface.material.friction_coefficient,
            reg_mm_per_s: cfg.friction_velocity_mm_per_s,
        };
        let mut fc = [0.0f64; 3];
        let mut sum = [0.0f64; 3];
        for _ in 0..n {
            let mut vs = st.structure();
            let before = [st.vel[0], st.vel[1], st.vel[2]];
            let tip = [st.pose[0], st.pose[1], st.pose[2]];
            fc = cut.contact_base(&mut vs, &before, &tip, dt, dt_over_m_tool, &rub);
            for (i, f) in cut.force_impulse_n_s.iter_mut().zip(fc) {
                *i += f * dt;
            }
            for (s, f) in sum.iter_mut().zip(fc) {
                *s += f;
            }
            st.advance(vs);
        }
        st.store(self);
        self.book_load(sum, n);
        self.penetration_mm = cut.stock().top_mm() - st.pose[2];
        self.contact_wrench = Vector4::new(fc[0], fc[1], fc[2], 0.0);
        self.cut = Some(cut);
    }
}
