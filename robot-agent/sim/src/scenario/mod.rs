//! Scenario files (`config/scenarios/*.toml`): the world a simulation runs in.
//!
//! Schema (every table rejects unknown fields; errors name the field and line):
//!
//! ```toml
//! name = "park"                      # required
//! description = "..."                # optional
//! [datum]                            # WGS-84 anchor of the map frame (ENU at this point)
//! lat_deg = 48.2; lon_deg = 16.37; h_m = 180.0
//! [extent]                           # world rectangle in the map frame, metres
//! x_min_m = -50.0; x_max_m = 50.0; y_min_m = -50.0; y_max_m = 50.0
//! [terrain]
//! resolution_m = 0.05                # height-field vertex spacing, <= 0.05
//! undulation_amplitude_m = 0.3       # gentle procedural hills (sum of sines), peak amplitude
//! undulation_wavelength_m = 30.0
//! grass_amplitude_m = 0.03           # LiDAR/depth returns on grass rise by U(0, a): blades, not ground
//! seed = 1                           # phases of the undulation
//! [[start]]  x_m, y_m, yaw_deg       # robot start poses (the first is used by default)
//! [drive]    points = [[x, y], ...], speed_mps = 0.8       # scripted evaluation drive
//! [teach]    points = [[x, y], ...], speed_mps = 0.8       # teach-and-repeat route
//! [[path]]   points, width_m                               # paved: no grass
//! [[step]]   rect = {center_m=[x,y], size_m=[sx,sy], yaw_deg} | points + width_m; height_m
//! [[platform]] rect, height_m        # flat top at terrain(centre) + height, vertical drop-offs
//! [[stairs]] x_m, y_m, yaw_deg, width_m, steps, step_height_m, step_depth_m, landing_m
//! [[ramp]]   x_m, y_m, yaw_deg, slope_deg, width_m, length_m, landing_m
//! [[hole]]   rect, depth_m
//! [[wall]]   points, thickness_m, height_m
//! [[pole]]   x_m, y_m, radius_m, height_m
//! [[tree]]   x_m, y_m, trunk_radius_m, canopy_base_m, canopy_radius_m, canopy_height_m
//! [[box]]    rect, height_m
//! [[car]]    x_m, y_m, yaw_deg  (length_m 4.5, width_m 1.8, height_m 1.5 by default)
//! [[walker]] points, speed_mps = 1.3, mode = "loop" | "ping_pong", phase_m = 0
//! [[gnss_denied]] points = [[x, y], ...], fix = "none" | "single"   # RTK off inside (ENU)
//! ```
//!
//! Ground features are baked into the height field in this order: steps, platforms, stairs,
//! ramps, holes (each kind in file order). All heights are offsets from the local procedural
//! terrain (so a curb keeps its height and a ramp meets a platform of the same height exactly on
//! undulating ground): steps and platforms set `terrain + height_m`; stairs and ramps rise along
//! `yaw_deg` from their bottom edge centre (`x_m`, `y_m`) and never lower what is already
//! there; holes lower what is there by `depth_m`.

use serde::Deserialize;

mod features;
#[cfg(test)]
mod tests;

pub use features::*;

/// Why a scenario could not be loaded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ScenarioError {
    /// The file could not be read.
    #[error("reading {path}: {source}")]
    Io {
        /// File path.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// TOML syntax or schema error (the message names the field and the line).
    #[error("{path}: {msg}")]
    Parse {
        /// File path (or `<string>`).
        path: String,
        /// What is wrong.
        msg: String,
    },
    /// A value is out of its allowed range.
    #[error("{path}: field `{field}`: {msg}")]
    Invalid {
        /// File path (or `<string>`).
        path: String,
        /// Dotted name of the field, e.g. `ramp[2].slope_deg`.
        field: String,
        /// What is wrong.
        msg: String,
    },
}

/// WGS-84 anchor of the map frame.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatumSpec {
    /// Latitude, degrees north.
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Height above the WGS-84 ellipsoid, metres.
    pub h_m: f64,
}

/// World rectangle in the map frame.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Extent {
    /// West edge, metres.
    pub x_min_m: f64,
    /// East edge, metres.
    pub x_max_m: f64,
    /// South edge, metres.
    pub y_min_m: f64,
    /// North edge, metres.
    pub y_max_m: f64,
}

/// Procedural terrain.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TerrainSpec {
    /// Height-field vertex spacing, metres (at most 0.05).
    pub resolution_m: f64,
    /// Peak amplitude of the gentle undulation, metres.
    pub undulation_amplitude_m: f64,
    /// Dominant wavelength of the undulation, metres.
    pub undulation_wavelength_m: f64,
    /// Grass: returns off unpaved ground rise by a uniform 0..this, metres.
    pub grass_amplitude_m: f64,
    /// Seed of the undulation phases.
    pub seed: u64,
}

