//! Configuration in TOML.
//!
//! Every configuration struct of the project is read through [`load`] / [`parse`]: the file
//! is parsed, `--set key.path=value` overrides are applied to it, and the result is
//! deserialised with unknown fields rejected, then validated ([`Validate`]) with errors
//! that name the field and its allowed range.

use std::path::Path;

use schemars::JsonSchema;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::kinematics::{ActuatorStiffness, H4Params, KinError, Workspace, WorkspaceLimits};

/// A configuration that could not be read or is not acceptable.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// The text is not valid TOML, or does not fit the expected fields (unknown field,
    /// wrong type, missing field). The message names the field.
    #[error("{source_name}: {message}")]
    Parse {
        /// File name, or a description of where the text came from.
        source_name: String,
        /// The parser's message.
        message: String,
    },
    /// A `--set key=value` argument is malformed or names a key that cannot be set.
    #[error("bad override `{arg}`: {reason}")]
    BadOverride {
        /// The argument as given.
        arg: String,
        /// Why it was refused.
        reason: String,
    },
    /// A field has a value outside its allowed range.
    #[error("{field} = {value} is out of range: allowed {allowed}")]
    OutOfRange {
        /// Dotted path of the field.
        field: String,
        /// The value given.
        value: String,
        /// The allowed range, with unit.
        allowed: String,
    },
}

/// A configuration that can check its own values.
pub trait Validate {
    /// Returns the first value outside its allowed range.
    fn validate(&self) -> Result<(), ConfigError>;
}

/// One section of a configuration file (`[slave.controller]`, `[coupling]`, …): its own type,
/// defaults and ranges. A file is only the sections it holds, so one value gets one verdict
/// wherever it appears.
pub trait Section {
    /// Checks every field of the section; `prefix` is the section's dotted path in the file
    /// with a trailing dot (`"slave.controller."`), so errors name the field as the user wrote it.
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError>;
}

/// What a check allows a field: a closed range, or a rule in words.
#[derive(Clone, Debug, PartialEq)]
pub enum Allowed {
    /// `min ≤ value ≤ max` (and finite), as [`check_range`] checks it.
    Range {
        /// Smallest value allowed.
        min: f64,
        /// Largest value allowed.
        max: f64,
    },
    /// A requirement stated in words (`must be finite and > 0`), as [`record_rule`] states it.
    Rule(String),
}

/// One check a validation ran, recorded by [`record_ranges`]: the field as the check named
/// it, what it allows and the unit it states.
#[derive(Clone, Debug, PartialEq)]
pub struct RangeRecord {
    /// The field's dotted path as checked, indices included (`slave.arm.actuator_stiffness_n_per_mm[2]`).
    pub field: String,
    /// What the check allows.
    pub allowed: Allowed,
    /// The unit as the check states it, with any note in parentheses (`mm (≥ the minimum)`;
    /// empty for a dimensionless value or a rule).
    pub unit: String,
}

impl RangeRecord {
    /// The field with its indices collapsed (see [`collapse_indices`]): every element of an
    /// array is one row of the reference.
    pub fn collapsed_field(&self) -> String {
        collapse_indices(&self.field)
    }

    /// The note the check put after the field's name in parentheses
    /// (`track.direction (length)` → `length`), if any.
    pub fn field_note(&self) -> Option<&str> {
        let (_, note) = self.field.split_once(" (")?;
        Some(note.strip_suffix(')').unwrap_or(note))
    }
}

/// A checked field's path as the reference lists it: a note after it in parentheses is cut
/// off, each index `[2]` becomes `[]`, and trailing `[]`s are dropped, so
/// `arm.actuator_stiffness_n_per_mm[2]` → `arm.actuator_stiffness_n_per_mm`,
/// `fixtures.corridor.path_mm[3][1]` → `fixtures.corridor.path_mm` and
/// `force.steps[0].time_s` → `force.steps[].time_s`.
pub fn collapse_indices(field: &str) -> String {
    let path = match field.split_once(" (") {
        Some((path, _)) => path,
        None => field,
    };
    let mut out = String::with_capacity(path.len());
    let mut rest = path;
    while let Some(open) = rest.find('[') {
        out.push_str(&rest[..open]);
        let after = &rest[open + 1..];
        match after.find(']') {
            Some(close) if after[..close].bytes().all(|b| b.is_ascii_digit()) => {
                out.push_str("[]");
                rest = &after[close + 1..];
            }
            _ => {
                out.push('[');
                rest = after;
            }
        }
    }
    out.push_str(rest);
    while out.ends_with("[]") {
        out.truncate(out.len() - 2);
    }
    out
}

