//! The digest of a run: SHA-256 over what the agent decided, so that a replay proves it reproduced
//! the run. Poses and base commands are taken at every control period, plans whenever the path
//! changes (with their time), and the map at the end ([`common::grid::map_digest`]): every bit of
//! every f64, so that equal digests mean the same run.

use agent::{Agent, Cmd};
use serde::{Deserialize, Serialize};
use sha2::{Digest as _, Sha256};

/// The four digests (hex) and what they cover.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Digest {
    /// The agent's pose at every control period.
    pub poses: String,
    /// Every path the agent planned, when it changed.
    pub plans: String,
    /// The final map.
    pub tiles: String,
    /// The base command of every control period.
    pub commands: String,
    /// Control periods covered.
    pub controls: u64,
    /// Plans covered.
    pub plan_changes: u64,
}

/// See the module docs.
pub struct RunDigest {
    poses: Sha256,
    plans: Sha256,
    commands: Sha256,
    last_path: Vec<(f64, f64)>,
    controls: u64,
    plan_changes: u64,
}

impl Default for RunDigest {
    fn default() -> Self {
        Self {
            poses: Sha256::new(),
            plans: Sha256::new(),
            commands: Sha256::new(),
            last_path: Vec::new(),
            controls: 0,
            plan_changes: 0,
        }
    }
}

fn put(h: &mut Sha256, xs: &[f64]) {
    for x in xs {
        h.update(x.to_bits().to_le_bytes());
    }
}

impl RunDigest {
    /// One control period at `t_s` that sent `cmd`.
    pub fn control(&mut self, t_s: f64, agent: &Agent, cmd: Cmd) {
        self.controls += 1;
        put(&mut self.commands, &[t_s, cmd.v_mps, cmd.omega_rps]);
        if let Some(p) = agent.pose(t_s) {
            let t = p.pose.iso.translation.vector;
            let q = p.pose.iso.rotation;
            put(&mut self.poses, &[t_s, t.x, t.y, t.z, q.i, q.j, q.k, q.w]);
        }
        let path = agent.current_path();
        if path != self.last_path {
            self.plan_changes += 1;
            put(&mut self.plans, &[t_s, path.len() as f64]);
            for p in &path {
                put(&mut self.plans, &[p.0, p.1]);
            }
            self.last_path = path;
        }
    }

    /// The digests, with the map of `agent` at the end.
    pub fn finish(self, agent: &Agent) -> Digest {
        let hex = |h: Sha256| {
            h.finalize()
                .iter()
                .map(|b| format!("{b:02x}"))
                .collect::<String>()
        };
        Digest {
            poses: hex(self.poses),
            plans: hex(self.plans),
            commands: hex(self.commands),
            tiles: common::grid::map_digest(&agent.all_tiles()),
            controls: self.controls,
            plan_changes: self.plan_changes,
        }
    }
}
