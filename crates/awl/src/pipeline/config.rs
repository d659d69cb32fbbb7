//! `FuseConfig`: every stage's parameters, with documented defaults (TOML/JSON, unknown keys refused).

use super::hand_eye::HandEyeConfig;
use serde::{Deserialize, Serialize};

use crate::cluster::DbscanParams;
use crate::error::{Error, Result};
use crate::filter::outlier::SorParams;
use crate::filter::voxel::VoxelParams;
use crate::normals::NormalParams;
use crate::registration::{IcpLevel, IcpParams};
use crate::segment::{FloorParams, PlaneParams};
use crate::smooth::MlsParams;

/// What to do with a view whose registration the rule rejects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum RejectPolicy {
    /// Leave the view out of the model (default: a wrong pose never reaches the model).
    Exclude,
    /// Merge the view at its recorded (seed) pose: the reference system's fallback.
    KeepSeed,
}

/// When a view's registration is accepted. Every check must pass; the first failing one is reported.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct AcceptanceRule {
    /// The finest ICP level must have converged. Default true.
    pub require_converged: bool,
    /// Fraction of the view's points with a model point inside the final gate, at least. Default 0.25.
    pub min_fitness: f64,
    /// Inlier point-to-plane RMSE at most, metres. Default 0.004 (about twice the sensor noise at 1 m).
    pub max_inlier_rmse_m: f64,
    /// Smallest / largest eigenvalue of the final ICP system, at least. Default 1e-3 (a flat wall
    /// alone gives ~1e-6: it cannot fix the view's slide along the wall).
    pub min_conditioning: f64,
    /// Largest accepted move of the view's centroid away from where the seed put it, metres.
    /// Default 0.075: 1.5 x the expected SLAM-level seed error (5 cm).
    pub max_correction_m: f64,
    /// Largest accepted rotation away from the seed, radians. Default 7.5 degrees (1.5 x 5 degrees).
    pub max_correction_rad: f64,
}

impl Default for AcceptanceRule {
    fn default() -> Self {
        Self {
            require_converged: true,
            min_fitness: 0.25,
            max_inlier_rmse_m: 0.004,
            min_conditioning: 1e-3,
            max_correction_m: 0.075,
            max_correction_rad: 7.5f64.to_radians(),
        }
    }
}

/// Registration of the views.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RegistrationConfig {
    /// ICP of each view against the growing model. Default: three levels from 15 mm voxels and a
    /// 10 cm gate (SLAM-level seed errors of 5 cm / 5 deg) down to 3 mm voxels and a 10 mm gate;
    /// the finest level converges when a step moves less than 0.1 mm and 1e-4 rad (the noise floor
    /// of the steps on realistic depth data), a coarser one at those scaled by its voxel over the
    /// finest level's; the 2 mm level is left to the joint refinement (BENCHMARKS.md 37).
    pub icp: IcpParams,
    /// Acceptance rule.
    pub accept: AcceptanceRule,
    /// What happens to rejected views.
    pub on_reject: RejectPolicy,
    /// Levels of the joint refinement of the anchor and the accepted views after the sequential
    /// pass (every overlapping pair at once, see `registration::joint`; it uses the ICP's kernel
    /// and its own convergence thresholds below); empty: none. Default 4 mm / 20 mm, 2 mm / 5 mm,
    /// at most 60 iterations each: the sequential pass drifts on some scans (BENCHMARKS.md 14), a
    /// box's loop of views takes 31-60 iterations to close, and a stop that slid 27 mm comes back
    /// within a 20 mm gate, not a 12 mm one (BENCHMARKS.md "Stop-mate seeds").
    pub joint_levels: Vec<IcpLevel>,
    /// Source points per view and joint level at most. Default 2500.
    pub joint_source_points: usize,
    /// A joint level converges when no view's step moves more than this, metres. Default 3e-5,
    /// under a third of the sequential ICP's: on views registered smoothed
    /// (`registration_smoothing_m`) the joint's steps keep improving the model below 0.1 mm
    /// (BENCHMARKS.md 43).
    pub joint_convergence_translation_m: f64,
    /// A joint level converges when no view's step rotates more than this either, radians. Default 3e-5.
    pub joint_convergence_rotation_rad: f64,
    /// A view seeded from a merged view of its base stop (the arm's recorded motion from it, see
    /// `pipeline::register`) is registered with every ICP level's gate at most this, metres: its
    /// seed is millimetres off, and a wider gate lets a view that sees a face and the floor lock
    /// onto the wrong surface (BENCHMARKS.md "Stop-mate seeds").
    /// Default 0.03; `false`: every view is seeded by its recorded pose.
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<f64>")]
    pub stop_seed_gate_m: Option<f64>,
}

