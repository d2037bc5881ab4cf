//! The inner loop of the simulation: `n` servo periods with the Jacobian held, the
//! carriages' servos ([`super::servo`]), the structure's springs, the platform's motion and
//! the contact with the surface, specialised per surface shape.

use h4_shared::kinematics::Pose;
use h4_shared::vec3::dot3;
use nalgebra::{Vector3, Vector4};

use super::SimArm;
use super::servo::{CarriageServo, clamp_sel};
use super::surface::SurfaceShape;

/// The plane kernel's constants for one block (see [`SimArm::substeps_plane`]).
struct PlaneFrame {
    /// The plane's tangents: `(n, t1, t2)` is right-handed and orthonormal.
    t1: [f64; 3],
    t2: [f64; 3],
    /// The legs' Jacobian in the plane's frame: `jb[c][r]` = d l_r / d V_c.
    jb: [[f64; 4]; 4],
    /// Velocity change per period per newton of leg force r: `a[r][c]`.
    a: [[f64; 4]; 4],
    /// The platform damping's share of the velocity kept per period, per axis.
    decay: [f64; 4],
}

impl SimArm {
    /// `n` servo periods with the Jacobian held: the inner loop of the simulation,
    /// specialised per surface shape.
    pub(super) fn substeps(&mut self, n: u32) {
        if self.cut.is_some() {
            self.substeps_cutting(n);
            return;
        }
        match self.surface.shape {
            SurfaceShape::Plane { point_mm, normal } if !self.generic_kernel_forced() => {
                self.substeps_plane(n, point_mm, normal)
            }
            _ => {
                let s = self.surface;
                self.substeps_with(n, move |p: &Vector3<f64>| s.penetration(p));
            }
        }
    }

    #[cfg(test)]
    fn generic_kernel_forced(&self) -> bool {
        self.generic_kernel
    }

    #[cfg(not(test))]
    #[inline(always)]
    fn generic_kernel_forced(&self) -> bool {
        false
    }

