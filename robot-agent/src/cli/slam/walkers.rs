//! Walker scoring for `slam eval --scenario`: how much of the walkers ends up in the map, and
//! whether it stays there.

use anyhow::{bail, Context};
use nalgebra::Isometry3;
use std::path::Path;

/// Walker scoring: how much of the walkers ends up in the map, and whether it stays there.
///
/// A map point is a walker point when, traced back to the world through the scan that inserted
/// it ([`slam::Provenance`]), it lies in a walker's body during that scan's sweep (the ground
/// under the feet excluded). At a checkpoint, a walker point is "left" when it is still in the
/// map though it was seen at least [`WALKER_GRACE_S`] ago, no walker is there now, and the
/// sensor has had a clear view of the spot for the last [`WALKER_VIEW_S`]: at every look a laser
/// of the (true) sensor passed within [`WALKER_SEEN_M`] of it with nothing in between, per a ray
/// cast in the scenario's world with the recorded walkers. Points no laser could look at (behind
/// a walker walking toward the sensor, or in the gap between two lasers) are reported apart.
pub(super) struct WalkerScore {
    pub(super) world: sim::World,
    /// Recorded walker states (`walkers.txt`): per time, every walker.
    track: Vec<(f64, Vec<sim::WalkerState>)>,
    /// Map points inserted from walker returns, over the run.
    pub(super) inserted: usize,
    /// Walker points left in the map at the last checkpoint.
    pub(super) left_final: usize,
    /// The most there ever were at a checkpoint, and when.
    pub(super) left_max: (usize, f64),
    /// Walker points the sensor could not look at, at the last checkpoint (not counted as left).
    pub(super) unseen_final: usize,
    next_check_s: f64,
}

/// Age a walker point must reach before it counts as left, seconds.
pub(super) const WALKER_GRACE_S: f64 = 3.0;
/// How long the sensor must have had a clear view of a spot before a point there counts, s.
const WALKER_VIEW_S: f64 = 1.5;
/// A laser passing this close to a spot looks at it (a person there would have been hit), m.
const WALKER_SEEN_M: f64 = 0.1;
/// Margin around a walker's body (sweep motion, range noise, pose error), metres.
const WALKER_MARGIN_M: f64 = 0.1;
/// Points lower than this above a walker's ground are ground under its feet, not the walker.
const WALKER_MIN_HEIGHT_M: f64 = 0.2;
/// Checkpoint period of the leftover count, seconds.
const WALKER_CHECK_S: f64 = 10.0;
/// Sweep duration assumed for a scan's points (they are seen over [stamp, stamp + this]).
const SWEEP_S: f64 = 0.1;

fn read_walkers(dir: &Path) -> anyhow::Result<Vec<(f64, Vec<sim::WalkerState>)>> {
    let p = dir.join("walkers.txt");
    let text = std::fs::read_to_string(&p).with_context(|| {
        format!(
            "reading {} (--scenario scores the walkers recorded by `robot-agent sim --record`)",
            p.display()
        )
    })?;
    let mut track: Vec<(f64, Vec<sim::WalkerState>)> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let v: Vec<f64> = line
            .split_whitespace()
            .map(str::parse)
            .collect::<Result<_, _>>()
            .with_context(|| format!("{} line {}", p.display(), n + 1))?;
        let [t, id, x, y, z, r, h] = v[..] else {
            bail!("{} line {}: want 7 numbers", p.display(), n + 1);
        };
        let w = sim::WalkerState {
            id: id as usize,
            x_m: x,
            y_m: y,
            z_m: z,
            radius_m: r,
            height_m: h,
        };
        match track.last_mut() {
            Some((lt, ws)) if (*lt - t).abs() < 1e-9 => ws.push(w),
            _ => track.push((t, vec![w])),
        }
    }
    Ok(track)
}

