//! The Orpheus navigation-computer gateway's logic (methods.md §7), without the socket.
//!
//! An existing navigation computer (NC) follows waypoints by itself. It sends its route list
//! (`$NALST` ... `$NALST,END`) and reports reached waypoints (`$NAWPT`); terranav keeps a copy of
//! the list and, when a detour is needed, edits it with removals (`$CAREM`) and insertions
//! (`$CAINS`) so the NC drives terranav's detour. Ids are positions in the NC's list: an insertion
//! at `id` shifts the rest, so removals are sent from the highest id down and insertions from the
//! lowest up, which keeps every id valid while the NC applies them one by one.
//!
//! When terranav owns the route (a route it taught and repeats, `robot-agent run
//! --nav-computer`), it sends the list itself in the same `$NALST` form ([`OrpheusGateway::send_list`])
//! and keeps it in step with the mission by edits ([`sync`]); [`follower`] is a navigation
//! computer that drives a simulated robot along such a list.

pub mod follower;
pub mod sync;

use common::geo::orpheus::{format_orpheus, parse_orpheus, OrpheusMessage, RoutePoint};

/// Why a line from the NC was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum GatewayError {
    /// Bad framing, checksum or fields.
    #[error("malformed sentence: {0}")]
    Malformed(String),
    /// A message the NC must not send (a `CA*` edit).
    #[error("unexpected {0} from the navigation computer")]
    Unexpected(&'static str),
    /// A route point out of sequence.
    #[error("route point id {got} out of sequence (expected {want})")]
    OutOfSequence {
        /// Id received.
        got: u32,
        /// Id expected.
        want: u32,
    },
    /// `$NAWPT` for an id not in the route.
    #[error("waypoint id {0} is not in the route ({1} points)")]
    UnknownId(u32, usize),
}

/// What a line from the NC changed.
#[derive(Clone, Debug, PartialEq)]
pub enum GatewayEvent {
    /// One more route point arrived.
    PointReceived(u32),
    /// The route list is complete.
    RouteComplete(usize),
    /// The NC reached this waypoint.
    Reached(u32),
}

/// Route copy and edit generation.
#[derive(Clone, Debug, Default)]
pub struct OrpheusGateway {
    route: Vec<RoutePoint>,
    incoming: Vec<RoutePoint>,
    complete: bool,
    reached: Option<u32>,
    /// Lines rejected since start.
    pub rejected: u32,
    /// Why the last line was rejected.
    pub last_error: Option<String>,
}

impl OrpheusGateway {
    /// An empty gateway.
    pub fn new() -> Self {
        Self::default()
    }

    /// The NC's current route (after every edit sent), ids = positions.
    pub fn route(&self) -> &[RoutePoint] {
        &self.route
    }

    /// True once a complete list has arrived.
    pub fn has_route(&self) -> bool {
        self.complete
    }

    /// The last waypoint the NC reported reached.
    pub fn reached(&self) -> Option<u32> {
        self.reached
    }

    /// Handles one line from the NC; rejected lines are counted with their reason.
    pub fn on_line(&mut self, line: &str) -> Result<GatewayEvent, GatewayError> {
        let r = self.handle(line);
        if let Err(e) = &r {
            self.rejected += 1;
            self.last_error = Some(e.to_string());
        }
        r
    }

    fn handle(&mut self, line: &str) -> Result<GatewayEvent, GatewayError> {
        let msg = parse_orpheus(line).map_err(|e| GatewayError::Malformed(e.to_string()))?;
        match msg {
            OrpheusMessage::RoutePoint(p) => {
                let want = self.incoming.len() as u32;
                // A new list starts at id 0 and replaces whatever was being received.
                if p.id == 0 {
                    self.incoming.clear();
                } else if p.id != want {
                    return Err(GatewayError::OutOfSequence { got: p.id, want });
                }
                self.incoming.push(p);
                Ok(GatewayEvent::PointReceived(p.id))
            }
            OrpheusMessage::RouteEnd => {
                self.route = std::mem::take(&mut self.incoming);
                self.complete = true;
                self.reached = None;
                Ok(GatewayEvent::RouteComplete(self.route.len()))
            }
            OrpheusMessage::WaypointReached(id) => {
                if id as usize >= self.route.len() {
                    return Err(GatewayError::UnknownId(id, self.route.len()));
                }
                self.reached = Some(id);
                Ok(GatewayEvent::Reached(id))
            }
            OrpheusMessage::Remove(_) | OrpheusMessage::RemoveEnd => {
                Err(GatewayError::Unexpected("$CAREM"))
            }
            OrpheusMessage::Insert(_) | OrpheusMessage::InsertEnd => {
                Err(GatewayError::Unexpected("$CAINS"))
            }
            OrpheusMessage::SpeedLimit(_) => Err(GatewayError::Unexpected("$CASPD")),
            _ => Err(GatewayError::Unexpected("message")),
        }
    }

