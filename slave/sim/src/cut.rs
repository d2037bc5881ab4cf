//! The cut as the simulated arm knows it: an extension of the product's endpoint
//! ([`SlaveTeleop`]) over the simulated arm, for the lockstep session and `h4-slave run
//! --arm sim`. The product crate knows nothing of cutting stock or its judge.

use h4_slave::controller::Status;
use h4_slave::teleop::{SlaveTeleop, TeleopCycle};
use serde::Serialize;

use crate::plant::SimArm;
use crate::plant::cutting::export::ExportError;
use crate::plant::cutting::judge::{
    CutEvaluator, CutSample, CutSummary, CutTarget, write_cut_json, write_outputs,
};

/// One cycle of the cut, in a cutting session or a cutting `h4-slave run` (topic
/// `/slave/cut`, schema `h4.CutCycle`: the simulation's recording and the processes' live
/// view).
#[derive(Clone, Copy, Debug, Serialize, schemars::JsonSchema)]
pub struct CutCycle {
    /// The tool's tip in the workpiece frame, mm (simulation truth).
    pub tool_tip_in_workpiece_mm: [f64; 3],
    /// The contact force on the tool (cutting, or rubbing when the spindle is stopped) at
    /// the cycle's end, N, workpiece frame (simulation truth, with the tooth-passing
    /// ripple).
    pub cutting_force_n: [f64; 3],
    /// That force averaged over the cycle, N.
    pub cutting_force_mean_n: [f64; 3],
    /// Volume removed so far, mm³.
    pub removed_mm3: f64,
    /// Removal rate over the cycle, mm³/s.
    pub removal_rate_mm3_per_s: f64,
    /// The spindle's torque over the cycle, N·mm.
    pub spindle_torque_n_mm: f64,
    /// The spindle has stalled.
    pub stalled: bool,
    /// A virtual fixture limited the slave's command this cycle.
    pub fixture_active: bool,
    /// The turntable's true angle, rad (0 without a turntable: the workpiece frame is then
    /// the base frame).
    pub turntable_rad: f64,
    /// The turntable's commanded angle (its servo's last set-point as commanded), rad (0
    /// without a turntable).
    pub turntable_cmd_rad: f64,
}

/// The cut of a simulated arm's endpoint: its evidence for a [`CutEvaluator`], the
/// cutting fields of a summary, and the `/slave/cut` record.
pub trait CutTeleop {
    /// The evidence of the cut in cycle `c`, for a [`CutEvaluator`] (None when the arm does
    /// not cut).
    fn cut_sample(&self, c: &TeleopCycle) -> Option<CutSample>;
    /// The cutting fields of a summary from the evidence `ev` gathered, judged against
    /// `target` and the fixture floor `floor_z_mm`; with `out_dir`, the part's files there
    /// (`height.png`, `part.stl`, `deviation.png` with a target, `cut.json`: these cutting
    /// fields). None when the arm does not cut.
    fn finish_cut(
        &self,
        ev: CutEvaluator,
        target: Option<&CutTarget>,
        floor_z_mm: Option<f64>,
        out_dir: Option<&std::path::Path>,
    ) -> Result<Option<CutSummary>, ExportError>;
    /// This cycle's cut, when the simulated arm cuts a workpiece (None otherwise).
    fn cut_cycle(&self) -> Option<CutCycle>;
}

impl CutTeleop for SlaveTeleop<SimArm> {
    /// The evidence of the cut in cycle `c`, for a
    /// [`CutEvaluator`] (None when the arm does
    /// not cut).
    fn cut_sample(&self, c: &TeleopCycle) -> Option<CutSample> {
        let cut = self.arm().cut()?;
        let p = self.arm().true_pose();
        Some(CutSample {
            report: cut.report(),
            tip_mm: cut.to_workpiece([p[0], p[1], p[2]]),
            in_contact: c.out.status == Status::Contact,
            fixture_active: self.controller().fixture_activity().0,
            setpoint_n: c.out.setpoint_n,
        })
    }

    /// The cutting fields of a summary from the evidence `ev` gathered, judged against
    /// `target` and the fixture floor `floor_z_mm`; with `out_dir`, the part's files there
    /// (`height.png`, `part.stl`, `deviation.png` with a target, `cut.json`: these cutting
    /// fields). None when the arm does not cut.
    fn finish_cut(
        &self,
        ev: CutEvaluator,
        target: Option<&CutTarget>,
        floor_z_mm: Option<f64>,
        out_dir: Option<&std::path::Path>,
    ) -> Result<Option<CutSummary>, ExportError> {
        let Some(cut) = self.arm().cut() else {
            return Ok(None);
        };
        let summary = ev.finish(
            cut.stock(),
            cut.tool(),
            &cut.report(),
            target,
            floor_z_mm,
            self.controller().fixture_activity().1,
        );
        if let Some(dir) = out_dir {
            write_outputs(dir, cut.stock(), cut.tool(), target)?;
            write_cut_json(dir, &summary)?;
        }
        Ok(Some(summary))
    }

    /// This cycle's cut, when the simulated arm cuts a workpiece (None otherwise).
    fn cut_cycle(&self) -> Option<CutCycle> {
        let cut = self.arm().cut()?;
        let tp = self.arm().true_pose();
        let f = self.arm().true_contact_wrench();
        let rep = cut.report();
        let table = cut.turntable();
        Some(CutCycle {
            tool_tip_in_workpiece_mm: cut.to_workpiece([tp[0], tp[1], tp[2]]),
            cutting_force_n: [f[0], f[1], f[2]],
            cutting_force_mean_n: rep.mean_force_n,
            removed_mm3: rep.removed_mm3,
            removal_rate_mm3_per_s: rep.removal_rate_mm3_per_s,
            spindle_torque_n_mm: rep.spindle_torque_n_mm,
            stalled: rep.stalled,
            fixture_active: self.controller().fixture_activity().0,
            turntable_rad: table.map_or(0.0, |t| t.angle_rad()),
            turntable_cmd_rad: table.map_or(0.0, |t| t.commanded_rad()),
        })
    }
}