impl WalkerScore {
    pub(super) fn new(scenario: &Path, dir: &Path) -> anyhow::Result<Self> {
        let sc = sim::Scenario::load(scenario)?;
        Ok(Self {
            world: sim::World::new(&sc),
            track: read_walkers(dir)?,
            inserted: 0,
            left_final: 0,
            left_max: (0, 0.0),
            unseen_final: 0,
            next_check_s: WALKER_CHECK_S,
        })
    }

    /// Walkers at `t_s`, interpolated between recorded states (same walkers in each record).
    fn walkers_at(&self, t_s: f64) -> Vec<sim::WalkerState> {
        let i = self.track.partition_point(|(t, _)| *t < t_s);
        match (
            i.checked_sub(1).and_then(|j| self.track.get(j)),
            self.track.get(i),
        ) {
            (Some((ta, a)), Some((tb, b))) if a.len() == b.len() && tb > ta => {
                let f = (t_s - ta) / (tb - ta);
                a.iter()
                    .zip(b)
                    .map(|(p, q)| sim::WalkerState {
                        x_m: p.x_m + f * (q.x_m - p.x_m),
                        y_m: p.y_m + f * (q.y_m - p.y_m),
                        z_m: p.z_m + f * (q.z_m - p.z_m),
                        ..*p
                    })
                    .collect()
            }
            (_, Some((_, b))) => b.clone(),
            (Some((_, a)), None) => a.clone(),
            (None, None) => Vec::new(),
        }
    }

    fn bodies(&self, t_s: f64, extra_m: f64) -> Vec<slam::Cylinder> {
        self.walkers_at(t_s)
            .iter()
            .map(|w| slam::Cylinder {
                x_m: w.x_m,
                y_m: w.y_m,
                z_min_m: w.z_m + WALKER_MIN_HEIGHT_M,
                z_max_m: w.z_m + w.height_m + WALKER_MARGIN_M + extra_m,
                radius_m: w.radius_m + WALKER_MARGIN_M + extra_m,
            })
            .collect()
    }

    /// Walker bodies over a scan's sweep.
    fn swept(&self, t_s: f64) -> Vec<slam::Cylinder> {
        [t_s, t_s + SWEEP_S]
            .iter()
            .flat_map(|t| self.bodies(*t, 0.0))
            .collect()
    }

    /// Counts the map points inserted by the scan stamped `t_s` that came from walkers.
    pub(super) fn count_inserted(
        &mut self,
        map: &slam::map::Map,
        prov: &slam::Provenance,
        t_s: f64,
    ) {
        let bodies = self.swept(t_s);
        let pts = &map.cloud().points;
        let stamps = map.stamps();
        self.inserted += (0..pts.len())
            .rev()
            .take_while(|i| stamps[*i] == t_s)
            .filter_map(|i| prov.world(&pts[i], t_s))
            .filter(|w| bodies.iter().any(|c| c.contains(w)))
            .count();
    }

    /// True when a laser of the sensor at `lidar` (true pose, time `t_s`) passed within
    /// [`WALKER_SEEN_M`] of `w` with nothing in between.
    fn looked_at(&self, lidar: &Isometry3<f64>, w: &nalgebra::Vector3<f64>, t_s: f64) -> bool {
        let q = lidar.inverse() * nalgebra::Point3::from(*w);
        let r = q.coords.norm();
        if r < 0.5 {
            return false;
        }
        let el = (q.z / r).asin();
        let az = q.y.atan2(q.x);
        let walkers = self.bodies(t_s, 0.0);
        sim::sensors::VLP16_ELEVATIONS_DEG.iter().any(|e| {
            let e = e.to_radians();
            if (e - el).abs() * r > WALKER_SEEN_M {
                return false;
            }
            let d = lidar.rotation
                * nalgebra::Vector3::new(e.cos() * az.cos(), e.cos() * az.sin(), e.sin());
            let o = nalgebra::Point3::from(lidar.translation.vector);
            let end = o + d * (r - 0.3);
            self.static_clear(&o, &d, r - 0.3, t_s)
                && !walkers.iter().any(|c| blocks(c, &o.coords, &end.coords))
        })
    }