thread_local! {
    /// The checks recorded on this thread while [`record_ranges`] runs (`None`: not recording).
    static RECORDED: std::cell::RefCell<Option<Vec<RangeRecord>>> =
        const { std::cell::RefCell::new(None) };
}

/// Whether [`record_ranges`] is recording on this thread (a caller that would build a field
/// name only for [`record_rule`] asks first).
pub fn recording() -> bool {
    RECORDED
        .try_with(|cell| cell.try_borrow().is_ok_and(|slot| slot.is_some()))
        .unwrap_or(false)
}

/// Adds one record if recording is on; `make` runs only then (nothing is built otherwise).
fn record(make: impl FnOnce() -> RangeRecord) {
    let _ = RECORDED.try_with(|cell| {
        if let Ok(mut slot) = cell.try_borrow_mut()
            && let Some(records) = slot.as_mut()
        {
            records.push(make());
        }
    });
}

/// Records a requirement in words on `field` (a check that is not a range, e.g. a geometry's
/// `|e| < R`) while [`record_ranges`] runs; does nothing otherwise.
pub fn record_rule(field: &str, rule: &str) {
    record(|| RangeRecord {
        field: field.to_string(),
        allowed: Allowed::Rule(rule.to_string()),
        unit: String::new(),
    });
}

/// Runs `f` (a validation) with recording on and returns its result with every check it
/// ran, in order: each [`check_range`] call (its field, min, max and unit) and each
/// [`record_rule`]. Recording is per thread; outside `f` nothing is recorded and the checks
/// cost one thread-local test. The reference (`h4-master config-reference`) takes the ranges
/// from here rather than from a copy.
pub fn record_ranges<R>(f: impl FnOnce() -> R) -> (R, Vec<RangeRecord>) {
    /// Puts the recorder back as it was, also if `f` panics.
    struct Restore(Option<Option<Vec<RangeRecord>>>);
    impl Drop for Restore {
        fn drop(&mut self) {
            if let Some(outer) = self.0.take() {
                let _ = RECORDED.try_with(|cell| {
                    if let Ok(mut slot) = cell.try_borrow_mut() {
                        *slot = outer;
                    }
                });
            }
        }
    }
    let outer = RECORDED.with(|cell| cell.replace(Some(Vec::new())));
    let restore = Restore(Some(outer));
    let out = f();
    let records = RECORDED
        .with(|cell| cell.borrow_mut().take())
        .unwrap_or_default();
    drop(restore);
    (out, records)
}

/// Checks `min ≤ value ≤ max` (and finiteness) for the field at `field`.
pub fn check_range(
    field: &str,
    value: f64,
    min: f64,
    max: f64,
    unit: &str,
) -> Result<(), ConfigError> {
    record(|| RangeRecord {
        field: field.to_string(),
        allowed: Allowed::Range { min, max },
        unit: unit.to_string(),
    });
    if value.is_finite() && value >= min && value <= max {
        Ok(())
    } else {
        Err(ConfigError::OutOfRange {
            field: field.to_string(),
            value: value.to_string(),
            allowed: format!("{min} to {max} {unit}").trim_end().to_string(),
        })
    }
}

/// Reads a TOML file, applies overrides, deserialises and validates it.
pub fn load<T: DeserializeOwned + Validate>(
    path: &Path,
    overrides: &[String],
) -> Result<T, ConfigError> {
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
        path: path.display().to_string(),
        source,
    })?;
    parse(&text, &path.display().to_string(), overrides)
}