    /// Replaces route points `from..to` (ids, end exclusive) by `detour` (lat, lon degrees) and
    /// returns the sentences that make the NC do the same. Position errors of inserted points are
    /// `err_m`.
    pub fn splice(
        &mut self,
        from: u32,
        to: u32,
        detour: &[(f64, f64)],
        err_m: f64,
    ) -> Result<Vec<String>, GatewayError> {
        let n = self.route.len();
        if from > to || to as usize > n {
            return Err(GatewayError::UnknownId(to, n));
        }
        let mut out = Vec::new();
        for id in (from..to).rev() {
            out.push(format_orpheus(&OrpheusMessage::Remove(id)));
        }
        out.push(format_orpheus(&OrpheusMessage::RemoveEnd));
        let inserted: Vec<RoutePoint> = detour
            .iter()
            .enumerate()
            .map(|(k, (lat, lon))| RoutePoint {
                id: from + k as u32,
                lat_deg: *lat,
                lon_deg: *lon,
                lat_err_m: err_m,
                lon_err_m: err_m,
            })
            .collect();
        for p in &inserted {
            out.push(format_orpheus(&OrpheusMessage::Insert(*p)));
        }
        out.push(format_orpheus(&OrpheusMessage::InsertEnd));
        self.route.splice(from as usize..to as usize, inserted);
        for (i, p) in self.route.iter_mut().enumerate() {
            p.id = i as u32;
        }
        Ok(out)
    }

    /// Makes `points` (lat, lon degrees, position errors `err_m`) the NC's route and returns the
    /// sentences announcing it (`$NALST` ids 0.., then `$NALST,END`): the list a control
    /// application that owns the route uploads. The NC starts it from id 0.
    pub fn send_list(&mut self, points: &[(f64, f64)], err_m: f64) -> Vec<String> {
        self.route = points
            .iter()
            .enumerate()
            .map(|(i, (lat, lon))| RoutePoint {
                id: i as u32,
                lat_deg: *lat,
                lon_deg: *lon,
                lat_err_m: err_m,
                lon_err_m: err_m,
            })
            .collect();
        self.incoming.clear();
        self.complete = true;
        self.reached = None;
        let mut out: Vec<String> = self
            .route
            .iter()
            .map(|p| format_orpheus(&OrpheusMessage::RoutePoint(*p)))
            .collect();
        out.push(format_orpheus(&OrpheusMessage::RouteEnd));
        out
    }

    /// The sentence that sets the NC's speed limit, percent of its maximum.
    pub fn speed_limit(pct: u8) -> String {
        format_orpheus(&OrpheusMessage::SpeedLimit(pct.min(100)))
    }
}

/// A minimal navigation computer: keeps a list and applies edits, as the real one does. Used
/// by the gateway tests (over real UDP sockets) and as a reference of the protocol's semantics.
#[derive(Clone, Debug, Default)]
pub struct ReferenceNavComputer {
    /// The NC's route.
    pub route: Vec<RoutePoint>,
    /// Speed limit, percent.
    pub speed_pct: u8,
}

impl ReferenceNavComputer {
    /// The sentences announcing the route.
    pub fn announce(&self) -> Vec<String> {
        let mut v: Vec<String> = self
            .route
            .iter()
            .map(|p| format_orpheus(&OrpheusMessage::RoutePoint(*p)))
            .collect();
        v.push(format_orpheus(&OrpheusMessage::RouteEnd));
        v
    }