    /// The kernel of [`SimArm::substeps`] for a plane: the same physics as
    /// [`SimArm::substeps_with`] (which the curved surfaces use), arranged for speed; only
    /// the rounding differs. The plane's normal is fixed, so the platform's velocity is kept
    /// in the plane's frame, `V = [v·n, v·t1, v·t2, θ̇]`: the contact reads its normal part
    /// and the friction solve scales its tangential part directly, the contact depth is the
    /// normal displacement, and every product with the Jacobian is one 4×4 matrix (`J` in
    /// that frame, projected once per block) on four-wide vectors, which the compiler
    /// vectorises. The leg rates of the tangential velocity are computed before the
    /// friction's square root is known and scaled after it, and the structural force is
    /// one multiply-add of the leg rate (`base`, the carriages' share, is known earlier).
    /// Measured variants (docs/slave-results.md, "Speed"): this one was the fastest; one
    /// that also propagated the velocity through a precomputed `M V` (a shorter chain,
    /// more arithmetic) and one with the fewest operations were both slower.
    fn substeps_plane(&mut self, n: u32, point_mm: [f64; 3], nrm: [f64; 3]) {
        let dt = self.substep_s;
        let cfg = self.cfg;
        let servo = CarriageServo::new(&cfg, dt);
        let damp = cfg.platform_damping_n_s_per_mm;
        let k = self.k;
        let cs = self.c_struct;
        let cmd = self.command;
        let mut q = self.q;
        let mut qd = self.qd;
        let mut integ = self.integral;
        let dt_over_m_tool = self.inv_mass[0] * dt;
        let m_tool_over_dt = 1.0 / dt_over_m_tool;
        let dt_over_inertia = self.inv_mass[3] * dt;

        let PlaneFrame {
            t1,
            t2,
            jb,
            a,
            decay,
        } = self.plane_frame(nrm, dt_over_m_tool, dt_over_inertia, damp);
        // Structural spring over one period: f = k (l + ld dt − q) + cs (ld − qd).
        let mut k_dt_cs = [0.0f64; 4];
        for i in 0..4 {
            k_dt_cs[i] = k[i] * dt + cs[i];
        }
        // State at the start of the block.
        let mut pose = [self.pose[0], self.pose[1], self.pose[2], self.pose[3]];
        let v3 = [self.vel[0], self.vel[1], self.vel[2]];
        let mut vb = [dot3(&v3, &nrm), dot3(&v3, &t1), dot3(&v3, &t2), self.vel[3]];
        let (mut l, mut ld) = self.legs_now();
        let mut f = [0.0f64; 4];
        for r in 0..4 {
            f[r] = k[r] * (l[r] - q[r]) + cs[r] * (ld[r] - qd[r]);
        }
        // Gravity's velocity change per period, in the plane's frame.
        let g = cfg.gravity_mm_per_s2;
        let gdt = [
            dot3(&g, &nrm) * dt,
            dot3(&g, &t1) * dt,
            dot3(&g, &t2) * dt,
            0.0,
        ];
        // Velocity before the contact forces of the first period.
        let mut w = [0.0f64; 4];
        for c in 0..4 {
            w[c] = vb[c] * decay[c] + gdt[c]
                - ((a[0][c] * f[0] + a[1][c] * f[1]) + (a[2][c] * f[2] + a[3][c] * f[3]));
        }
        let depth0 = -(nrm[0] * (pose[0] - point_mm[0])
            + nrm[1] * (pose[1] - point_mm[1])
            + nrm[2] * (pose[2] - point_mm[2]));
        let mut disp = [0.0f64; 4];

        let material = self.surface.material;
        let k_env = material.stiffness_n_per_mm;
        let b_env = self.contact_damping;
        let mu = material.friction_coefficient;
        let reg = cfg.friction_velocity_mm_per_s;
        let mut pen = self.penetration_mm;
        let mut last_fn = 0.0;
        let mut last_slip = [0.0f64; 2];
        // Σ normal force and Σ slip over the block, for the sensor's period mean.
        let (mut sum_fn, mut sum_slip) = (0.0, [0.0f64; 2]);
        for _ in 0..n {
            // Carriages: PID servo on the encoder (derivative on the measurement,
            // anti-windup), the structural force f, friction.
            let mut base = [0.0f64; 4];
            for i in 0..4 {
                let pre = k[i] * (l[i] - q[i]);
                let v_new = servo.step(cmd[i], &mut q[i], &mut qd[i], &mut integ[i], f[i]);
                // The next period's structural force without the platform's share.
                base[i] = pre - k_dt_cs[i] * v_new;
            }
            // Contact at the tool point (Kelvin–Voigt, damping on the last velocity).
            let depth = depth0 - disp[0];
            pen = depth;
            let mut dv_n = 0.0;
            let mut removed = 0.0;
            last_fn = 0.0;
            if depth > 0.0 {
                let f_n = clamp_sel(k_env * depth - b_env * vb[0], 0.0, f64::INFINITY);
                dv_n = f_n * dt_over_m_tool;
                // Regularised Coulomb friction F_t = −μ F_n v_t / max(|v_t|, v₀), solved
                // for the velocity at the end of the period (backward Euler): `removed`
                // of the tangential velocity goes (see `substeps_with`).
                let s2 = w[1] * w[1] + w[2] * w[2];
                let reach = mu * dv_n;
                let edge = reg + reach;
                removed = if s2 >= edge * edge {
                    (reach / s2) * s2.sqrt()
                } else {
                    reach / edge
                };
                last_fn = f_n;
            }
            let v0 = w[0] + dv_n;
            let (w1, w2, w3) = (w[1], w[2], w[3]);
            last_slip = [w1 * removed, w2 * removed];
            sum_fn += last_fn;
            sum_slip = [sum_slip[0] + last_slip[0], sum_slip[1] + last_slip[1]];
            // Leg rates J V (the tangential part's computed before the friction's square
            // root is known, then scaled), the structural forces and leg lengths of the
            // next period.
            for r in 0..4 {
                let fixed = jb[0][r] * v0 + jb[3][r] * w3;
                let slid = jb[1][r] * w1 + jb[2][r] * w2;
                ld[r] = fixed + (slid - removed * slid);
                f[r] = k_dt_cs[r] * ld[r] + base[r];
                l[r] += ld[r] * dt;
            }
            vb = [v0, w1 - removed * w1, w2 - removed * w2, w3];
            // The next period's velocity before contact: the legs act through Jᵀ
            // (explicit), plus joint/air damping.
            let mut w_next = [0.0f64; 4];
            for c in 0..4 {
                w_next[c] = vb[c] * decay[c] + gdt[c]
                    - ((a[0][c] * f[0] + a[1][c] * f[1]) + (a[2][c] * f[2] + a[3][c] * f[3]));
            }
            for c in 0..4 {
                disp[c] += vb[c] * dt;
            }
            w = w_next;
        }
        for a in 0..3 {
            pose[a] += nrm[a] * disp[0] + t1[a] * disp[1] + t2[a] * disp[2];
        }
        pose[3] += disp[3];
        self.q = q;
        self.qd = qd;
        self.integral = integ;
        self.pose = Pose::from(pose);
        let mut vel = [0.0f64; 4];
        for a in 0..3 {
            vel[a] = nrm[a] * vb[0] + t1[a] * vb[1] + t2[a] * vb[2];
        }
        vel[3] = vb[3];
        self.vel = Pose::from(vel);
        self.penetration_mm = pen;
        let fc = plane_force(&nrm, &t1, &t2, last_fn, last_slip, m_tool_over_dt);
        let sum = plane_force(&nrm, &t1, &t2, sum_fn, sum_slip, m_tool_over_dt);
        self.contact_wrench = Vector4::new(fc[0], fc[1], fc[2], 0.0);
        self.book_load(sum, n);
    }