impl Default for RegistrationConfig {
    fn default() -> Self {
        let level =
            |voxel_m, max_correspondence_m, max_iterations| IcpLevel { voxel_m, max_correspondence_m, max_iterations };
        Self {
            icp: IcpParams {
                levels: vec![level(0.015, 0.10, 30), level(0.006, 0.03, 30), level(0.003, 0.01, 30)],
                convergence_translation_m: 1e-4,
                convergence_rotation_rad: 1e-4,
                unobserved_ratio: 1e-3,
                ..IcpParams::default()
            },
            accept: AcceptanceRule::default(),
            on_reject: RejectPolicy::Exclude,
            joint_levels: vec![level(0.004, 0.02, 60), level(0.002, 0.005, 60)],
            joint_source_points: 2500,
            joint_convergence_translation_m: 3e-5,
            joint_convergence_rotation_rad: 3e-5,
            stop_seed_gate_m: Some(0.03),
        }
    }
}

impl RegistrationConfig {
    /// The ICP parameters of the joint refinement: its levels, source points and thresholds, the
    /// sequential ICP's kernel.
    #[must_use]
    pub fn joint_params(&self) -> IcpParams {
        IcpParams {
            levels: self.joint_levels.clone(),
            max_source_points: self.joint_source_points,
            convergence_translation_m: self.joint_convergence_translation_m,
            convergence_rotation_rad: self.joint_convergence_rotation_rad,
            ..self.icp.clone()
        }
    }
}

/// Isolation of the object: floor removal and clustering.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct IsolateConfig {
    /// Remove the floor (the lowest large plane perpendicular to world z). Default true.
    pub remove_floor: bool,
    /// Floor search; its `distance_m` is the band above the floor that goes with it. Default 10 mm
    /// (floor noise of the merged views reaches several mm; a thinner band leaves floor remnants that
    /// connect the object to its clutter).
    pub floor: FloorParams,
    /// Keep one DBSCAN cluster. Default true.
    pub cluster: bool,
    /// DBSCAN parameters. Default eps 10 mm, 10 points.
    pub dbscan: DbscanParams,
    /// Keep the cluster holding the model point nearest this world point (metres) instead of the
    /// largest cluster.
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<[f64; 3]>")]
    pub seed_point: Option<[f64; 3]>,
}

impl Default for IsolateConfig {
    fn default() -> Self {
        Self {
            remove_floor: true,
            floor: FloorParams::default(),
            cluster: true,
            dbscan: DbscanParams::default(),
            seed_point: None,
        }
    }
}

/// The region of interest: the object is where the cameras look.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RoiConfig {
    /// Keep only points within this distance of the point the cameras look at, metres.
    /// That point is the least-squares intersection of the views' optical axes (from the recorded
    /// poses), written in the report; `false` keeps everything. Default 1.0: the simulated 50 cm
    /// workpieces and their surroundings; raise it for bigger workpieces.
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<f64>")]
    pub radius_m: Option<f64>,
}

impl Default for RoiConfig {
    fn default() -> Self {
        Self { radius_m: Some(1.0) }
    }
}

/// How the fuse holds its views between their preparation and the merge.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum ViewMemory {
    /// Prepare every view first and hold each merged one's registration copy, for the joint
    /// refinement (default).
    #[default]
    Hold,
    /// Register each view as it is prepared and keep only its measured points once merged: the
    /// memory is the model and a view or two in flight. Each pose is final once its view is judged,
    /// so it needs `registration.joint_levels = []` (the `fast` preset).
    Stream,
}