impl Default for TerrainSpec {
    fn default() -> Self {
        Self {
            resolution_m: 0.05,
            undulation_amplitude_m: 0.2,
            undulation_wavelength_m: 30.0,
            grass_amplitude_m: 0.03,
            seed: 1,
        }
    }
}

/// An oriented rectangle.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rect {
    /// Centre (x, y), metres.
    pub center_m: [f64; 2],
    /// Size along its own x and y, metres.
    pub size_m: [f64; 2],
    /// Rotation of its x axis from the map x axis, degrees.
    #[serde(default)]
    pub yaw_deg: f64,
}

/// A robot start pose.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartSpec {
    /// x, metres.
    pub x_m: f64,
    /// y, metres.
    pub y_m: f64,
    /// Heading, degrees counter-clockwise from east.
    #[serde(default)]
    pub yaw_deg: f64,
}

/// A polyline to drive (scripted drive or teach route).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RouteSpec {
    /// Vertices (x, y), metres.
    pub points: Vec<[f64; 2]>,
    /// Cruise speed, m/s.
    #[serde(default = "default_route_speed")]
    pub speed_mps: f64,
}

fn default_route_speed() -> f64 {
    0.8
}

/// A paved path (no grass noise).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathSpec {
    /// Centre line, metres.
    pub points: Vec<[f64; 2]>,
    /// Width, metres.
    pub width_m: f64,
}

/// A whole scenario file.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Short name (`park`).
    pub name: String,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// WGS-84 anchor of the map frame.
    pub datum: DatumSpec,
    /// World rectangle.
    pub extent: Extent,
    /// Procedural terrain.
    #[serde(default)]
    pub terrain: TerrainSpec,
    /// Robot start poses; the first is the default.
    #[serde(default)]
    pub start: Vec<StartSpec>,
    /// Scripted evaluation drive.
    pub drive: Option<RouteSpec>,
    /// Teach-and-repeat route.
    pub teach: Option<RouteSpec>,
    /// Paved paths.
    #[serde(default)]
    pub path: Vec<PathSpec>,
    /// Curbs and steps.
    #[serde(default)]
    pub step: Vec<StepSpec>,
    /// Platforms.
    #[serde(default)]
    pub platform: Vec<PlatformSpec>,
    /// Stairs.
    #[serde(default)]
    pub stairs: Vec<StairsSpec>,
    /// Ramps.
    #[serde(default)]
    pub ramp: Vec<RampSpec>,
    /// Holes.
    #[serde(default)]
    pub hole: Vec<HoleSpec>,
    /// Walls.
    #[serde(default)]
    pub wall: Vec<WallSpec>,
    /// Poles.
    #[serde(default)]
    pub pole: Vec<PoleSpec>,
    /// Trees.
    #[serde(default)]
    pub tree: Vec<TreeSpec>,
    /// Boxes.
    #[serde(default, rename = "box")]
    pub boxes: Vec<BoxSpec>,
    /// Parked cars.
    #[serde(default)]
    pub car: Vec<CarSpec>,
    /// Walkers.
    #[serde(default)]
    pub walker: Vec<WalkerSpec>,
    /// Areas without RTK.
    #[serde(default)]
    pub gnss_denied: Vec<GnssDeniedSpec>,
}

impl Scenario {
    /// Parses and validates a scenario from TOML text; `path` only labels errors.
    pub fn from_toml_str(text: &str, path: &str) -> Result<Self, ScenarioError> {
        let s: Scenario = toml::from_str(text).map_err(|e| ScenarioError::Parse {
            path: path.to_string(),
            msg: e.to_string(),
        })?;
        s.validate(path)?;
        Ok(s)
    }

    /// Reads, parses and validates a scenario file.
    pub fn load(path: impl AsRef<std::path::Path>) -> Result<Self, ScenarioError> {
        let p = path.as_ref();
        let text = std::fs::read_to_string(p).map_err(|source| ScenarioError::Io {
            path: p.display().to_string(),
            source,
        })?;
        Self::from_toml_str(&text, &p.display().to_string())
    }

    /// The datum as the wire type.
    pub fn datum(&self) -> common::msg::Datum {
        common::msg::Datum {
            lat_deg: self.datum.lat_deg,
            lon_deg: self.datum.lon_deg,
            h_m: self.datum.h_m,
        }
    }