    /// The legs' lengths and rates at the platform's present pose and velocity, the
    /// Jacobian held (linearised about `pose0`): where a block of servo periods starts.
    #[inline(always)]
    fn legs_now(&self) -> ([f64; 4], [f64; 4]) {
        let mut l = [0.0f64; 4];
        let mut ld = [0.0f64; 4];
        for r in 0..4 {
            let mut acc = self.l0[r];
            let mut rate = 0.0;
            for c in 0..4 {
                acc += self.jac[(r, c)] * (self.pose[c] - self.pose0[c]);
                rate += self.jac[(r, c)] * self.vel[c];
            }
            l[r] = acc;
            ld[r] = rate;
        }
        (l, ld)
    }

    /// The constants of a block of the plane kernel: the plane's frame `(nrm, t1, t2)`, the
    /// legs' Jacobian in it (the Jacobian held over the block) and the platform's velocity
    /// response per period (`dt_over_m_tool`, `dt_over_inertia`: the period over the tool's
    /// mass and inertia; `damp`: the platform's damping).
    #[inline(always)]
    fn plane_frame(
        &self,
        nrm: [f64; 3],
        dt_over_m_tool: f64,
        dt_over_inertia: f64,
        damp: f64,
    ) -> PlaneFrame {
        // The plane's frame and the legs' Jacobian in it: `jb[c][r]` = d l_r / d V_c.
        let (t1, t2) = tangent_basis(nrm);
        let basis = [nrm, t1, t2];
        let mut jb = [[0.0f64; 4]; 4];
        for (c, col) in jb.iter_mut().enumerate() {
            for (r, v) in col.iter_mut().enumerate() {
                *v = if c < 3 {
                    self.jac[(r, 0)] * basis[c][0]
                        + self.jac[(r, 1)] * basis[c][1]
                        + self.jac[(r, 2)] * basis[c][2]
                } else {
                    self.jac[(r, 3)]
                };
            }
        }
        // Velocity change per period per newton of leg force r: `a[r][c]`.
        let per_mass = [
            dt_over_m_tool,
            dt_over_m_tool,
            dt_over_m_tool,
            dt_over_inertia,
        ];
        let mut decay = [0.0f64; 4];
        let mut a = [[0.0f64; 4]; 4];
        for c in 0..4 {
            decay[c] = 1.0 - damp * per_mass[c];
            for r in 0..4 {
                a[r][c] = jb[c][r] * per_mass[c];
            }
        }
        PlaneFrame {
            t1,
            t2,
            jb,
            a,
            decay,
        }
    }

