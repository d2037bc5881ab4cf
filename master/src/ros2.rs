//! The master's CRTK topics for ROS 2 (issue 35): [`Ros2Tee`] wraps the server's [`Sink`] and,
//! every cycle, writes the handle's pose and the rendered wrench as a [`MasterSample`] into
//! the [`LatestCell`] the ROS 2 publishing thread (`h4_transport::ros2::node`, started by the
//! command line) reads at its own rate. No allocation, no waiting, no Zenoh in the loop.

use std::sync::Arc;

use h4_telemetry::sink::Sink;
use h4_transport::ros2::telemetry::{LatestCell, MasterSample};

use crate::server::CycleRecord;

/// A sink that also feeds the ROS 2 publishing thread (none: just the inner sink).
pub struct Ros2Tee<S> {
    inner: S,
    cell: Option<Arc<LatestCell<MasterSample>>>,
}

impl<S> Ros2Tee<S> {
    /// `inner`, and the cell of the publishing thread when `--ros2` is on.
    pub fn new(inner: S, cell: Option<Arc<LatestCell<MasterSample>>>) -> Self {
        Ros2Tee { inner, cell }
    }
}

impl<S: Sink<CycleRecord>> Sink<CycleRecord> for Ros2Tee<S> {
    fn record(&mut self, unix_ns: u64, first: CycleRecord, second: Option<()>) {
        if let Some(cell) = &self.cell {
            cell.offer(MasterSample {
                stamp_unix_ns: unix_ns,
                pose_mm_rad: first.pose,
                wrench_rendered_n_nmm: first.rendered_wrench,
            });
        }
        self.inner.record(unix_ns, first, second);
    }
    fn show(&mut self, unix_ns: u64, first: CycleRecord, second: Option<()>) {
        self.inner.show(unix_ns, first, second);
    }
    fn dropped(&self) -> u64 {
        self.inner.dropped()
    }
    fn finish(self) -> Result<(), String> {
        self.inner.finish()
    }
}