    /// The default start pose (first `[[start]]`, else the extent centre facing east).
    pub fn start_pose(&self) -> common::geom::Pose2 {
        match self.start.first() {
            Some(s) => common::geom::Pose2::new(s.x_m, s.y_m, s.yaw_deg.to_radians()),
            None => common::geom::Pose2::new(
                0.5 * (self.extent.x_min_m + self.extent.x_max_m),
                0.5 * (self.extent.y_min_m + self.extent.y_max_m),
                0.0,
            ),
        }
    }

    fn validate(&self, path: &str) -> Result<(), ScenarioError> {
        let bad = |field: String, msg: &str| ScenarioError::Invalid {
            path: path.to_string(),
            field,
            msg: msg.to_string(),
        };
        let finite_pos = |v: f64| v.is_finite() && v > 0.0;
        let d = &self.datum;
        if !(d.lat_deg.is_finite() && d.lat_deg.abs() <= 90.0) {
            return Err(bad("datum.lat_deg".into(), "must be within -90..90"));
        }
        if !(d.lon_deg.is_finite() && d.lon_deg.abs() <= 180.0) {
            return Err(bad("datum.lon_deg".into(), "must be within -180..180"));
        }
        if !d.h_m.is_finite() {
            return Err(bad("datum.h_m".into(), "must be finite"));
        }
        let e = &self.extent;
        let w = e.x_max_m - e.x_min_m;
        let h = e.y_max_m - e.y_min_m;
        if !(finite_pos(w) && finite_pos(h)) {
            return Err(bad(
                "extent".into(),
                "x_max_m/y_max_m must exceed x_min_m/y_min_m",
            ));
        }
        if w > 1000.0 || h > 1000.0 {
            return Err(bad("extent".into(), "at most 1000 m per side"));
        }
        let t = &self.terrain;
        if !(finite_pos(t.resolution_m) && t.resolution_m <= 0.05 + 1e-9 && t.resolution_m >= 0.01)
        {
            return Err(bad(
                "terrain.resolution_m".into(),
                "must be within 0.01..=0.05",
            ));
        }
        if !(t.undulation_amplitude_m.is_finite() && t.undulation_amplitude_m >= 0.0) {
            return Err(bad("terrain.undulation_amplitude_m".into(), "must be >= 0"));
        }
        if !finite_pos(t.undulation_wavelength_m) {
            return Err(bad("terrain.undulation_wavelength_m".into(), "must be > 0"));
        }
        if !(t.grass_amplitude_m.is_finite() && (0.0..=0.3).contains(&t.grass_amplitude_m)) {
            return Err(bad(
                "terrain.grass_amplitude_m".into(),
                "must be within 0..0.3",
            ));
        }
        let pts_ok = |pts: &[[f64; 2]]| pts.iter().all(|p| p[0].is_finite() && p[1].is_finite());
        let rect_ok = |r: &Rect| {
            r.center_m.iter().all(|v| v.is_finite())
                && r.size_m.iter().all(|&v| finite_pos(v))
                && r.yaw_deg.is_finite()
        };
        for (name, r) in [("drive", &self.drive), ("teach", &self.teach)] {
            if let Some(r) = r {
                if r.points.len() < 2 || !pts_ok(&r.points) {
                    return Err(bad(
                        format!("{name}.points"),
                        "needs at least 2 finite points",
                    ));
                }
                if !finite_pos(r.speed_mps) {
                    return Err(bad(format!("{name}.speed_mps"), "must be > 0"));
                }
            }
        }
        for (i, g) in self.gnss_denied.iter().enumerate() {
            if let Err(e) = common::zone::check_polygon(&g.polygon()) {
                return Err(bad(format!("gnss_denied[{i}].points"), &e.to_string()));
            }
        }
        for (i, s) in self.start.iter().enumerate() {
            if !(s.x_m.is_finite() && s.y_m.is_finite() && s.yaw_deg.is_finite()) {
                return Err(bad(format!("start[{i}]"), "must be finite"));
            }
        }
        for (i, p) in self.path.iter().enumerate() {
            if p.points.len() < 2 || !pts_ok(&p.points) || !finite_pos(p.width_m) {
                return Err(bad(
                    format!("path[{i}]"),
                    "needs >= 2 finite points and width_m > 0",
                ));
            }
        }
        for (i, s) in self.step.iter().enumerate() {
            match (&s.rect, &s.points) {
                (Some(r), None) if rect_ok(r) => {}
                (None, Some(p)) if p.len() >= 2 && pts_ok(p) && finite_pos(s.width_m) => {}
                _ => {
                    return Err(bad(
                        format!("step[{i}]"),
                        "needs exactly one of `rect` or `points` (>= 2 points)",
                    ))
                }
            }
            if !(s.height_m.is_finite() && s.height_m.abs() <= 5.0) {
                return Err(bad(format!("step[{i}].height_m"), "must be within -5..5"));
            }
        }
        for (i, p) in self.platform.iter().enumerate() {
            if !rect_ok(&p.rect) {
                return Err(bad(format!("platform[{i}].rect"), "bad rectangle"));
            }
            if !(p.height_m.is_finite() && (0.0..=10.0).contains(&p.height_m)) {
                return Err(bad(
                    format!("platform[{i}].height_m"),
                    "must be within 0..10",
                ));
            }
        }
        for (i, s) in self.stairs.iter().enumerate() {
            let ok = [s.x_m, s.y_m, s.yaw_deg, s.landing_m]
                .iter()
                .all(|v| v.is_finite())
                && finite_pos(s.width_m)
                && finite_pos(s.step_height_m)
                && finite_pos(s.step_depth_m)
                && (1..=100).contains(&s.steps)
                && s.landing_m >= 0.0;
            if !ok {
                return Err(bad(
                    format!("stairs[{i}]"),
                    "needs finite positions, positive sizes, 1..=100 steps",
                ));
            }
        }
        for (i, r) in self.ramp.iter().enumerate() {
            if !(r.slope_deg.is_finite() && r.slope_deg > 0.0 && r.slope_deg < 80.0) {
                return Err(bad(format!("ramp[{i}].slope_deg"), "must be within 0..80"));
            }
            let ok = [r.x_m, r.y_m, r.yaw_deg, r.landing_m]
                .iter()
                .all(|v| v.is_finite())
                && finite_pos(r.width_m)
                && finite_pos(r.length_m)
                && r.landing_m >= 0.0;
            if !ok {
                return Err(bad(
                    format!("ramp[{i}]"),
                    "needs finite positions and positive sizes",
                ));
            }
        }
        for (i, hl) in self.hole.iter().enumerate() {
            if !rect_ok(&hl.rect) || !finite_pos(hl.depth_m) {
                return Err(bad(
                    format!("hole[{i}]"),
                    "needs a rectangle and depth_m > 0",
                ));
            }
        }
        for (i, wl) in self.wall.iter().enumerate() {
            if wl.points.len() < 2
                || !pts_ok(&wl.points)
                || !finite_pos(wl.thickness_m)
                || !finite_pos(wl.height_m)
            {
                return Err(bad(
                    format!("wall[{i}]"),
                    "needs >= 2 finite points, thickness_m > 0, height_m > 0",
                ));
            }
        }
        for (i, p) in self.pole.iter().enumerate() {
            if !(p.x_m.is_finite()
                && p.y_m.is_finite()
                && finite_pos(p.radius_m)
                && finite_pos(p.height_m))
            {
                return Err(bad(
                    format!("pole[{i}]"),
                    "needs finite position, radius_m > 0, height_m > 0",
                ));
            }
        }
        for (i, t) in self.tree.iter().enumerate() {
            let ok = t.x_m.is_finite()
                && t.y_m.is_finite()
                && finite_pos(t.trunk_radius_m)
                && finite_pos(t.canopy_base_m)
                && finite_pos(t.canopy_radius_m)
                && finite_pos(t.canopy_height_m);
            if !ok {
                return Err(bad(
                    format!("tree[{i}]"),
                    "needs finite position and positive sizes",
                ));
            }
        }
        for (i, b) in self.boxes.iter().enumerate() {
            if !rect_ok(&b.rect) || !finite_pos(b.height_m) {
                return Err(bad(
                    format!("box[{i}]"),
                    "needs a rectangle and height_m > 0",
                ));
            }
        }
        for (i, c) in self.car.iter().enumerate() {
            let ok = c.x_m.is_finite()
                && c.y_m.is_finite()
                && c.yaw_deg.is_finite()
                && finite_pos(c.length_m)
                && finite_pos(c.width_m)
                && c.height_m.is_finite()
                && c.height_m > 1.0;
            if !ok {
                return Err(bad(
                    format!("car[{i}]"),
                    "needs finite pose, positive sizes, height_m > 1",
                ));
            }
        }
        for (i, wk) in self.walker.iter().enumerate() {
            if wk.points.len() < 2 || !pts_ok(&wk.points) {
                return Err(bad(
                    format!("walker[{i}].points"),
                    "needs at least 2 finite points",
                ));
            }
            if !(wk.speed_mps.is_finite() && (0.0..=5.0).contains(&wk.speed_mps)) {
                return Err(bad(format!("walker[{i}].speed_mps"), "must be within 0..5"));
            }
            if !(wk.phase_m.is_finite() && finite_pos(wk.radius_m) && finite_pos(wk.height_m)) {
                return Err(bad(
                    format!("walker[{i}]"),
                    "needs finite phase_m, radius_m > 0, height_m > 0",
                ));
            }
        }
        Ok(())
    }
}