/// Parses TOML text, applies `key.path=value` overrides, deserialises and validates it.
pub fn parse<T: DeserializeOwned + Validate>(
    text: &str,
    source_name: &str,
    overrides: &[String],
) -> Result<T, ConfigError> {
    let parse_err = |e: toml::de::Error| ConfigError::Parse {
        source_name: source_name.to_string(),
        message: e.to_string().trim_end().to_string(),
    };
    let value: T = if overrides.is_empty() {
        toml::from_str(text).map_err(parse_err)?
    } else {
        let mut table: toml::Table = toml::from_str(text).map_err(parse_err)?;
        let mut original_fits = None;
        for (i, arg) in overrides.iter().enumerate() {
            apply_override(&mut table, arg)?;
            if let Err(e) = from_table::<T>(&table, source_name) {
                // Blame the first override that turns a fitting document into one that does
                // not, by its key and value as given: the document the overrides produce is
                // not a file the user has, so its line numbers would mislead.
                let fits_before = *original_fits
                    .get_or_insert_with(|| i > 0 || toml::from_str::<T>(text).is_ok());
                if fits_before {
                    return Err(ConfigError::BadOverride {
                        arg: arg.clone(),
                        reason: e.message().trim_end().to_string(),
                    });
                }
            } else {
                original_fits = Some(true);
            }
        }
        match from_table(&table, source_name) {
            Ok(value) => value,
            // The file itself does not fit and no override mends it: its own lines.
            Err(_) if original_fits == Some(false) => toml::from_str(text).map_err(parse_err)?,
            Err(e) => {
                return Err(ConfigError::Parse {
                    source_name: format!("{source_name} (with --set overrides)"),
                    message: e.message().trim_end().to_string(),
                });
            }
        }
    };
    value.validate()?;
    Ok(value)
}

/// Deserialises a table (a document with overrides applied) into `T`.
fn from_table<T: DeserializeOwned>(
    table: &toml::Table,
    source_name: &str,
) -> Result<T, toml::de::Error> {
    let merged = toml::to_string(table).map_err(|e| {
        <toml::de::Error as serde::de::Error>::custom(format!("{source_name}: {e}"))
    })?;
    toml::from_str(&merged)
}

/// Applies one `a.b.c=value` override. The value is read as a TOML value (number, bool,
/// array, quoted string); anything else is taken as a bare string, so `--set
/// surface.material=steel` works without quotes.
pub fn apply_override(table: &mut toml::Table, arg: &str) -> Result<(), ConfigError> {
    let bad = |reason: &str| ConfigError::BadOverride {
        arg: arg.to_string(),
        reason: reason.to_string(),
    };
    let (key, raw) = arg
        .split_once('=')
        .ok_or_else(|| bad("expected key=value"))?;
    let key = key.trim();
    if key.is_empty() || key.split('.').any(|part| part.trim().is_empty()) {
        return Err(bad("empty key"));
    }
    let raw = raw.trim();
    let value = match toml::from_str::<toml::Table>(&format!("v = {raw}")) {
        Ok(mut t) => t
            .remove("v")
            .unwrap_or_else(|| toml::Value::String(raw.to_string())),
        Err(_) => toml::Value::String(raw.to_string()),
    };
    let parts: Vec<&str> = key.split('.').map(str::trim).collect();
    let (last, parents) = parts.split_last().ok_or_else(|| bad("empty key"))?;
    let mut node = table;
    for (i, part) in parents.iter().enumerate() {
        let entry = node
            .entry(part.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        node = match entry {
            toml::Value::Table(t) => t,
            _ => {
                return Err(bad(&format!("`{}` is not a table", parts[..=i].join("."))));
            }
        };
    }
    node.insert(last.to_string(), value);
    Ok(())
}

/// Kinematic geometry as configured: a named preset, or explicit parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, untagged)]
pub enum GeometryConfig {
    /// `geometry = "prototype"` (R 400, e 143, c 20, d 20 mm) or `"alt"` (R 300, e 100, c 15, d 25 mm).
    Preset(GeometryPreset),
    /// Explicit parameters, mm.
    Custom(H4Params),
}

/// Named parameter sets.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum GeometryPreset {
    /// The paper's prototype.
    Prototype,
    /// The second parameter set of the reference vectors.
    Alt,
}

impl GeometryConfig {
    /// The parameters.
    pub fn params(&self) -> H4Params {
        match self {
            GeometryConfig::Preset(GeometryPreset::Prototype) => H4Params::PROTOTYPE,
            GeometryConfig::Preset(GeometryPreset::Alt) => H4Params::ALT,
            GeometryConfig::Custom(p) => *p,
        }
    }
}