    /// Applies one edit from the control application; other lines are errors.
    pub fn apply(&mut self, line: &str) -> Result<(), String> {
        match parse_orpheus(line).map_err(|e| e.to_string())? {
            OrpheusMessage::Remove(id) if (id as usize) < self.route.len() => {
                self.route.remove(id as usize);
            }
            OrpheusMessage::Insert(p) if (p.id as usize) <= self.route.len() => {
                self.route.insert(p.id as usize, p)
            }
            OrpheusMessage::RemoveEnd | OrpheusMessage::InsertEnd => {}
            OrpheusMessage::SpeedLimit(p) => self.speed_pct = p,
            other => return Err(format!("unexpected {other:?}")),
        }
        for (i, p) in self.route.iter_mut().enumerate() {
            p.id = i as u32;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn nc_with(n: u32) -> ReferenceNavComputer {
        ReferenceNavComputer {
            route: (0..n)
                .map(|i| RoutePoint {
                    id: i,
                    lat_deg: 48.0 + f64::from(i) * 1e-5,
                    lon_deg: 11.0,
                    lat_err_m: 0.02,
                    lon_err_m: 0.02,
                })
                .collect(),
            speed_pct: 100,
        }
    }

    #[test]
    fn receives_the_list_and_splices_a_detour_the_nc_reproduces() {
        let mut nc = nc_with(10);
        let mut gw = OrpheusGateway::new();
        for l in nc.announce() {
            gw.on_line(&l).unwrap();
        }
        assert!(gw.has_route());
        assert_eq!(gw.route().len(), 10);
        assert!(gw.on_line("$NAWPT,3*").is_err(), "malformed");
        let wpt = common::geo::nmea::frame("NAWPT,3");
        assert_eq!(gw.on_line(&wpt).unwrap(), GatewayEvent::Reached(3));
        let detour = [
            (48.00004, 11.00001),
            (48.00005, 11.00002),
            (48.00006, 11.00001),
        ];
        let edits = gw.splice(4, 6, &detour, 0.05).unwrap();
        for e in &edits {
            nc.apply(e).unwrap();
        }
        assert_eq!(nc.route.len(), 11);
        for (a, b) in nc.route.iter().zip(gw.route()) {
            assert_eq!(a.id, b.id);
            assert!((a.lat_deg - b.lat_deg).abs() < 1e-8 && (a.lon_deg - b.lon_deg).abs() < 1e-8);
        }
        assert!((nc.route[5].lat_deg - 48.00005).abs() < 1e-8);
        assert!(
            (nc.route[7].lat_deg - 48.00006).abs() < 1e-9,
            "old id 6 follows the detour"
        );
    }

    #[test]
    fn bad_lines_are_rejected_with_reasons() {
        let mut gw = OrpheusGateway::new();
        let mut bad = common::geo::nmea::frame("NAWPT,1");
        bad.replace_range(bad.len() - 4..bad.len() - 2, "00");
        assert!(matches!(gw.on_line(&bad), Err(GatewayError::Malformed(_))));
        assert!(matches!(
            gw.on_line(&common::geo::nmea::frame("NAWPT,1")),
            Err(GatewayError::UnknownId(1, 0))
        ));
        assert!(matches!(
            gw.on_line(&common::geo::nmea::frame("CAREM,1")),
            Err(GatewayError::Unexpected(_))
        ));
        let p = |id: u32| {
            format_orpheus(&OrpheusMessage::RoutePoint(RoutePoint {
                id,
                lat_deg: 1.0,
                lon_deg: 2.0,
                lat_err_m: 0.1,
                lon_err_m: 0.1,
            }))
        };
        gw.on_line(&p(0)).unwrap();
        assert!(matches!(
            gw.on_line(&p(2)),
            Err(GatewayError::OutOfSequence { got: 2, want: 1 })
        ));
        assert_eq!(gw.rejected, 4);
        assert!(gw.last_error.as_deref().unwrap().contains("sequence"));
    }
}