/// Every parameter of `awl fuse`. Deserialized, a document's keys override exactly those of
/// [`FuseConfig::default`] ([`FuseConfig::with_overrides`]): each key has one default, whichever
/// table names it (a partial `[registration.icp]` keeps the fuse's ICP levels, not those of
/// `IcpParams::default`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(remote = "Self")]
#[serde(default, deny_unknown_fields)]
pub struct FuseConfig {
    /// Region of interest around the point the cameras look at.
    pub roi: RoiConfig,
    /// Per-view voxel down-sampling. Default 2 mm.
    pub view_voxel: VoxelParams,
    /// Per-view statistical outlier removal. Default 20 neighbours, 2.0 sigma.
    pub outliers: SorParams,
    /// Per-view normals, oriented toward the view's camera. Default 20 neighbours within 10 mm.
    pub normals: NormalParams,
    /// Half-width, pixels, of the image window where a depth view's points find their neighbours
    /// for outlier removal and normals. Applied before the view's voxel grid; 0: a k-d tree of the
    /// down-sampled view, as for views given as clouds. Default 3 (7 x 7 pixels, about 1 cm at
    /// 1 m; BENCHMARKS.md 20).
    pub pixel_window: usize,
    /// Use the pixels of every this-many-th row and column of a depth view only (1: all). The
    /// `pixel_window` counts pixels of that coarser grid. Default 1; the `fast` preset takes 2.
    pub pixel_step: usize,
    /// Drop points whose normal is more than this far from the ray to the camera, radians.
    /// Flying pixels at depth edges form veils seen edge-on, and grazing returns are the noisiest.
    /// `false` keeps all. Default 80 degrees.
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<f64>")]
    pub max_incidence_rad: Option<f64>,
    /// How far a depth view's points may move along their rays for registration, metres.
    /// The registration's copy of each point goes onto the plane of its pixel-window neighbours
    /// (the normals' neighbourhoods); the model is still made of the measured points. `false`
    /// registers the measured points. Views given as clouds (or cleaned with `pixel_window = 0`)
    /// are not smoothed. Default 0.005 (BENCHMARKS.md 42, 43).
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<f64>")]
    pub registration_smoothing_m: Option<f64>,
    /// Snap the normals of each view's dominant horizontal plane to the plane's fitted normal
    /// before registration; `false` to keep per-point normals. Default: RANSAC, 10 mm, 300
    /// hypotheses, within 15 degrees of world z.
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<PlaneParams>")]
    pub snap_plane: Option<PlaneParams>,
    /// Registration.
    pub registration: RegistrationConfig,
    /// How the views are held: `hold` (default) or `stream` (the `fast` preset; no joint levels,
    /// [`ViewMemory`]).
    pub view_memory: ViewMemory,
    /// Voxel of the merged model. Default 2 mm.
    pub merge_voxel: VoxelParams,
    /// Floor removal and clustering.
    pub isolate: IsolateConfig,
    /// MLS smoothing of the model; `false` to skip. Default 6 mm radius, quadratic.
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<MlsParams>")]
    pub smoothing: Option<MlsParams>,
    /// The hand-eye refined from the registered base stops (`pipeline::hand_eye`); `false` to skip.
    #[serde(with = "crate::off")]
    #[schemars(with = "Option<HandEyeConfig>")]
    pub hand_eye: Option<HandEyeConfig>,
}

impl Default for FuseConfig {
    fn default() -> Self {
        Self {
            roi: RoiConfig::default(),
            view_voxel: VoxelParams::default(),
            outliers: SorParams::default(),
            normals: NormalParams::default(),
            pixel_window: 3,
            pixel_step: 1,
            max_incidence_rad: Some(80f64.to_radians()),
            registration_smoothing_m: Some(0.005),
            snap_plane: Some(PlaneParams { iterations: 300, ..PlaneParams::default() }),
            registration: RegistrationConfig::default(),
            view_memory: ViewMemory::Hold,
            merge_voxel: VoxelParams::default(),
            isolate: IsolateConfig::default(),
            smoothing: Some(MlsParams::default()),
            hand_eye: Some(HandEyeConfig::default()),
        }
    }
}

impl Serialize for FuseConfig {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> std::result::Result<S::Ok, S::Error> {
        FuseConfig::serialize(self, serializer)
    }
}

impl<'de> Deserialize<'de> for FuseConfig {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> std::result::Result<Self, D::Error> {
        let document = serde_json::Value::deserialize(deserializer)?;
        FuseConfig::with_overrides(&document).map_err(serde::de::Error::custom)
    }
}