/// One arm: geometry, actuator stiffness and workspace limits.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ArmConfig {
    /// Geometry: `"prototype"`, `"alt"`, or a table `{ leg_length_mm, e_mm, c_mm, d_mm }`.
    pub geometry: GeometryConfig,
    /// Axial stiffness of actuators 1–4 with their drive trains, N/mm (1 to 1e6).
    pub actuator_stiffness_n_per_mm: [f64; 4],
    /// Workspace limits.
    pub workspace: WorkspaceLimits,
    /// The tool beyond the force sensor as `h4-slave identify` estimated it (the
    /// controller's gravity and inertia compensation uses it).
    pub tool: ToolModel,
    /// The arm's ratings: the limits the slave's safety monitor enforces whatever the
    /// controller, a session file, `--set` or the master asks for (those may lower them,
    /// never raise them).
    pub ratings: ArmRatings,
}

/// The arm's ratings (`[ratings]` of an arm file): what the arm, its sensor and its
/// controller are rated for. The slave's safety monitor (`h4_slave::safety`) trips the arm
/// into its safe stop when one is broken; the controller's own limits must lie within them.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ArmRatings {
    /// Largest contact force, N: the controller's `force_limit_n` may be lower, never
    /// higher; the monitor trips when the sensed force stays above the limit in effect for
    /// 2 cycles, or exceeds 1.2 × it once (1 to 1000).
    pub force_limit_n: f64,
    /// Largest speed of the tool point, mm/s: the controller's `max_speed_mm_per_s` may be
    /// lower, never higher; the monitor trips on a measured speed above
    /// `speed_trip_share` × this (0.1 to 1000).
    pub max_speed_mm_per_s: f64,
    /// The monitor trips on a measured tool speed above this share of
    /// `max_speed_mm_per_s` (1 to 5: the measured speed overshoots the commanded one).
    pub speed_trip_share: f64,
    /// How far the measured pose may leave the workspace (`workspace.*`: singular distance,
    /// rail clearance, strokes) before the monitor trips, mm (0 to 100).
    pub workspace_margin_mm: f64,
    /// How far |theta| may exceed `workspace.theta_max_rad` before the monitor trips, rad
    /// (0 to 0.5).
    pub workspace_margin_rad: f64,
    /// Largest speed of each actuator on its rail, mm/s (1 to 1e5).
    pub actuator_speed_max_mm_per_s: f64,
    /// The force/torque sensor's range on each force axis, N: a reading at or beyond it is
    /// saturated (1 to 1e5).
    pub sensor_range_n: f64,
    /// A sensor whose reading repeats bit for bit in this many new samples in a row (while
    /// the encoders' readings are fresh) is frozen (1 to 1000). A driver whose sensor
    /// samples slower than the loop hands one sample to several cycles; those repeats are
    /// not new samples (`ArmDriver::wrench_is_new_sample`). A sensor that sends no new
    /// sample at all is the driver's staleness.
    pub sensor_freeze_cycles: u32,
    /// Largest proportional gain (`controller.kp`) the controller is stable with on this
    /// arm, on every surface it is rated for (0 to 10).
    pub kp_max: f64,
    /// Largest integral gain (`controller.ki_per_s`) the controller is stable with on this
    /// arm, 1/s (0 to 1000).
    pub ki_max_per_s: f64,
}

impl Default for ArmRatings {
    /// The prototype's ratings (config/arms/prototype.toml).
    fn default() -> Self {
        ArmRatings {
            force_limit_n: 80.0,
            max_speed_mm_per_s: 100.0,
            speed_trip_share: 1.5,
            workspace_margin_mm: 5.0,
            workspace_margin_rad: 0.05,
            actuator_speed_max_mm_per_s: 1000.0,
            sensor_range_n: 145.0,
            sensor_freeze_cycles: 2,
            kp_max: 1.0,
            ki_max_per_s: 120.0,
        }
    }
}

