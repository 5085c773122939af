//! Obstacles added to a world at run time, and the distances the scoring measures to them.

/// Obstacles added to a world at run time (`--add-obstacles FILE`): the scenario's own tables.
#[derive(Clone, Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleFile {
    /// Parked cars.
    #[serde(default)]
    pub car: Vec<sim::scenario::CarSpec>,
    /// Boxes (debris).
    #[serde(default, rename = "box")]
    pub boxes: Vec<sim::scenario::BoxSpec>,
    /// Walls; a fallen trunk is a low wall.
    #[serde(default)]
    pub wall: Vec<sim::scenario::WallSpec>,
    /// Standing trees.
    #[serde(default)]
    pub tree: Vec<sim::scenario::TreeSpec>,
    /// Poles.
    #[serde(default)]
    pub pole: Vec<sim::scenario::PoleSpec>,
}

impl ObstacleFile {
    /// Reads an obstacle file.
    pub fn load(path: &std::path::Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)?;
        Ok(toml::from_str(&text)?)
    }

    /// The obstacles for [`sim::Simulation::add_obstacles`].
    pub fn obstacles(&self) -> Vec<sim::Obstacle> {
        let mut v: Vec<sim::Obstacle> = self.car.iter().map(|c| sim::Obstacle::Car(*c)).collect();
        v.extend(self.boxes.iter().map(|b| sim::Obstacle::Box(*b)));
        v.extend(self.wall.iter().map(|w| sim::Obstacle::Wall(w.clone())));
        v.extend(self.tree.iter().map(|t| sim::Obstacle::Tree(*t)));
        v.extend(self.pole.iter().map(|p| sim::Obstacle::Pole(*p)));
        v
    }

    /// Distance from `p` to the nearest obstacle's footprint (0 inside), metres.
    pub fn distance_to(&self, p: (f64, f64)) -> f64 {
        // Distance to a rotated rectangle given by centre, size and heading.
        let rect = |cx: f64, cy: f64, len: f64, wid: f64, yaw_deg: f64| {
            let (s, co) = yaw_deg.to_radians().sin_cos();
            let (dx, dy) = (p.0 - cx, p.1 - cy);
            let (lx, ly) = (co * dx + s * dy, -s * dx + co * dy);
            ((lx.abs() - len / 2.0).max(0.0)).hypot((ly.abs() - wid / 2.0).max(0.0))
        };
        let mut d = f64::INFINITY;
        for c in &self.car {
            d = d.min(rect(c.x_m, c.y_m, c.length_m, c.width_m, c.yaw_deg));
        }
        for b in &self.boxes {
            let r = &b.rect;
            d = d.min(rect(
                r.center_m[0],
                r.center_m[1],
                r.size_m[0],
                r.size_m[1],
                r.yaw_deg,
            ));
        }
        for w in &self.wall {
            let line: Vec<(f64, f64)> = w.points.iter().map(|q| (q[0], q[1])).collect();
            d = d.min((distance_to_polyline(&line, p) - w.thickness_m / 2.0).max(0.0));
        }
        for t in &self.tree {
            d = d.min(((p.0 - t.x_m).hypot(p.1 - t.y_m) - t.trunk_radius_m).max(0.0));
        }
        for q in &self.pole {
            d = d.min(((p.0 - q.x_m).hypot(p.1 - q.y_m) - q.radius_m).max(0.0));
        }
        d
    }
}

/// Distance from `p` to a polyline, metres.
pub fn distance_to_polyline(line: &[(f64, f64)], p: (f64, f64)) -> f64 {
    if line.len() == 1 {
        return (line[0].0 - p.0).hypot(line[0].1 - p.1);
    }
    line.windows(2)
        .map(|w| common::zone::segment_distance_m(w[0], w[1], p))
        .fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polyline_distance() {
        let l = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0)];
        assert!((distance_to_polyline(&l, (5.0, 1.0)) - 1.0).abs() < 1e-12);
        assert!((distance_to_polyline(&l, (11.0, 5.0)) - 1.0).abs() < 1e-12);
        assert!((distance_to_polyline(&l, (-3.0, -4.0)) - 5.0).abs() < 1e-12);
    }
}
