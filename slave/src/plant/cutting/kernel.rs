//! The servo periods of an arm that cuts: the generic kernel's servos, structure and
//! platform, with the contact replaced by the cut ([`CutState::contact`]).

use h4_shared::kinematics::Pose;
use nalgebra::Vector4;

use super::CutState;
use super::mechanics::solve_damped;
use crate::plant::SimArm;
use crate::plant::servo::CarriageServo;

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
            let phase = self.phase_rev - n * self.since_update_s;
            let m = self.engagement.matrix(phase, self.tool.flutes, vs);
            let v = solve_damped(&m, dt_over_m, vs);
            let f = [
                -(m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2]),
                -(m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2]),
                -(m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2]),
            ];
            *vs = v;
            return f;
        }
        // Sideways: the stock the tool moved into without cutting pushes it back out
        // (Kelvin–Voigt along the contact's direction, explicit as the other kernels).
        let e = self.engagement.lateral_dir;
        let moved_in =
            -((tip_mm[0] - self.rub_tip0_mm[0]) * e[0] + (tip_mm[1] - self.rub_tip0_mm[1]) * e[1]);
        let side = self.engagement.lateral_mm + moved_in;
        let mut f_side = [0.0; 2];
        if self.engagement.lateral_mm > 0.0 && side > 0.0 {
            let v_in = -(vel_before[0] * e[0] + vel_before[1] * e[1]);
            let f = (rub.k_n_per_mm * side + rub.b_n_s_per_mm * v_in).max(0.0);
            f_side = [f * e[0], f * e[1]];
            vs[0] += f_side[0] * dt_over_m;
            vs[1] += f_side[1] * dt_over_m;
        }
        let depth = self.engagement.penetration_mm + (self.rub_tip0_mm[2] - tip_mm[2]);
        if depth <= 0.0 {
            return [f_side[0], f_side[1], 0.0];
        }
        // Rubbing on the stock's top (normal +z): Kelvin–Voigt with the regularised
        // Coulomb friction solved for the end of the period, as the plant's other kernels.
        let f_n = (rub.k_n_per_mm * depth - rub.b_n_s_per_mm * vel_before[2]).max(0.0);
        let dv_n = f_n * dt_over_m;
        vs[2] += dv_n;
        let s2 = vs[0] * vs[0] + vs[1] * vs[1];
        let reach = rub.mu * dv_n;
        let edge = rub.reg_mm_per_s + reach;
        let removed = if s2 >= edge * edge {
            (reach / s2) * s2.sqrt()
        } else {
            reach / edge
        };
        let f = [
            f_side[0] - vs[0] * removed / dt_over_m,
            f_side[1] - vs[1] * removed / dt_over_m,
            f_n,
        ];
        vs[0] -= vs[0] * removed;
        vs[1] -= vs[1] * removed;
        f
    }
}

impl SimArm {
    /// `n` servo periods with the Jacobian held, cutting: [`SimArm::substeps_with`]'s
    /// servos, structure and platform, the contact the cut's.
    pub(in crate::plant) fn substeps_cutting(&mut self, n: u32) {
        let Some(mut cut) = self.cut.take() else {
            return;
        };
        let dt = self.substep_s;
        let cfg = self.cfg;
        let mut j = [[0.0f64; 4]; 4];
        for (r, row) in j.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = self.jac[(r, c)];
            }
        }
        let servo = CarriageServo::new(&cfg, dt);
        let damp = cfg.platform_damping_n_s_per_mm;
        let g = cfg.gravity_mm_per_s2;
        let (k, cs, cmd) = (self.k, self.c_struct, self.command);
        let (mut q, mut qd, mut integ) = (self.q, self.qd, self.integral);
        let mut pose = [self.pose[0], self.pose[1], self.pose[2], self.pose[3]];
        let mut vel = [self.vel[0], self.vel[1], self.vel[2], self.vel[3]];
        let mut l = [0.0f64; 4];
        let mut ld = [0.0f64; 4];
        for r in 0..4 {
            l[r] = self.l0[r];
            for c in 0..4 {
                l[r] += j[r][c] * (pose[c] - self.pose0[c]);
                ld[r] += j[r][c] * vel[c];
            }
        }
        let rub = Rubbing {
            k_n_per_mm: self.surface.material.stiffness_n_per_mm,
            b_n_s_per_mm: self.contact_damping,
            mu: self.surface.material.friction_coefficient,
            reg_mm_per_s: cfg.friction_velocity_mm_per_s,
        };
        let dt_over_m_tool = self.inv_mass[0] * dt;
        let dt_over_inertia = self.inv_mass[3] * dt;
        let mut fc = [0.0f64; 3];
        for _ in 0..n {
            let mut f_act = [0.0f64; 4];
            for i in 0..4 {
                let f = k[i] * (l[i] - q[i]) + cs[i] * (ld[i] - qd[i]);
                f_act[i] = f;
                servo.step(cmd[i], &mut q[i], &mut qd[i], &mut integ[i], f);
            }
            let mut gen_f = [0.0f64; 4];
            for (c, gf) in gen_f.iter_mut().enumerate() {
                *gf = -(j[0][c] * f_act[0]
                    + j[1][c] * f_act[1]
                    + j[2][c] * f_act[2]
                    + j[3][c] * f_act[3])
                    - vel[c] * damp;
            }
            vel[3] += gen_f[3] * dt_over_inertia;
            let mut vs = [
                vel[0] + gen_f[0] * dt_over_m_tool + g[0] * dt,
                vel[1] + gen_f[1] * dt_over_m_tool + g[1] * dt,
                vel[2] + gen_f[2] * dt_over_m_tool + g[2] * dt,
            ];
            let before = [vel[0], vel[1], vel[2]];
            let tip = [pose[0], pose[1], pose[2]];
            fc = cut.contact(&mut vs, &before, &tip, dt, dt_over_m_tool, &rub);
            for (i, f) in cut.force_impulse_n_s.iter_mut().zip(fc) {
                *i += f * dt;
            }
            vel[..3].copy_from_slice(&vs);
            for c in 0..4 {
                pose[c] += vel[c] * dt;
            }
            for r in 0..4 {
                ld[r] = j[r][0] * vel[0] + j[r][1] * vel[1] + j[r][2] * vel[2] + j[r][3] * vel[3];
                l[r] += ld[r] * dt;
            }
        }
        self.q = q;
        self.qd = qd;
        self.integral = integ;
        self.pose = Pose::from(pose);
        self.vel = Pose::from(vel);
        self.penetration_mm = cut.stock().top_mm() - pose[2];
        self.contact_wrench = Vector4::new(fc[0], fc[1], fc[2], 0.0);
        self.cut = Some(cut);
    }
}