impl ArmRatings {
    /// `self` with no rating above `ceiling`'s (a session's copy of the arm may lower the
    /// arm file's ratings, never raise them): the first rating that does, by name.
    pub fn check_within(&self, ceiling: &ArmRatings, prefix: &str) -> Result<(), ConfigError> {
        let pairs: [(&str, f64, f64); 8] = [
            ("force_limit_n", self.force_limit_n, ceiling.force_limit_n),
            (
                "max_speed_mm_per_s",
                self.max_speed_mm_per_s,
                ceiling.max_speed_mm_per_s,
            ),
            (
                "speed_trip_share",
                self.speed_trip_share,
                ceiling.speed_trip_share,
            ),
            (
                "workspace_margin_mm",
                self.workspace_margin_mm,
                ceiling.workspace_margin_mm,
            ),
            (
                "workspace_margin_rad",
                self.workspace_margin_rad,
                ceiling.workspace_margin_rad,
            ),
            (
                "actuator_speed_max_mm_per_s",
                self.actuator_speed_max_mm_per_s,
                ceiling.actuator_speed_max_mm_per_s,
            ),
            ("kp_max", self.kp_max, ceiling.kp_max),
            ("ki_max_per_s", self.ki_max_per_s, ceiling.ki_max_per_s),
        ];
        for (name, value, max) in pairs {
            if value > max {
                return Err(ConfigError::OutOfRange {
                    field: format!("{prefix}{name}"),
                    value: value.to_string(),
                    allowed: format!(
                        "at most the arm's rating {max} (a session may lower a rating, never raise it)"
                    ),
                });
            }
        }
        if self.sensor_freeze_cycles > ceiling.sensor_freeze_cycles {
            return Err(ConfigError::OutOfRange {
                field: format!("{prefix}sensor_freeze_cycles"),
                value: self.sensor_freeze_cycles.to_string(),
                allowed: format!(
                    "at most the arm's rating {} (a session may lower a rating, never raise it)",
                    ceiling.sensor_freeze_cycles
                ),
            });
        }
        Ok(())
    }
}

/// The tool beyond the force sensor, identified from free-space poses (`h4-slave identify`):
/// its weight and inertia load the sensor; the controller subtracts them.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ToolModel {
    /// Whether the fields below were identified (false: the controller compensates nothing
    /// beyond its start-up tare).
    pub identified: bool,
    /// Mass beyond the sensor, kg (0 to 100).
    pub mass_kg: f64,
    /// Its centre of mass in the sensor's frame, mm (y is not observable from `My`: 0).
    pub com_mm: [f64; 3],
    /// The sensor's bias at identification, `[Fx, Fy, Fz]` N.
    pub sensor_bias_n: [f64; 3],
    /// The sensor's bias on `My` at identification, N·mm.
    pub sensor_bias_n_mm: f64,
}

impl Default for ToolModel {
    fn default() -> Self {
        ToolModel {
            identified: false,
            mass_kg: 0.0,
            com_mm: [0.0; 3],
            sensor_bias_n: [0.0; 3],
            sensor_bias_n_mm: 0.0,
        }
    }
}

impl Default for ArmConfig {
    fn default() -> Self {
        ArmConfig {
            geometry: GeometryConfig::Preset(GeometryPreset::Prototype),
            actuator_stiffness_n_per_mm: [100.0; 4],
            workspace: WorkspaceLimits::default(),
            tool: ToolModel::default(),
            ratings: ArmRatings::default(),
        }
    }
}

impl ArmConfig {
    /// The workspace (geometry and limits).
    pub fn workspace(&self) -> Workspace {
        Workspace {
            params: self.geometry.params(),
            limits: self.workspace,
        }
    }

    /// The actuator stiffness.
    pub fn stiffness(&self) -> Result<ActuatorStiffness, KinError> {
        ActuatorStiffness::per_actuator(self.actuator_stiffness_n_per_mm)
    }
}

impl Validate for ArmConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        self.validate_at("")
    }
}

