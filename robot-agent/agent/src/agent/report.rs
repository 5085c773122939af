//! What the agent tells the world: the pose estimate, the status, the path, the changed tiles,
//! and read access to its parts (split from `agent.rs`, no behaviour of its own).

use super::Agent;
use crate::driver::Driver;
use crate::localiser::{FrameKind, Localiser};
use crate::mission::{MissionMachine, Mode, Phase};
use crate::status::{AgentStatus, PoseEstimate, RouteProgress};
use crate::terrain::TerrainMap;
use common::grid::{Lattice, Tile, TileIndex};
use common::msg::Datum;

impl Agent {
    // ---- what the agent tells the world ----

    /// The pose estimate for now.
    pub fn pose(&self, t_s: f64) -> Option<PoseEstimate> {
        let p = self.localiser.pose_now()?;
        let odom = self.localiser.last_odom();
        Some(PoseEstimate {
            t_s,
            pose: p,
            v_mps: odom.map_or(0.0, |o| o.v_mps),
            omega_rps: odom.map_or(0.0, |o| o.omega_rps),
            fix: self.localiser.fix_kind(t_s),
            lla: self.localiser.lla_of(&p),
        })
    }

    /// The status for now.
    pub fn status(&self, t_s: f64) -> AgentStatus {
        let pose = self
            .localiser
            .pose_now()
            .map(|p| p.planar)
            .unwrap_or_default();
        let (mut phase, mut reason) = self.mission.phase(self.driver.safety().stop);
        // An operator's drive is in force only while the deadman is held and fresh; after the
        // keys are released the robot stands, and must not read "Driving".
        let driving = self
            .mission
            .teleop()
            .is_some_and(|d| d.deadman && t_s - d.t_s <= self.cfg.deadman_s);
        if matches!(self.mission.mode(), Mode::Teleop | Mode::Teach) && !driving {
            phase = Phase::Idle;
            reason = "teleop: standing (no drive held)".into();
        }
        let here = (pose.x_m, pose.y_m);
        let lead = 0.5 * self.cfg.profile.length_m;
        let zone = self.zones.note(
            here,
            self.keep_out_margin_m,
            self.zones.speed_cap(here, lead),
        );
        let route = self.mission.repeat().map(|r| {
            let (k, n, left) = r.follower.progress(&pose);
            RouteProgress {
                route_id: r.route_id.clone(),
                name: r.name.clone(),
                waypoint: k,
                waypoints: n,
                distance_left_m: left,
                detours: r.follower.detours.len(),
            }
        });
        let nav = self.mission.nav();
        // A goal that failed or was reached stays in the status (where, which id), so the
        // operator sees where the robot gave up and a mission runner which goal ended.
        let goal = nav.goal().or(match phase {
            Phase::NoPath | Phase::Reached if self.mission.mode() != Mode::Repeat => {
                nav.last_goal()
            }
            _ => None,
        });
        AgentStatus {
            t_s,
            mode: self.mission.mode(),
            driving,
            phase,
            reason,
            goal_m: goal.map(|g| g.goal_map),
            goal_id: goal.map_or(0, |g| g.id),
            fix: self.localiser.fix_kind(t_s),
            gnss_lost: self.localiser.gnss_lost(t_s),
            slam: self.localiser.health().clone(),
            speed_limit_mps: self.driver.speed_limit_mps(),
            speed_max_mps: self.cfg.control.v_max_mps,
            zones_version: self.zones.version,
            zone,
            recording: self.mission.recording(),
            route,
            last_error: self.last_error.clone(),
            commands_refused: self.commands_refused,
        }
    }

    /// The path being followed (goal or route), map frame.
    pub fn current_path(&self) -> Vec<(f64, f64)> {
        match (self.mission.repeat(), self.localiser.pose_now()) {
            (Some(r), Some(p)) => r.follower.path_ahead(&p.planar),
            _ => self.mission.nav().path().to_vec(),
        }
    }

    /// The tiles whose cells changed since the last call, sorted (what is published when is
    /// the publisher's policy).
    pub fn take_changed_tiles(&mut self) -> Vec<TileIndex> {
        std::mem::take(&mut self.changed_tiles)
            .into_iter()
            .collect()
    }

    /// The current cells of one tile.
    pub fn tile_cells(&self, index: TileIndex) -> Option<&[common::grid::Cell]> {
        self.terrain.tile_cells(index)
    }

    /// Every current tile.
    pub fn all_tiles(&self) -> Vec<Tile> {
        self.terrain.tiles()
    }

    /// The map frame's anchoring, once the first sweep has arrived.
    pub fn map_frame(&self) -> Option<(FrameKind, Option<Datum>)> {
        self.localiser.frame()
    }

    /// The lattice tiles live on.
    pub fn lattice(&self) -> Lattice {
        self.terrain.lattice()
    }

    /// The localiser (evaluation, pose between sweeps).
    pub fn localiser(&self) -> &Localiser {
        &self.localiser
    }

    /// The terrain map (evaluation, rendering).
    pub fn terrain(&self) -> &TerrainMap {
        &self.terrain
    }

    /// The mapper (evaluation, rendering).
    pub fn mapper(&self) -> &mapping::Mapper {
        self.terrain.mapper()
    }

    /// The mapper, taking the agent apart (evaluation's last step).
    pub fn into_mapper(self) -> mapping::Mapper {
        self.terrain.into_mapper()
    }

    /// The mission state machine (evaluation).
    pub fn mission(&self) -> &MissionMachine {
        &self.mission
    }

    /// The driver (safety verdict, last command).
    pub fn driver(&self) -> &Driver {
        &self.driver
    }

    /// The mode the agent is in.
    pub fn mode(&self) -> Mode {
        self.mission.mode()
    }

    /// The last error or refusal, for operators and logs.
    pub fn last_error(&self) -> Option<&str> {
        self.last_error.as_deref()
    }

    /// Sweeps left out of the map because their pose was not trusted (a SLAM glitch).
    pub fn scans_not_mapped(&self) -> u64 {
        self.scans_not_mapped
    }

    /// Sweeps localised.
    pub fn scans(&self) -> u32 {
        self.localiser.scans()
    }
}