impl FuseConfig {
    /// The `fast` preset: a quick model, 0.4-1.6 mm RMSE on 8 simulated scans instead of the
    /// defaults' 0.4-0.7 mm (registered without the joint refinement, a box's views stay 1-4 mm
    /// apart). Every second pixel of the depth views (5 x 5 windows on that grid), 5 mm view
    /// voxels, a 4 mm model, the default's two coarse sequential ICP levels (15 mm, 6 mm), no joint
    /// refinement, and MLS onto planes (on the 4 mm model, quadrics fit the noise) within 10 mm.
    /// The default's 6 mm ball holds a median 11 points of the 4 mm model and leaves 14 % of them
    /// (fewer than 8 neighbours) as they are; 10 mm holds 32: 1.35 mm instead of 1.98 on box
    /// seed 1 (BENCHMARKS.md 46, 65).
    #[must_use]
    pub fn fast() -> Self {
        let default = Self::default();
        let mut registration = default.registration.clone();
        registration.icp.levels.truncate(2);
        registration.joint_levels.clear();
        Self {
            pixel_step: 2,
            pixel_window: 2,
            view_voxel: VoxelParams { voxel_size_m: 0.005 },
            merge_voxel: VoxelParams { voxel_size_m: 0.004 },
            registration,
            view_memory: ViewMemory::Stream,
            smoothing: default.smoothing.map(|mls| MlsParams { radius_m: 0.010, polynomial: false, ..mls }),
            ..default
        }
    }

    /// Checks the parameters no stage checks on its own (the others are checked by their stage).
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the parameter.
    pub fn check(&self) -> Result<()> {
        if self.pixel_step == 0 {
            return Err(Error::invalid("pixel_step", "must be 1 or more"));
        }
        let r = &self.registration;
        if self.view_memory == ViewMemory::Stream && !r.joint_levels.is_empty() {
            return Err(Error::invalid(
                "view_memory",
                "\"stream\" fixes each pose once its view is judged: it needs registration.joint_levels = [] (or \
                 view_memory = \"hold\")",
            ));
        }
        if let Some(v) = r.stop_seed_gate_m.filter(|v| !v.is_finite() || *v <= 0.0) {
            return Err(Error::invalid(
                "registration.stop_seed_gate_m",
                format!("{v} is not a positive number (or false)"),
            ));
        }
        for (name, value) in [
            ("registration_smoothing_m", self.registration_smoothing_m),
            ("registration.joint_convergence_translation_m", Some(r.joint_convergence_translation_m)),
            ("registration.joint_convergence_rotation_rad", Some(r.joint_convergence_rotation_rad)),
        ] {
            if let Some(v) = value.filter(|v| !v.is_finite() || *v < 0.0) {
                return Err(Error::invalid(name, format!("{v} is not a finite number >= 0")));
            }
        }
        if let Some(h) = &self.hand_eye {
            h.validate()?;
        }
        r.icp.validate().map_err(|e| match e {
            Error::Invalid { what, message } => Error::invalid(format!("registration.{what}"), message),
            other => other,
        })?;
        let document = serde_json::to_value(self).map_err(|e| Error::invalid("fuse config", e.to_string()))?;
        match too_many_iterations(&document, "") {
            Some((key, v)) => Err(Error::invalid(
                key,
                format!("{v} iterations, more than the {MAX_ITERATIONS} any stage runs at most: lower it"),
            )),
            None => Ok(()),
        }
    }

    /// The config a partial document describes (e.g. a TOML file turned into a JSON value): each
    /// key it gives replaces the same key of [`FuseConfig::default`] (an RFC 7396 merge: tables
    /// key by key, lists and values whole), so `[registration.icp]` with one key keeps the fuse's
    /// own ICP levels. `false` (or JSON's `null`) switches an optional stage off.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the unknown key or the value of the wrong type.
    pub fn with_overrides(overrides: &serde_json::Value) -> Result<Self> {
        Self::with_overrides_on(Self::default(), overrides)
    }

