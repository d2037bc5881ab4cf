//! The simulated slave as configuration: the sections that make one arm with its force
//! sensor, the surface it touches and its controller, and the one place that builds them.

use h4_shared::config::{ArmConfig, ConfigError, Section};
use h4_shared::kinematics::Pose;
use serde::{Deserialize, Serialize};

use crate::plant::cutting::CuttingConfig;
use crate::plant::{PlantConfig, SensorConfig, SimArm, SimError, SurfaceConfig};
use h4_slave::controller::{ControllerParams, FixturesConfig, SlaveController};

/// The slave-side sections of a simulation: arm, surface, sensor, plant, controller.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SlaveWorld {
    /// The arm: geometry, the actuator stiffness the controller assumes, workspace.
    pub arm: ArmConfig,
    /// The surface the tool touches (the controller does not know it).
    pub surface: SurfaceConfig,
    /// The force sensor.
    pub sensor: SensorConfig,
    /// The simulated arm's mechanics and servos.
    pub plant: PlantConfig,
    /// The controller.
    pub controller: ControllerParams,
    /// The workpiece and the spindle's tool, when the arm cuts (`docs/cutting.md`); the
    /// surface's material then gives the tool's rubbing contact with the stock.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cutting: Option<CuttingConfig>,
    /// Virtual fixtures the controller holds the tool point in (`docs/cutting.md`).
    #[serde(default, skip_serializing_if = "FixturesConfig::is_empty")]
    pub fixtures: FixturesConfig,
}

impl Section for SlaveWorld {
    /// Checks every section, under `prefix` + `arm.`, `surface.`, `sensor.`, `plant.`,
    /// `controller.`, `cutting.`.
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        self.arm.validate_at(&format!("{prefix}arm."))?;
        self.surface.validate_at(&format!("{prefix}surface."))?;
        self.sensor.validate_at(&format!("{prefix}sensor."))?;
        self.plant.validate_at(&format!("{prefix}plant."))?;
        self.controller
            .validate_at(&format!("{prefix}controller."))?;
        if let Some(c) = &self.cutting {
            c.validate_at(&format!("{prefix}cutting."))?;
        }
        self.fixtures.validate_at(&format!("{prefix}fixtures."))?;
        let table = self.cutting.is_some_and(|c| c.turntable.is_some());
        self.fixtures
            .check_turntable(&format!("{prefix}fixtures."), table)
    }
}

impl SlaveWorld {
    /// The simulated arm, at rest at `initial_pose` (its sensor noise drawn from `seed`)
    /// with the surface in place, and its controller (assuming the arm's configured
    /// actuator stiffness).
    pub fn build(
        &self,
        initial_pose: Pose,
        seed: u64,
    ) -> Result<(SimArm, SlaveController), SimError> {
        // A mesh fixture guards only once its part is loaded (`judge::load_mesh_target`):
        // never run with it silently off.
        if self
            .fixtures
            .mesh
            .as_ref()
            .is_some_and(|m| m.guard.is_none())
        {
            return Err(SimError::BadParameter(
                "fixtures.mesh (its part, the cut_target's mesh, is not loaded)",
            ));
        }
        let ws = self.arm.workspace();
        let assumed = self.arm.stiffness()?;
        let arm = SimArm::new(
            ws.params,
            self.arm.actuator_stiffness_n_per_mm,
            self.plant,
            self.sensor,
            self.surface.surface(),
            initial_pose,
            seed,
        )?;
        let arm = match &self.cutting {
            Some(c) => arm.with_cutting(c)?,
            None => arm,
        };
        let mut ctrl = SlaveController::new(ws, assumed, self.controller)
            .with_tool(self.arm.tool)
            .with_fixtures(&self.fixtures);
        if let Some(t) = self.cutting.and_then(|c| c.turntable) {
            ctrl = ctrl.with_turntable_axis(t.axis_mm);
        }
        Ok((arm, ctrl))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::{MaterialPreset, ShapeKind};

    fn world() -> SlaveWorld {
        SlaveWorld {
            arm: ArmConfig::default(),
            surface: SurfaceConfig::new(
                ShapeKind::Plane,
                MaterialPreset::Steel,
                [0.0, 0.0, -250.0],
            ),
            sensor: SensorConfig::default(),
            plant: PlantConfig::default(),
            controller: ControllerParams::default(),
            cutting: None,
            fixtures: FixturesConfig::default(),
        }
    }

    /// One value, one verdict: a section's field is named under the prefix it is checked at,
    /// with its range, wherever the section appears.
    #[test]
    fn every_section_names_its_fields_under_the_prefix() {
        assert!(world().validate_at("slave.").is_ok());
        let mut w = world();
        w.controller.kp = -5.0;
        let e = w.validate_at("slave.").unwrap_err().to_string();
        assert!(
            e.contains("slave.controller.kp") && e.contains("0 to 10"),
            "{e}"
        );
        let mut w = world();
        w.controller.tool_mass_kg = 0.0;
        let e = w.validate_at("").unwrap_err().to_string();
        assert!(e.contains("controller.tool_mass_kg"), "{e}");
        let mut w = world();
        w.surface.tilt_deg = 61.0;
        let e = w.validate_at("").unwrap_err().to_string();
        assert!(e.contains("surface.tilt_deg"), "{e}");
        let mut w = world();
        w.sensor.bias_n[1] = 99.0;
        let e = w.validate_at("x.").unwrap_err().to_string();
        assert!(e.contains("x.sensor.bias_n[1]"), "{e}");
    }

    #[test]
    fn build_places_the_arm_and_its_surface() {
        let (arm, ctrl) = world().build(Pose::new(0.0, 0.0, -248.0, 0.0), 1).unwrap();
        let p = arm.true_pose();
        let (depth_mm, _) = arm
            .surface()
            .penetration(&nalgebra::Vector3::new(p[0], p[1], p[2]));
        assert!((depth_mm + 2.0).abs() < 1e-9, "{depth_mm}");
        assert_eq!(ctrl.params(), &ControllerParams::default());
        let mut bad = world();
        bad.plant.servo_rate_hz = 10.0;
        assert!(bad.build(Pose::new(0.0, 0.0, -248.0, 0.0), 1).is_err());
    }
}