impl Section for ArmConfig {
    /// Checks the geometry, the actuator stiffness and the workspace limits, naming fields
    /// under `prefix` (e.g. `"arm."`).
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        if recording() {
            for (_, field, requirement) in H4Params::RULES {
                record_rule(&format!("{prefix}geometry.{field}"), requirement);
            }
        }
        self.geometry.params().validate().map_err(|e| match e {
            KinError::InvalidParameter {
                name,
                value,
                requirement,
            } => ConfigError::OutOfRange {
                field: format!("{prefix}geometry.{name}"),
                value: value.to_string(),
                allowed: requirement.to_string(),
            },
            other => ConfigError::OutOfRange {
                field: format!("{prefix}geometry"),
                value: String::new(),
                allowed: other.to_string(),
            },
        })?;
        for (i, k) in self.actuator_stiffness_n_per_mm.iter().enumerate() {
            check_range(
                &format!("{prefix}actuator_stiffness_n_per_mm[{i}]"),
                *k,
                1.0,
                1e6,
                "N/mm",
            )?;
        }
        let t = &self.tool;
        check_range(
            &format!("{prefix}tool.mass_kg"),
            t.mass_kg,
            0.0,
            100.0,
            "kg",
        )?;
        for i in 0..3 {
            check_range(
                &format!("{prefix}tool.com_mm[{i}]"),
                t.com_mm[i],
                -1e3,
                1e3,
                "mm",
            )?;
            check_range(
                &format!("{prefix}tool.sensor_bias_n[{i}]"),
                t.sensor_bias_n[i],
                -1e3,
                1e3,
                "N",
            )?;
        }
        check_range(
            &format!("{prefix}tool.sensor_bias_n_mm"),
            t.sensor_bias_n_mm,
            -1e5,
            1e5,
            "N·mm",
        )?;
        let w = &self.workspace;
        check_range(
            &format!("{prefix}workspace.theta_max_rad"),
            w.theta_max_rad,
            0.0,
            1.5,
            "rad",
        )?;
        check_range(
            &format!("{prefix}workspace.min_singular_distance_mm"),
            w.min_singular_distance_mm,
            0.0,
            1e3,
            "mm",
        )?;
        check_range(
            &format!("{prefix}workspace.min_rail_clearance_mm"),
            w.min_rail_clearance_mm,
            0.0,
            1e3,
            "mm",
        )?;
        for i in 0..4 {
            check_range(
                &format!("{prefix}workspace.stroke_max_mm[{i}]"),
                w.stroke_max_mm[i],
                w.stroke_min_mm[i],
                1e4,
                "mm (and >= stroke_min_mm)",
            )?;
            check_range(
                &format!("{prefix}workspace.stroke_min_mm[{i}]"),
                w.stroke_min_mm[i],
                -1e4,
                1e4,
                "mm",
            )?;
        }
        let r = &self.ratings;
        #[rustfmt::skip]
        let checks: [(&str, f64, f64, f64, &str); 10] = [
            ("force_limit_n", r.force_limit_n, 1.0, 1000.0, "N"),
            ("max_speed_mm_per_s", r.max_speed_mm_per_s, 0.1, 1000.0, "mm/s"),
            ("speed_trip_share", r.speed_trip_share, 1.0, 5.0, ""),
            ("workspace_margin_mm", r.workspace_margin_mm, 0.0, 100.0, "mm"),
            ("workspace_margin_rad", r.workspace_margin_rad, 0.0, 0.5, "rad"),
            ("actuator_speed_max_mm_per_s", r.actuator_speed_max_mm_per_s, 1.0, 1e5, "mm/s"),
            ("sensor_range_n", r.sensor_range_n, 1.0, 1e5, "N"),
            ("sensor_freeze_cycles", f64::from(r.sensor_freeze_cycles), 1.0, 1000.0, "cycles"),
            ("kp_max", r.kp_max, 0.0, 10.0, ""),
            ("ki_max_per_s", r.ki_max_per_s, 0.0, 1000.0, "1/s"),
        ];
        for (name, value, min, max, unit) in checks {
            check_range(&format!("{prefix}ratings.{name}"), value, min, max, unit)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overrides_apply_and_unknown_keys_are_named() {
        let cfg: ArmConfig = parse(
            "geometry = \"alt\"\n",
            "test",
            &["actuator_stiffness_n_per_mm=[50, 60, 70, 80]".into()],
        )
        .unwrap();
        assert_eq!(cfg.geometry.params(), H4Params::ALT);
        assert_eq!(cfg.actuator_stiffness_n_per_mm, [50.0, 60.0, 70.0, 80.0]);

        let err =
            parse::<ArmConfig>("", "test", &["workspace.theta_max_deg=3".into()]).unwrap_err();
        assert!(err.to_string().contains("theta_max_deg"), "{err}");
        let err = parse::<ArmConfig>("bogus = 1\n", "arm.toml", &[]).unwrap_err();
        assert!(err.to_string().contains("bogus"), "{err}");
        let err = parse::<ArmConfig>("", "test", &["novalue".into()]).unwrap_err();
        assert!(matches!(err, ConfigError::BadOverride { .. }));
    }

    #[test]
    fn override_errors_name_the_override_not_a_rebuilt_line() {
        let file =
            "geometry = \"alt\"\n\n\n# padding\n\nactuator_stiffness_n_per_mm = [50, 60, 70, 80]\n";
        let err = parse::<ArmConfig>(file, "arm.toml", &["geometry=\"wood\"".into()]).unwrap_err();
        let text = err.to_string();
        assert!(text.contains("geometry=\"wood\""), "{text}");
        assert!(!text.contains("line"), "{text}");
        // The second of two overrides is the one blamed.
        let err = parse::<ArmConfig>(
            file,
            "arm.toml",
            &[
                "geometry=\"prototype\"".into(),
                "actuator_stiffness_n_per_mm=\"x\"".into(),
            ],
        )
        .unwrap_err();
        assert!(text_has(&err, "actuator_stiffness_n_per_mm=\"x\""), "{err}");
        // A file that does not fit by itself keeps its own line numbers.
        let err = parse::<ArmConfig>("\n\nbogus = 1\n", "arm.toml", &["geometry=\"alt\"".into()])
            .unwrap_err();
        assert!(text_has(&err, "line 3"), "{err}");
    }

    #[test]
    fn the_recorder_sees_every_check_only_while_on() {
        // Off: nothing is kept, the checks behave as before.
        assert!(!recording());
        assert!(check_range("a", 5.0, 0.0, 10.0, "mm").is_ok());
        let (result, records) = record_ranges(|| {
            assert!(recording());
            ArmConfig::default().validate()
        });
        assert!(result.is_ok());
        assert!(!recording());
        let stiffness: Vec<&RangeRecord> = records
            .iter()
            .filter(|r| r.collapsed_field() == "actuator_stiffness_n_per_mm")
            .collect();
        assert_eq!(stiffness.len(), 4, "{records:?}");
        assert_eq!(stiffness[2].field, "actuator_stiffness_n_per_mm[2]");
        assert_eq!(stiffness[2].allowed, Allowed::Range { min: 1.0, max: 1e6 });
        assert_eq!(stiffness[2].unit, "N/mm");
        assert!(records.iter().any(|r| r.field == "geometry.e_mm"
            && matches!(&r.allowed, Allowed::Rule(t) if t.contains("|e| < R"))));
        // A failing check is recorded too; the records stop where the validation stops.
        let (result, records) = record_ranges(|| check_range("x.y[3]", -1.0, 0.0, 1.0, "s"));
        assert!(result.is_err());
        assert_eq!(records.len(), 1);
        // Nothing leaks out of the recording.
        let (_, records) = record_ranges(|| ());
        assert!(records.is_empty());
    }

    #[test]
    fn indices_collapse_to_one_field() {
        assert_eq!(
            collapse_indices("arm.stroke_max_mm[3]"),
            "arm.stroke_max_mm"
        );
        assert_eq!(
            collapse_indices("fixtures.corridor.path_mm[12][1]"),
            "fixtures.corridor.path_mm"
        );
        assert_eq!(
            collapse_indices("force.steps[0].time_s"),
            "force.steps[].time_s"
        );
        assert_eq!(
            collapse_indices("track.direction (length)"),
            "track.direction"
        );
        assert_eq!(collapse_indices("plain"), "plain");
        let r = RangeRecord {
            field: "track.direction (length)".into(),
            allowed: Allowed::Range { min: 0.0, max: 1.0 },
            unit: String::new(),
        };
        assert_eq!(r.field_note(), Some("length"));
    }

    fn text_has(err: &ConfigError, needle: &str) -> bool {
        err.to_string().contains(needle)
    }

    #[test]
    fn out_of_range_names_field_and_range() {
        let err = parse::<ArmConfig>(
            "actuator_stiffness_n_per_mm = [100, 100, 0.5, 100]\n",
            "t",
            &[],
        )
        .unwrap_err();
        let text = err.to_string();
        assert!(text.contains("actuator_stiffness_n_per_mm[2]"), "{text}");
        assert!(text.contains("1 to 1000000 N/mm"), "{text}");
        let err = parse::<ArmConfig>(
            "geometry = { leg_length_mm = 400, e_mm = 0, c_mm = 20, d_mm = 20 }\n",
            "t",
            &[],
        )
        .unwrap_err();
        assert!(err.to_string().contains("geometry.e"), "{err}");
    }
}