    /// [`FuseConfig::with_overrides`] over `base` (e.g. [`FuseConfig::fast`]) instead of the defaults.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the unknown key or the value of the wrong type.
    pub fn with_overrides_on(base: Self, overrides: &serde_json::Value) -> Result<Self> {
        let mut merged =
            serde_json::to_value(base).map_err(|e| Error::invalid("fuse config defaults", e.to_string()))?;
        // a merge patch's null deletes its key; here it switches the stage off, as `false` does
        json_patch::merge(&mut merged, &null_as_false(overrides));
        // the derived (strict) deserializer: the document is complete now
        FuseConfig::deserialize(merged).map_err(|e| Error::invalid("fuse config", e.to_string()))
    }

    /// A TOML document's keys over `base` ([`FuseConfig::with_overrides_on`]).
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the line and key of a syntax error, an unknown key, a wrong type
    /// or a number that is not finite.
    pub fn from_toml_on(base: Self, text: &str) -> Result<Self> {
        // parsed once as the config itself for messages with the line and key
        let strict = toml::Deserializer::parse(text).and_then(FuseConfig::deserialize);
        strict.map_err(|e| Error::invalid("fuse config", e.to_string()))?;
        let document: toml::Value = toml::from_str(text).map_err(|e| Error::invalid("fuse config", e.to_string()))?;
        if let Some((key, v)) = non_finite(&document, "") {
            return Err(Error::invalid(key, format!("{v} is not a finite number")));
        }
        let document = serde_json::to_value(document).map_err(|e| Error::invalid("fuse config", e.to_string()))?;
        Self::with_overrides_on(base, &document)
    }

    /// A JSON document's keys over `base` ([`FuseConfig::with_overrides_on`]).
    ///
    /// # Errors
    /// [`Error::Invalid`] naming a syntax error, an unknown key or a wrong type.
    pub fn from_json_on(base: Self, text: &str) -> Result<Self> {
        let document: serde_json::Value =
            serde_json::from_str(text).map_err(|e| Error::invalid("fuse config", e.to_string()))?;
        Self::with_overrides_on(base, &document)
    }

    /// The whole config as TOML, each key and table after a comment: the first sentence of its
    /// doc comment. Read back by [`FuseConfig::from_toml_on`], it gives this config.
    ///
    /// # Errors
    /// [`Error::Invalid`] when the config does not serialize (a number that is not finite).
    pub fn documented_toml(&self) -> Result<String> {
        let text = toml::to_string(self).map_err(|e| Error::invalid("fuse config", e.to_string()))?;
        let mut doc: toml_edit::DocumentMut =
            text.parse().map_err(|e: toml_edit::TomlError| Error::invalid("fuse config", e.to_string()))?;
        let schema = serde_json::to_value(schemars::schema_for!(FuseConfig))
            .map_err(|e| Error::invalid("fuse config schema", e.to_string()))?;
        document_table(doc.as_table_mut(), &schema, &schema);
        Ok(doc.to_string())
    }
}

/// `value` with every JSON `null` replaced by `false` (both switch an optional stage off).
fn null_as_false(value: &serde_json::Value) -> serde_json::Value {
    use serde_json::Value;
    match value {
        Value::Null => Value::Bool(false),
        Value::Object(map) => Value::Object(map.iter().map(|(k, v)| (k.clone(), null_as_false(v))).collect()),
        Value::Array(items) => Value::Array(items.iter().map(null_as_false).collect()),
        other => other.clone(),
    }
}

/// The first number of `value` that is NaN or infinite (JSON, which the merge goes through, has
/// neither), with its dotted key.
fn non_finite(value: &toml::Value, key: &str) -> Option<(String, f64)> {
    let child = |k: &str| if key.is_empty() { k.to_string() } else { format!("{key}.{k}") };
    match value {
        toml::Value::Float(v) if !v.is_finite() => Some((key.to_string(), *v)),
        toml::Value::Table(t) => t.iter().find_map(|(k, v)| non_finite(v, &child(k))),
        toml::Value::Array(a) => a.iter().enumerate().find_map(|(i, v)| non_finite(v, &format!("{key}[{i}]"))),
        _ => None,
    }
}

