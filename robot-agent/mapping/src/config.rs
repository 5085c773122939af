//! Mapper parameters (docs/algorithms.md §4.14). Defaults are the source's Husky A200 values;
//! `config/mapper.toml` fills them, `config/mapper-car.toml` is the KITTI car profile.

use serde::{Deserialize, Serialize};

/// One pair of the isolated-point filter: drop a point whose mean distance to its `knn_k` nearest
/// neighbours exceeds `dist_k_m`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IsolatedPair {
    /// Number of neighbours.
    pub knn_k: usize,
    /// Largest allowed mean distance to them, metres.
    pub dist_k_m: f64,
}

/// All mapper parameters (the source's names, units in the names; docs/algorithms.md §4.14).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    // --- Lattice and planning window ---
    /// Cell edge `grid_size`, metres (the lattice `l`).
    pub grid_size_m: f64,
    /// Cells per side of the robot-centred planning window (`num_of_grid_cells`).
    pub num_of_grid_cells: u32,
    /// Cells per tile side on the fixed map-frame lattice.
    pub tile_cells: u16,

    // --- 1. Height filter ---
    /// Robot height `h_r`, metres: what the robot must pass under.
    pub h_r_m: f64,
    /// Largest climb angle `phi_max`, degrees.
    pub phi_max_deg: f64,
    /// Points farther than this from the robot (horizontally) are ignored, metres.
    pub max_range_m: f64,

    // --- 2. Isolated-point filter ---
    /// The `(knn_k, dist_k)` pairs; a point failing any pair is dropped.
    pub isolated_pairs: Vec<IsolatedPair>,

    // --- 3. Binning ---
    /// Radius of the cells whose lowest point sets a cell's ceiling `h_max2`, cells.
    pub ceiling_radius_cells: u32,

    // --- 4. Classification ---
    /// Cells farther than this from the robot are not (re)classified, metres.
    pub processing_distance_m: f64,
    /// Beyond `processing_distance_m` and up to this distance, a cell judged traversable from
    /// within it on its own close evidence becomes an obstacle when the profile step test fires
    /// on newer, distant evidence around it (never the reverse); at or below
    /// `processing_distance_m` (0, say) there is no such band and the rule is off, metres.
    pub far_step_distance_m: f64,
    /// Minimum points in the 3x3 neighbourhood of a cell before it is classified
    /// (`points_around_threshold`); fewer leaves it undecided.
    pub points_around_threshold: u32,
    /// Minimum points in the cell itself for it to count as observed.
    pub min_points_per_cell: u32,
    /// Largest height variance of a traversable cell (`max_variance`), m^2.
    pub max_variance_m2: f64,
    /// Largest slope `alpha`, degrees; gives the 8-neighbour step limit `h_max = l tan(alpha)`.
    pub alpha_deg: f64,
    /// Beyond the source: the limit of the profile step test (the jump from a cell to a neighbour
    /// less the slopes on either side) and of the face test across a cell, which find 5-10 cm
    /// curbs on slopes (docs/algorithms.md §4.6), metres.
    pub max_step_m: f64,
    /// Beyond the source: in the profile step test a cell whose height spread lies between
    /// `grass_sd_min_m` (the sensor's noise on a hard surface) and `grass_sd_max_m` (below a
    /// face's or a slope's spread) is taken as grass over its ground, at its lowest return:
    /// grass returns stand U(0, a) above the ground and would hide a third of a 10 cm step.
    /// The slopes beside the jump still come from the means. With 0.016 park's obstacle recall
    /// goes from 0.986 to 1.000 and its 5 cm band stays traversable (README).
    /// `grass_sd_max_m <= grass_sd_min_m` turns this off (`mapper-car.toml`: a car LiDAR's own
    /// spread on asphalt is grass-like), metres.
    pub grass_sd_min_m: f64,
    /// See `grass_sd_min_m`, metres.
    pub grass_sd_max_m: f64,
    /// Beyond the source: points higher than this above the cell's lowest evidence, when they are
    /// a minority seen in a single scan, are treated as stray dynamic points and dropped, metres.
    pub stray_height_m: f64,

    // --- Free space (beyond the source) ---
    /// A beam counts as crossing a cell's headroom from this height above the ground up to
    /// `h_r`; lower beams graze the ground and prove nothing, metres.
    pub clear_low_m: f64,
    /// Beams of one sweep that must cross a cell below its stored points (with none of the
    /// sweep's own returns up there) before those points are taken as gone.
    pub clear_min_beams: u16,
    /// Stored points must stand this much above the lowest crossing beam to be contradicted,
    /// and the sweep's own returns this close to it keep the cell occupied, metres.
    pub clear_margin_m: f64,
    /// Every n-th return is marched for free space (the azimuth step of a VLP-16 is 0.2 deg,
    /// far finer than a cell at the ranges that matter).
    pub beam_stride: usize,
    /// Free space is marched out to this distance from the sensor, metres. Beyond
    /// `processing_distance_m` only a grazing ring or two still crosses a cell's headroom, so one
    /// crossing beam per sweep is enough there; a cell it wipes there is judged again from its
    /// new evidence (only towards traversable or unknown): a person who walked behind the robot
    /// left a trail that the robot sees only from afar once it has turned. At or below
    /// `processing_distance_m` marching stops at `processing_distance_m`.
    pub clear_reach_m: f64,

    /// Points of a sweep are ignored for a cell that was seen from less than
    /// 1/`far_evidence_factor` of today's distance (minus 1 m) within the last
    /// `evidence_stale_s`, unless they stand higher (or lie lower) than anything the cell and its
    /// 8 neighbours held by `max_step_m`: a far glimpse is not allowed to replace a close look, only to show what is
    /// new (what went is shown by free space).
    pub far_evidence_factor: f64,
    /// After this long without accepted evidence a cell takes whatever comes, seconds.
    pub evidence_stale_s: f64,
    /// A cell with no evidence from within the processing distance for this long belongs to an
    /// earlier visit: a sweep that sees enough such ground within the processing distance
    /// measures the old map's height offset from the current frame and moves the earlier
    /// visit's evidence within reach by it, seconds (0: off).
    pub revisit_gap_s: f64,
    /// Fewest such ground cells in one sweep for the offset to be measured.
    pub revisit_min_cells: usize,

    // --- Evidence ---
    /// Length of one evidence epoch, seconds. A cell's statistics are those of its newest two
    /// epochs with observations, so newer evidence replaces what walkers left behind.
    pub evidence_epoch_s: f64,

    // --- 5. Inflation and costs ---
    /// Non-traversable cells are inflated by this distance (`obstacle_distance`), metres.
    pub obstacle_distance_m: f64,
    /// Cost penalties decay to zero at this distance from an obstacle, metres.
    pub cost_distance_m: f64,
    /// Cost of the first cell beyond the inflation band (0..=254).
    pub cost_max: u8,
    /// Decay length of the cost penalty, metres.
    pub cost_decay_m: f64,
    /// Also inflate undecided cells (observed, too few points around) as the source does.
    pub inflate_undecided: bool,

    // --- 6. Proprioception and negative obstacles ---
    /// Robot footprint length (along x of base_link), metres.
    pub footprint_length_m: f64,
    /// Robot footprint width, metres.
    pub footprint_width_m: f64,
    /// LiDAR height above the ground under the robot, metres.
    pub sensor_height_m: f64,
    /// Lowest beam elevation of the LiDAR, degrees (negative = down); with the sensor height it
    /// gives the blind radius around the robot where missing returns mean nothing.
    pub lowest_beam_deg: f64,
    /// Unknown cells within this distance that the geometry says the sensor should have seen are
    /// checked for drop-offs, metres.
    pub negative_obstacle_distance_m: f64,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            grid_size_m: 0.2,
            num_of_grid_cells: 300,
            tile_cells: 64,
            h_r_m: 1.0,
            phi_max_deg: 23.0,
            max_range_m: 30.0,
            isolated_pairs: vec![
                IsolatedPair {
                    knn_k: 2,
                    dist_k_m: 0.08,
                },
                IsolatedPair {
                    knn_k: 3,
                    dist_k_m: 0.12,
                },
                IsolatedPair {
                    knn_k: 6,
                    dist_k_m: 0.19,
                },
            ],
            ceiling_radius_cells: 3,
            processing_distance_m: 12.0,
            far_step_distance_m: 20.0,
            points_around_threshold: 12,
            min_points_per_cell: 2,
            max_variance_m2: 0.0017,
            alpha_deg: 23.0,
            max_step_m: 0.075,
            grass_sd_min_m: 0.008,
            grass_sd_max_m: 0.016,
            stray_height_m: 0.15,
            clear_low_m: 0.3,
            clear_min_beams: 2,
            clear_margin_m: 0.05,
            beam_stride: 4,
            clear_reach_m: 25.0,
            far_evidence_factor: 2.0,
            evidence_stale_s: 3600.0,
            revisit_gap_s: 30.0,
            revisit_min_cells: 40,
            evidence_epoch_s: 1.0,
            obstacle_distance_m: 0.4,
            cost_distance_m: 1.2,
            cost_max: 120,
            cost_decay_m: 0.3,
            inflate_undecided: true,
            footprint_length_m: 1.0,
            footprint_width_m: 0.7,
            sensor_height_m: 0.7,
            lowest_beam_deg: -15.0,
            negative_obstacle_distance_m: 6.0,
        }
    }
}