    #[inline(always)]
    fn substeps_with<F: Fn(&Vector3<f64>) -> (f64, Vector3<f64>)>(
        &mut self,
        n: u32,
        penetration: F,
    ) {
        let mut st = Substep::new(self);
        let cfg = self.cfg;
        let surface = self.surface;
        let k_env = surface.material.stiffness_n_per_mm;
        let b_env = self.contact_damping;
        let mu = surface.material.friction_coefficient;
        let reg = cfg.friction_velocity_mm_per_s;
        let mut fc = [0.0f64; 3];
        let mut sum = [0.0f64; 3];
        let mut pen = self.penetration_mm;
        // Products of constants taken out of the loop.
        let dt_over_m_tool = st.dt_over_m_tool;
        let m_tool_over_dt = 1.0 / dt_over_m_tool;
        for _ in 0..n {
            let mut vs = st.structure();
            let vel = st.vel;
            // Contact at the tool point.
            let p = Vector3::new(st.pose[0], st.pose[1], st.pose[2]);
            let (depth, nrm) = penetration(&p);
            pen = depth;
            fc = [0.0; 3];
            if depth > 0.0 {
                let vn = vel[0] * nrm[0] + vel[1] * nrm[1] + vel[2] * nrm[2];
                let f_n = (k_env * depth - b_env * vn).max(0.0);
                let dv_n = f_n * dt_over_m_tool;
                for a in 0..3 {
                    vs[a] += nrm[a] * dv_n;
                }
                // Regularised Coulomb friction F_t = −μ F_n v_t / max(|v_t|, v₀), solved
                // for the velocity at the end of the period (backward Euler): below v₀ it
                // is a damper of μ F_n / v₀, far too stiff for an explicit step with the
                // tool's mass; solved implicitly, |F_t| ≤ μ F_n always holds.
                let vsn = vs[0] * nrm[0] + vs[1] * nrm[1] + vs[2] * nrm[2];
                let vt = [
                    vs[0] - nrm[0] * vsn,
                    vs[1] - nrm[1] * vsn,
                    vs[2] - nrm[2] * vsn,
                ];
                let s2 = vt[0] * vt[0] + vt[1] * vt[1] + vt[2] * vt[2];
                let reach = mu * dv_n;
                let edge = reg + reach;
                // Sliding on (|v_t| − reach ≥ v₀): `reach` of the speed goes; below, the
                // damper regime. (reach / |v_t|² × |v_t|: the division and the square root
                // run side by side, off each other's latency.)
                let removed = if s2 >= edge * edge {
                    (reach / s2) * s2.sqrt()
                } else {
                    reach / edge
                };
                for a in 0..3 {
                    let dv_t = vt[a] * removed;
                    vs[a] -= dv_t;
                    fc[a] = nrm[a] * f_n - dv_t * m_tool_over_dt;
                }
            }
            for (s, f) in sum.iter_mut().zip(fc) {
                *s += f;
            }
            st.advance(vs);
        }
        st.store(self);
        self.penetration_mm = pen;
        self.contact_wrench = Vector4::new(fc[0], fc[1], fc[2], 0.0);
        self.book_load(sum, n);
    }
}

/// One block of servo periods with the Jacobian held, the part every contact model shares:
/// the carriages' servos against the structure's springs, and the platform's motion. A
/// kernel calls [`Substep::structure`], applies its contact to the velocity it returns, then
/// [`Substep::advance`]; [`Substep::store`] writes the state back.
pub(in crate::plant) struct Substep {
    j: [[f64; 4]; 4],
    servo: CarriageServo,
    damp: f64,
    g: [f64; 3],
    k: [f64; 4],
    cs: [f64; 4],
    cmd: [f64; 4],
    /// The servo period, s.
    pub dt: f64,
    /// The period over the tool's mass, s/kg.
    pub dt_over_m_tool: f64,
    dt_over_inertia: f64,
    q: [f64; 4],
    qd: [f64; 4],
    integ: [f64; 4],
    /// The platform's pose, mm and rad.
    pub pose: [f64; 4],
    /// The platform's velocity at the start of the period, mm/s and rad/s.
    pub vel: [f64; 4],
    l: [f64; 4],
    ld: [f64; 4],
}