    /// True when nothing static lies along `d` from `o` within `range_m` (the world's own walkers
    /// follow their scripts, not the recorded positions, and are stepped through).
    fn static_clear(
        &self,
        o: &nalgebra::Point3<f64>,
        d: &nalgebra::Vector3<f64>,
        range_m: f64,
        t_s: f64,
    ) -> bool {
        let mut start = 0.0;
        while start < range_m {
            let from = o + d * start;
            match self.world.raycast(&from, d, range_m - start, t_s) {
                None => return true,
                Some(h) if matches!(h.kind, sim::HitKind::Walker(_)) => start += h.range_m + 0.6,
                Some(_) => return false,
            }
        }
        true
    }

    /// Walker points left at `now_s`, and those the sensor could not look at; `lidar_at` is
    /// the true sensor pose at a time.
    fn left(
        &self,
        map: &slam::map::Map,
        prov: &slam::Provenance,
        now_s: f64,
        lidar_at: impl Fn(f64) -> Isometry3<f64>,
    ) -> (usize, usize) {
        let now: Vec<_> = [now_s - SWEEP_S, now_s, now_s + SWEEP_S]
            .iter()
            .flat_map(|t| self.bodies(*t, 0.2))
            .collect();
        let views: Vec<(f64, Isometry3<f64>)> = (0..=(WALKER_VIEW_S / 0.5).round() as usize)
            .map(|j| now_s - 0.5 * j as f64)
            .map(|t| (t, lidar_at(t)))
            .collect();
        // Walker bodies per insertion stamp: map points come in batches of one scan each.
        let mut at: std::collections::HashMap<u64, Vec<slam::Cylinder>> = Default::default();
        let (mut left, mut unseen) = (0, 0);
        for (p, t) in map.cloud().points.iter().zip(map.stamps()) {
            if *t > now_s - WALKER_GRACE_S {
                continue;
            }
            let Some(w) = prov.world(p, *t) else { continue };
            let then = at.entry(t.to_bits()).or_insert_with(|| self.swept(*t));
            if !then.iter().any(|c| c.contains(&w)) || now.iter().any(|c| c.contains(&w)) {
                continue;
            }
            if views.iter().all(|(t, lidar)| self.looked_at(lidar, &w, *t)) {
                left += 1;
            } else {
                unseen += 1;
            }
        }
        (left, unseen)
    }

    pub(super) fn check(
        &mut self,
        map: &slam::map::Map,
        prov: &slam::Provenance,
        now_s: f64,
        last: bool,
        lidar_at: impl Fn(f64) -> Isometry3<f64>,
    ) {
        if !last && now_s < self.next_check_s {
            return;
        }
        self.next_check_s = now_s + WALKER_CHECK_S;
        let (n, unseen) = self.left(map, prov, now_s, lidar_at);
        self.left_final = n;
        self.unseen_final = unseen;
        if n > self.left_max.0 {
            self.left_max = (n, now_s);
        }
    }
}

/// True when the body `c` stands on the line of sight from `s` to `w`.
fn blocks(c: &slam::Cylinder, s: &nalgebra::Vector3<f64>, w: &nalgebra::Vector3<f64>) -> bool {
    let d = w - s;
    let len2 = d.x * d.x + d.y * d.y;
    if len2 < 1e-9 {
        return false;
    }
    // Closest approach of the horizontal projection to the axis.
    let u = (((c.x_m - s.x) * d.x + (c.y_m - s.y) * d.y) / len2).clamp(0.0, 1.0);
    let (x, y, z) = (s.x + u * d.x, s.y + u * d.y, s.z + u * d.z);
    (x - c.x_m).hypot(y - c.y_m) <= c.radius_m
        && z >= c.z_min_m - WALKER_MIN_HEIGHT_M
        && z <= c.z_max_m
}