/// A parameter that makes no sense.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// A parameter is out of its range.
    #[error("mapper config: {0}")]
    OutOfRange(&'static str),
}

impl Config {
    /// Checks ranges so the mapper never divides by zero or allocates absurd windows.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |ok: bool, m: &'static str| {
            if ok {
                Ok(())
            } else {
                Err(ConfigError::OutOfRange(m))
            }
        };
        bad(
            self.grid_size_m > 0.01 && self.grid_size_m <= 5.0,
            "grid_size_m must be in (0.01, 5]",
        )?;
        bad(
            (8..=4000).contains(&self.num_of_grid_cells),
            "num_of_grid_cells must be in 8..=4000",
        )?;
        bad(
            (4..=512).contains(&self.tile_cells),
            "tile_cells must be in 4..=512",
        )?;
        bad(self.h_r_m > 0.0, "h_r_m must be positive")?;
        bad(
            (0.0..89.0).contains(&self.phi_max_deg),
            "phi_max_deg must be in [0, 89)",
        )?;
        bad(
            (0.0..89.0).contains(&self.alpha_deg),
            "alpha_deg must be in [0, 89)",
        )?;
        bad(self.max_range_m > 0.0, "max_range_m must be positive")?;
        bad(
            self.processing_distance_m > 0.0,
            "processing_distance_m must be positive",
        )?;
        bad(
            self.far_step_distance_m >= 0.0,
            "far_step_distance_m must be 0 or more (up to processing_distance_m: off)",
        )?;
        bad(
            self.max_variance_m2 > 0.0,
            "max_variance_m2 must be positive",
        )?;
        bad(self.max_step_m > 0.0, "max_step_m must be positive")?;
        bad(
            self.grass_sd_min_m >= 0.0 && self.grass_sd_max_m.is_finite(),
            "grass_sd_min_m must be >= 0 and grass_sd_max_m finite",
        )?;
        bad(
            self.evidence_epoch_s > 0.0,
            "evidence_epoch_s must be positive",
        )?;
        bad(
            self.revisit_gap_s >= 0.0 && self.revisit_gap_s.is_finite(),
            "revisit_gap_s must be 0 (off) or more",
        )?;
        bad(
            self.obstacle_distance_m >= 0.0,
            "obstacle_distance_m must be >= 0",
        )?;
        bad(
            self.cost_distance_m >= self.obstacle_distance_m,
            "cost_distance_m must be >= obstacle_distance_m",
        )?;
        bad(self.cost_decay_m > 0.0, "cost_decay_m must be positive")?;
        bad(
            self.ceiling_radius_cells <= 16,
            "ceiling_radius_cells must be <= 16",
        )?;
        bad(
            self.isolated_pairs
                .iter()
                .all(|p| (1..=32).contains(&p.knn_k) && p.dist_k_m > 0.0),
            "isolated_pairs: knn_k in 1..=32, dist_k_m > 0",
        )?;
        bad(
            self.footprint_length_m >= 0.0 && self.footprint_width_m >= 0.0,
            "footprint must be >= 0",
        )?;
        bad(
            self.lowest_beam_deg < 0.0 && self.lowest_beam_deg > -89.0,
            "lowest_beam_deg must be in (-89, 0)",
        )?;
        bad(
            self.clear_low_m >= 0.0 && self.clear_low_m < self.h_r_m,
            "clear_low_m must be in [0, h_r_m)",
        )?;
        bad(self.clear_margin_m >= 0.0, "clear_margin_m must be >= 0")?;
        bad(
            (1..=64).contains(&self.beam_stride),
            "beam_stride must be in 1..=64",
        )?;
        bad(
            self.clear_reach_m.is_finite() && self.clear_reach_m >= 0.0,
            "clear_reach_m must be finite and >= 0",
        )?;
        Ok(())
    }

    /// The 8-neighbour step limit `h_max = l tan(alpha)`, metres.
    pub fn h_max_m(&self) -> f64 {
        self.grid_size_m * self.alpha_deg.to_radians().tan()
    }

    /// The lattice the mapper's cells live on.
    pub fn lattice(&self) -> common::grid::Lattice {
        common::grid::Lattice {
            cell_size_m: self.grid_size_m as f32,
            tile_cells: self.tile_cells,
        }
    }

    /// Radius around the robot inside which the LiDAR cannot see flat ground, metres.
    pub fn blind_radius_m(&self) -> f64 {
        self.sensor_height_m / (-self.lowest_beam_deg).to_radians().tan()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_husky_profile_and_valid() {
        let c = Config::default();
        c.validate().unwrap();
        // h_max = 0.2 tan(23 deg) = 0.085 m: a 10 cm step exceeds it, a 5 cm step does not.
        assert!((c.h_max_m() - 0.0849).abs() < 1e-3);
        assert_eq!(c.isolated_pairs.len(), 3);
    }

    #[test]
    fn bad_values_are_refused() {
        let c = Config {
            grid_size_m: 0.0,
            ..Config::default()
        };
        assert!(c.validate().is_err());
        let c = Config {
            isolated_pairs: vec![IsolatedPair {
                knn_k: 0,
                dist_k_m: 0.1,
            }],
            ..Config::default()
        };
        assert!(c.validate().is_err());
    }

    #[test]
    fn every_shipped_mapper_file_loads_and_validates() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        let mut n = 0;
        for e in std::fs::read_dir(&dir).unwrap() {
            let path = e.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().to_string();
            if !(name.starts_with("mapper") && name.ends_with(".toml")) {
                continue;
            }
            let c: Config = toml::from_str(&std::fs::read_to_string(&path).unwrap())
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            c.validate().unwrap_or_else(|e| panic!("{name}: {e}"));
            n += 1;
        }
        assert!(n >= 2, "found {n} mapper files in {}", dir.display());
    }

    #[test]
    fn toml_fills_and_unknown_keys_fail() {
        let c: Config = toml::from_str("h_r_m = 1.5\n").unwrap();
        assert_eq!(c.h_r_m, 1.5);
        assert_eq!(c.phi_max_deg, 23.0);
        assert!(toml::from_str::<Config>("h_r = 1.5\n").is_err());
    }
}