impl Substep {
    /// The block's constants and the arm's state.
    pub(in crate::plant) fn new(arm: &SimArm) -> Self {
        let dt = arm.substep_s;
        let cfg = arm.cfg;
        let mut j = [[0.0f64; 4]; 4];
        for (r, row) in j.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = arm.jac[(r, c)];
            }
        }
        let pose = [arm.pose[0], arm.pose[1], arm.pose[2], arm.pose[3]];
        let vel = [arm.vel[0], arm.vel[1], arm.vel[2], arm.vel[3]];
        // Leg lengths and the rates the platform imposes (J held over the block).
        let (l, ld) = arm.legs_now();
        Substep {
            j,
            servo: CarriageServo::new(&cfg, dt),
            damp: cfg.platform_damping_n_s_per_mm,
            g: cfg.gravity_mm_per_s2,
            k: arm.k,
            cs: arm.c_struct,
            cmd: arm.command,
            dt,
            dt_over_m_tool: arm.inv_mass[0] * dt,
            dt_over_inertia: arm.inv_mass[3] * dt,
            q: arm.q,
            qd: arm.qd,
            integ: arm.integral,
            pose,
            vel,
            l,
            ld,
        }
    }

    /// The carriages' servos against the structural springs, then the platform under the
    /// legs' forces (through Jᵀ, explicit), its damping and gravity: advances the rotation
    /// and returns the translational velocity before the contact forces, mm/s.
    #[inline(always)]
    pub(in crate::plant) fn structure(&mut self) -> [f64; 3] {
        let (j, k, cs) = (&self.j, &self.k, &self.cs);
        let mut f_act = [0.0f64; 4];
        for i in 0..4 {
            // Structural spring, positive when the platform pulls the carriage forward.
            let f = k[i] * (self.l[i] - self.q[i]) + cs[i] * (self.ld[i] - self.qd[i]);
            f_act[i] = f;
            self.servo.step(
                self.cmd[i],
                &mut self.q[i],
                &mut self.qd[i],
                &mut self.integ[i],
                f,
            );
        }
        // Platform: the legs act through Jᵀ (explicit), plus joint/air damping.
        let mut gen_f = [0.0f64; 4];
        for (c, g) in gen_f.iter_mut().enumerate() {
            *g = -(j[0][c] * f_act[0]
                + j[1][c] * f_act[1]
                + j[2][c] * f_act[2]
                + j[3][c] * f_act[3])
                - self.vel[c] * self.damp;
        }
        self.vel[3] += gen_f[3] * self.dt_over_inertia;
        let (g, dt, dm) = (self.g, self.dt, self.dt_over_m_tool);
        [
            self.vel[0] + gen_f[0] * dm + g[0] * dt,
            self.vel[1] + gen_f[1] * dm + g[1] * dt,
            self.vel[2] + gen_f[2] * dm + g[2] * dt,
        ]
    }

    /// Takes the translational velocity after the contact, moves the platform over the
    /// period and updates the legs.
    #[inline(always)]
    pub(in crate::plant) fn advance(&mut self, vs: [f64; 3]) {
        let (j, dt) = (&self.j, self.dt);
        self.vel[..3].copy_from_slice(&vs);
        let vel = self.vel;
        for (p, v) in self.pose.iter_mut().zip(vel) {
            *p += v * dt;
        }
        for ((ld, l), jr) in self.ld.iter_mut().zip(self.l.iter_mut()).zip(j) {
            *ld = jr[0] * vel[0] + jr[1] * vel[1] + jr[2] * vel[2] + jr[3] * vel[3];
            *l += *ld * dt;
        }
    }

    /// Writes the carriages' and the platform's state back into the arm.
    pub(in crate::plant) fn store(&self, arm: &mut SimArm) {
        arm.q = self.q;
        arm.qd = self.qd;
        arm.integral = self.integ;
        arm.pose = Pose::from(self.pose);
        arm.vel = Pose::from(self.vel);
    }
}

/// The plane kernel's contact force in the base frame, N: the normal force `f_n` along
/// `nrm` and the friction that took the tangential velocity `slip` (along `t1`, `t2`) off
/// the tool in one period (`m_over_dt`: the tool's mass over the period).
#[inline(always)]
fn plane_force(
    nrm: &[f64; 3],
    t1: &[f64; 3],
    t2: &[f64; 3],
    f_n: f64,
    slip: [f64; 2],
    m_over_dt: f64,
) -> [f64; 3] {
    let mut f = [0.0f64; 3];
    for a in 0..3 {
        f[a] = nrm[a] * f_n - (t1[a] * slip[0] + t2[a] * slip[1]) * m_over_dt;
    }
    f
}

/// Two unit vectors that complete the unit vector `n` to a right-handed orthonormal frame
/// `(n, t1, t2)`: `t1` from the axis least aligned with `n`.
fn tangent_basis(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let mut axis = 0;
    for i in 1..3 {
        if n[i].abs() < n[axis].abs() {
            axis = i;
        }
    }
    let mut e = [0.0; 3];
    e[axis] = 1.0;
    let d = n[axis];
    let t = [e[0] - n[0] * d, e[1] - n[1] * d, e[2] - n[2] * d];
    let norm = dot3(&t, &t).sqrt();
    let t1 = [t[0] / norm, t[1] / norm, t[2] / norm];
    let t2 = [
        n[1] * t1[2] - n[2] * t1[1],
        n[2] * t1[0] - n[0] * t1[2],
        n[0] * t1[1] - n[1] * t1[0],
    ];
    (t1, t2)
}
