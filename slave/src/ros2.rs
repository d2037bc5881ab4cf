//! The slave's CRTK topics for ROS 2 (issue 35): [`Ros2Tee`] wraps the server's [`Sink`] and,
//! every cycle, writes the cycle as an [`SlaveSample`] into the [`LatestCell`] the ROS 2
//! publishing thread (`h4_transport::ros2::node`, started by the command line) reads at its
//! own rate. The loop's cost: one finite difference and one `try_lock`ed copy; no
//! allocation, no waiting, no Zenoh.

use std::sync::Arc;

use h4_shared::wire::SlaveState;
use h4_telemetry::sink::Sink;
use h4_transport::ros2::telemetry::{CrtkState, LatestCell, SlaveSample};

use crate::server::CycleRecord;

/// A sink that also feeds the ROS 2 publishing thread (none: just the inner sink).
pub struct Ros2Tee<S> {
    inner: S,
    cell: Option<Arc<LatestCell<SlaveSample>>>,
    /// The previous cycle's loop time, ns, and measured pose, for the velocity.
    prev: Option<(u64, [f64; 4])>,
}

impl<S> Ros2Tee<S> {
    /// `inner`, and the cell of the publishing thread when `--ros2` is on.
    pub fn new(inner: S, cell: Option<Arc<LatestCell<SlaveSample>>>) -> Self {
        Ros2Tee {
            inner,
            cell,
            prev: None,
        }
    }
}

/// The CRTK state of an endpoint state code (`SlaveState as u8`).
pub fn crtk_state(state: u8) -> CrtkState {
    match state {
        s if s == SlaveState::Active as u8 => CrtkState::Following,
        s if s == SlaveState::SafeStop as u8 => CrtkState::Paused,
        s if s == SlaveState::Fault as u8 => CrtkState::Fault,
        _ => CrtkState::Ready,
    }
}

/// The sample of one cycle: the measured pose, its finite-difference velocity since the
/// previous cycle (`prev`: its loop time and pose; zero at the first), the sensor's wrench,
/// and the force set-point along the contact normal as a force vector.
pub fn sample_of(unix_ns: u64, r: &CycleRecord, prev: Option<(u64, [f64; 4])>) -> SlaveSample {
    let mut velocity = [0.0; 4];
    if let Some((t0, p0)) = prev {
        let dt_s = r.time_ns.saturating_sub(t0) as f64 * 1e-9;
        if dt_s > 0.0 {
            for (v, (p, q)) in velocity
                .iter_mut()
                .zip(r.measured_pose.iter().zip(p0.iter()))
            {
                *v = (p - q) / dt_s;
            }
        }
    }
    let n = r.contact_normal;
    let f = r.force_desired_n;
    SlaveSample {
        stamp_unix_ns: unix_ns,
        pose_mm_rad: r.measured_pose,
        velocity_mm_rad_per_s: velocity,
        wrench_sensor_n_nmm: r.wrench_sensor,
        wrench_setpoint_n_nmm: [f * n[0], f * n[1], f * n[2], 0.0],
        state: crtk_state(r.state),
    }
}

impl<S, U> Sink<CycleRecord, U> for Ros2Tee<S>
where
    S: Sink<CycleRecord, U>,
{
    fn record(&mut self, unix_ns: u64, first: CycleRecord, second: Option<U>) {
        if let Some(cell) = &self.cell {
            cell.offer(sample_of(unix_ns, &first, self.prev));
            self.prev = Some((first.time_ns, first.measured_pose));
        }
        self.inner.record(unix_ns, first, second);
    }
    fn show(&mut self, unix_ns: u64, first: CycleRecord, second: Option<U>) {
        self.inner.show(unix_ns, first, second);
    }
    fn dropped(&self) -> u64 {
        self.inner.dropped()
    }
    fn finish(self) -> Result<(), String> {
        self.inner.finish()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use h4_telemetry::sink::NoSink;

    fn record(time_ns: u64, x_mm: f64, state: SlaveState) -> CycleRecord {
        CycleRecord {
            time_ns,
            state: state as u8,
            status: 0,
            lateness_us: 0.0,
            force_measured_n: 0.0,
            force_desired_n: 4.0,
            force_true_n: 0.0,
            measured_pose: [x_mm, 0.0, 100.0, 0.0],
            commanded_pose: [0.0; 4],
            contact_normal: [0.0, 0.0, 1.0],
            command_seq: 0,
            energy_observed_j: 0.0,
            actuators_mm: [0.0; 4],
            wrench_sensor: [0.0, 0.0, 3.5, 10.0],
        }
    }

    #[test]
    fn the_tee_feeds_the_cell_every_cycle_with_velocity_and_setpoint() {
        let cell = Arc::new(LatestCell::new());
        let mut tee = Ros2Tee::new(NoSink, Some(Arc::clone(&cell)));
        Sink::<CycleRecord, ()>::record(&mut tee, 10, record(0, 1.0, SlaveState::Idle), None);
        let (v1, s1) = cell.newer_than(0).unwrap();
        assert_eq!(s1.velocity_mm_rad_per_s, [0.0; 4]);
        assert_eq!(s1.state, CrtkState::Ready);
        Sink::<CycleRecord, ()>::record(
            &mut tee,
            11,
            record(1_000_000, 1.5, SlaveState::Active),
            None,
        );
        let (_, s2) = cell.newer_than(v1).unwrap();
        assert_eq!(s2.stamp_unix_ns, 11);
        assert!((s2.velocity_mm_rad_per_s[0] - 500.0).abs() < 1e-9);
        assert_eq!(s2.wrench_setpoint_n_nmm, [0.0, 0.0, 4.0, 0.0]);
        assert_eq!(s2.wrench_sensor_n_nmm, [0.0, 0.0, 3.5, 10.0]);
        assert_eq!(s2.state, CrtkState::Following);
    }

    #[test]
    fn states_map_to_crtk() {
        assert_eq!(crtk_state(SlaveState::SafeStop as u8), CrtkState::Paused);
        assert_eq!(crtk_state(SlaveState::Fault as u8), CrtkState::Fault);
        assert_eq!(crtk_state(SlaveState::Idle as u8), CrtkState::Ready);
    }
}