/// The object schema `schema` stands for: its `$ref` resolved in `root`'s `$defs`, through an
/// `anyOf` (an optional setting) to its first object member.
fn resolve<'a>(schema: &'a serde_json::Value, root: &'a serde_json::Value) -> &'a serde_json::Value {
    if let Some(name) = schema.get("$ref").and_then(|r| r.as_str()).and_then(|r| r.strip_prefix("#/$defs/")) {
        return root.get("$defs").and_then(|d| d.get(name)).map_or(schema, |s| resolve(s, root));
    }
    match schema.get("anyOf").and_then(|a| a.as_array()) {
        Some(members) => {
            members.iter().map(|m| resolve(m, root)).find(|m| m.get("properties").is_some()).unwrap_or(schema)
        }
        None => schema,
    }
}

/// A doc comment's first sentence, as one `# ` line.
fn comment_of(schema: &serde_json::Value) -> Option<String> {
    let text = schema.get("description")?.as_str()?.replace('\n', " ");
    let end = text.find(". ").map_or(text.len(), |i| i + 1);
    Some(format!("# {}\n", text[..end].trim()))
}

/// Puts each key's comment before it, recursing into tables and arrays of tables.
fn document_table(table: &mut toml_edit::Table, schema: &serde_json::Value, root: &serde_json::Value) {
    let schema = resolve(schema, root);
    let Some(properties) = schema.get("properties") else { return };
    for (mut key, item) in table.iter_mut() {
        let Some(field) = properties.get(key.get()) else { continue };
        let comment = comment_of(field).unwrap_or_default();
        match item {
            toml_edit::Item::Table(sub) => {
                sub.decor_mut().set_prefix(format!("\n{comment}"));
                document_table(sub, field, root);
            }
            toml_edit::Item::ArrayOfTables(array) => {
                let element = resolve(field, root).get("items").unwrap_or(field);
                for sub in array.iter_mut() {
                    sub.decor_mut().set_prefix(format!("\n{comment}"));
                    document_table(sub, element, root);
                }
            }
            _ => key.leaf_decor_mut().set_prefix(comment),
        }
    }
}

/// The most iterations any stage's count (RANSAC, ICP levels, joint refinement: every key with
/// `iterations` in its name) may ask for: a count from a config file is a loop
/// bound, and 1e12 would run for days.
pub const MAX_ITERATIONS: u64 = 100_000;

/// The first key (dotted, with list indices) of an iteration count over [`MAX_ITERATIONS`].
fn too_many_iterations(value: &serde_json::Value, key: &str) -> Option<(String, u64)> {
    use serde_json::Value;
    let child = |k: &str| if key.is_empty() { k.to_string() } else { format!("{key}.{k}") };
    match value {
        Value::Object(map) => map.iter().find_map(|(k, v)| {
            let counted = k.contains("iterations");
            match v.as_u64() {
                Some(n) if counted && n > MAX_ITERATIONS => Some((child(k), n)),
                _ => too_many_iterations(v, &child(k)),
            }
        }),
        Value::Array(items) => {
            items.iter().enumerate().find_map(|(i, v)| too_many_iterations(v, &format!("{key}[{i}]")))
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use serde_json::{Value, json};

    use super::*;

    /// Every leaf of `v` as (path of keys, value); lists are leaves.
    fn leaves(v: &Value, path: &mut Vec<String>, out: &mut Vec<(Vec<String>, Value)>) {
        match v {
            Value::Object(map) => {
                for (k, x) in map {
                    path.push(k.clone());
                    leaves(x, path, out);
                    path.pop();
                }
            }
            other => out.push((path.clone(), other.clone())),
        }
    }

    fn document(path: &[String], value: Value) -> Value {
        path.iter().rev().fold(value, |inner, key| json!({ key: inner }))
    }

    #[test]
    fn one_key_of_a_section_keeps_the_fuse_defaults_of_the_others() {
        let defaults = serde_json::to_value(FuseConfig::default()).expect("defaults");
        let mut all = Vec::new();
        leaves(&defaults, &mut Vec::new(), &mut all);
        assert!(all.len() > 40, "{} leaves", all.len());
        for (path, value) in all.into_iter().filter(|(_, v)| !v.is_null()) {
            let doc = document(&path, value);
            let config = FuseConfig::with_overrides(&doc).expect("parse");
            assert_eq!(config, FuseConfig::default(), "{}", path.join("."));
        }
        // the case that went wrong when a table was deserialized on its own: IcpParams::default has
        // other levels (10 / 4 / 2 mm) and 1e-5 thresholds, the fuse 15 / 6 / 3 mm and 1e-4
        let c =
            FuseConfig::with_overrides(&json!({"registration": {"icp": {"kernel_scale_ratio": 0.25}}})).expect("parse");
        assert_eq!(c.registration.icp.kernel_scale_ratio, 0.25);
        assert_eq!(c.registration.icp.levels, FuseConfig::default().registration.icp.levels);
        assert_eq!(c.registration.icp.levels.len(), 3);
        assert_eq!(c.registration.icp.convergence_translation_m, 1e-4);
        // deserialized with serde directly: the same, one default per key
        let alone: FuseConfig =
            serde_json::from_value(json!({"registration": {"icp": {"kernel_scale_ratio": 0.25}}})).expect("parse");
        assert_eq!(alone, c);
        let alone: FuseConfig = toml::from_str("[snap_plane]\ndistance_m = 0.02\n").expect("parse");
        let snap = FuseConfig::default().snap_plane.map(|p| PlaneParams { distance_m: 0.02, ..p });
        assert_eq!(alone, FuseConfig { snap_plane: snap, ..FuseConfig::default() });
        assert_ne!(snap.map(|p| p.iterations), Some(PlaneParams::default().iterations), "the fuse's own default");
    }

    #[test]
    fn the_documented_toml_reads_back_as_the_same_config_and_comments_every_key() {
        let mut off = FuseConfig::fast();
        off.smoothing = None;
        off.isolate.seed_point = Some([0.1, -0.2, 0.3]);
        off.registration.icp.max_normal_angle_rad = None;
        for config in [FuseConfig::default(), FuseConfig::fast(), off] {
            let text = config.documented_toml().expect("toml");
            // read over the other preset, so that every key must come from the text
            let back = FuseConfig::from_toml_on(FuseConfig::fast(), &text).expect("read back");
            assert!(back == config, "round trip changed the config:\n{text}");
            let back = FuseConfig::from_toml_on(FuseConfig::default(), &text).expect("read back");
            assert!(back == config, "round trip over the default changed the config");
            for (i, line) in text.lines().enumerate() {
                let keyed = !line.starts_with('#') && (line.contains(" = ") || line.starts_with('['));
                let before = if i == 0 { "" } else { text.lines().nth(i - 1).unwrap_or("") };
                assert!(!keyed || before.starts_with("# "), "line {} has no comment: {line}", i + 1);
            }
        }
        let text = FuseConfig::default().documented_toml().expect("toml");
        assert!(text.contains("# MLS smoothing of the model; `false` to skip."), "{text}");
        assert!(text.contains("\nsmoothing") || text.contains("[smoothing]"), "{text}");
        let c = FuseConfig::from_toml_on(FuseConfig::default(), "smoothing = false\n[roi]\nradius_m = false\n")
            .expect("off in TOML");
        assert_eq!((c.smoothing, c.roi.radius_m), (None, None));
        let e = FuseConfig::from_toml_on(FuseConfig::default(), "smoothing = true\n").expect_err("true");
        assert!(e.to_string().contains("false to switch it off"), "{e}");
        let e = FuseConfig::from_toml_on(FuseConfig::default(), "[view_voxel]\nvoxel_size_m = nan\n").expect_err("nan");
        assert!(e.to_string().contains("view_voxel.voxel_size_m"), "{e}");
        let c = FuseConfig::from_json_on(FuseConfig::default(), r#"{"smoothing": null, "hand_eye": false}"#)
            .expect("JSON off");
        assert_eq!((c.smoothing, c.hand_eye), (None, None));
    }

    #[test]
    fn overrides_replace_lists_and_refuse_unknown_keys() {
        let c = FuseConfig::with_overrides(&json!({
            "registration": {"joint_levels": []},
            "view_voxel": {"voxel_size_m": 0.003},
            "isolate": {"seed_point": [0.1, -0.2, 0.3]}
        }))
        .expect("parse");
        assert!(c.registration.joint_levels.is_empty());
        assert_eq!(c.view_voxel.voxel_size_m, 0.003);
        assert_eq!(c.isolate.seed_point, Some([0.1, -0.2, 0.3]));
        assert_eq!(c.registration.icp, FuseConfig::default().registration.icp);
        let e = FuseConfig::with_overrides(&json!({"registration": {"icp": {"kernal": "huber"}}}))
            .expect_err("unknown key")
            .to_string();
        assert!(e.contains("kernal"), "{e}");
        let e = FuseConfig::with_overrides(&json!({"view_voxel": {"voxel_size_m": "two"}}))
            .expect_err("wrong type")
            .to_string();
        assert!(e.contains("fuse config"), "{e}");
        for bad in [-0.001, f64::NAN, f64::INFINITY] {
            let c = FuseConfig { registration_smoothing_m: Some(bad), ..FuseConfig::default() };
            let e = c.check().expect_err("bad smoothing").to_string();
            assert!(e.contains("registration_smoothing_m"), "{e}");
            let mut c = FuseConfig::default();
            c.registration.joint_convergence_rotation_rad = bad;
            let e = c.check().expect_err("bad joint threshold").to_string();
            assert!(e.contains("joint_convergence_rotation_rad"), "{e}");
            let mut c = FuseConfig::default();
            c.registration.icp.convergence_translation_m = bad;
            let e = c.check().expect_err("bad sequential threshold").to_string();
            assert!(e.contains("registration.icp.convergence_translation_m"), "{e}");
            let mut c = FuseConfig::default();
            c.registration.stop_seed_gate_m = Some(bad);
            let e = c.check().expect_err("bad stop seed gate").to_string();
            assert!(e.contains("registration.stop_seed_gate_m"), "{e}");
            let mut c = FuseConfig::default();
            c.registration.icp.max_tangential_voxels = Some(bad);
            let e = c.check().expect_err("bad tangential gate").to_string();
            assert!(e.contains("registration.icp.max_tangential_voxels"), "{e}");
        }
        let mut c = FuseConfig::default();
        c.registration.stop_seed_gate_m = Some(0.0);
        let e = c.check().expect_err("zero stop seed gate").to_string();
        assert!(e.contains("registration.stop_seed_gate_m") && e.contains("positive"), "{e}");
        c.registration.stop_seed_gate_m = None;
        assert!(c.check().is_ok(), "stop seeds off are valid");
        c.registration.icp.kernel_scale_ratio = 0.0;
        let e = c.check().expect_err("zero kernel scale").to_string();
        assert!(e.contains("registration.icp.kernel_scale_ratio"), "{e}");
        c.registration.icp =
            IcpParams { max_tangential_voxels: None, max_normal_angle_rad: None, ..IcpParams::default() };
        assert!(c.check().is_ok(), "gates off are valid");
        assert!(FuseConfig { registration_smoothing_m: None, ..FuseConfig::default() }.check().is_ok());
        assert!(FuseConfig::default().check().is_ok());
        let e = FuseConfig { pixel_step: 0, ..FuseConfig::default() }.check().expect_err("step 0").to_string();
        assert!(e.contains("pixel_step"), "{e}");
        assert!(FuseConfig::fast().check().is_ok());
        // the fast preset streams its views; the default holds them for the joint refinement
        assert_eq!(
            (FuseConfig::fast().view_memory, FuseConfig::default().view_memory),
            (ViewMemory::Stream, ViewMemory::Hold)
        );
        // streaming is asked for, not derived, and refused with what it cannot do
        let joint = FuseConfig { view_memory: ViewMemory::Stream, ..FuseConfig::default() };
        let e = joint.check().expect_err("joint while streaming").to_string();
        assert!(e.contains("view_memory") && e.contains("joint_levels = []"), "{e}");
        let mut held = FuseConfig::fast();
        held.view_memory = ViewMemory::Hold;
        assert!(held.check().is_ok(), "no joint levels, held: valid");
        // the leave-one-out refinement rounds are gone: the key is refused, naming it
        let e = FuseConfig::from_toml_on(FuseConfig::default(), "[registration]\nrefine_rounds = 2\n")
            .expect_err("removed key")
            .to_string();
        assert!(e.contains("refine_rounds"), "{e}");
        // a partial document over the fast preset keeps the preset's other keys
        let c = FuseConfig::with_overrides_on(FuseConfig::fast(), &json!({"merge_voxel": {"voxel_size_m": 0.003}}))
            .expect("parse");
        assert_eq!(c, FuseConfig { merge_voxel: VoxelParams { voxel_size_m: 0.003 }, ..FuseConfig::fast() });
    }
}
