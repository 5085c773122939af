//! GNSS state: the latest fix and heading from NMEA sentences, loss detection, whether the map
//! frame can be anchored, and GNSS goals through the datum (docs/algorithms.md §2, §5.2).

use super::FixKind;
use common::geo::{parse_sentence, LocalFrame, NmeaError, Sentence};
use common::msg::Datum;
use nalgebra::Vector3;
use serde::Deserialize;

/// GNSS handling parameters.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct GnssConfig {
    /// A fix older than this counts as lost, seconds.
    pub fix_timeout_s: f64,
    /// A GNSS goal closer than this is no longer re-evaluated per fix (noise would make it wander), metres.
    pub goal_freeze_distance_m: f64,
    /// Satellites needed to trust an RTK fix for anchoring the map frame (RTK needs ≥ 5 to initialise).
    pub min_satellites_anchor: u8,
    /// Forward offset of the GNSS antenna reference point from base_link, metres.
    pub antenna_x_m: f64,
    /// Share of the GNSS-minus-SLAM position difference corrected per RTK fixed fix (0 = GNSS
    /// only anchors the start; SLAM then drifts freely).
    pub fusion_gain: f64,
    /// Share of the GNSS-minus-SLAM height difference corrected per RTK fixed fix. Far smaller
    /// than `fusion_gain`: a height step between sweeps reads as a step in the terrain, so the
    /// height only creeps towards GNSS to cancel SLAM's slow vertical drift.
    pub height_gain: f64,
    /// Share of the dual-antenna heading difference corrected per fix.
    pub heading_gain: f64,
    /// A fix further than this from the SLAM pose is treated as an outlier, metres.
    pub fusion_gate_m: f64,
    /// While the pose is farther than this from a fresh RTK fixed fix, it is not trusted: no
    /// teach waypoint is taken from it and no sweep is mapped with it (SLAM thrown off for a
    /// moment, e.g. by the jolt of a curb, and GNSS still pulling it back), metres.
    pub pose_trust_residual_m: f64,
    /// Nor is a sweep mapped whose SLAM pose lands farther than this from where odometry
    /// carried the previous one (the glitch itself, before a fix can tell), metres.
    pub pose_jump_max_m: f64,
    /// Nor one whose pitch differs from the fresh dual-antenna pitch by more than this (1 deg
    /// of pitch lifts ground 7 m ahead by 12 cm: a step against what the map holds), degrees.
    pub pose_trust_pitch_deg: f64,
    /// Stored map heights within this distance of the robot follow each correction of the
    /// frame's height and tilt (the last quarter tapers), metres: the map's reach for one
    /// correction, a bound on its cost.
    pub map_follow_radius_m: f64,
    /// Tilt of the SLAM frame estimated from the GNSS track (`[gnss.tilt]`).
    pub tilt: super::tilt::TiltConfig,
}

impl Default for GnssConfig {
    fn default() -> Self {
        Self {
            fix_timeout_s: 1.0,
            goal_freeze_distance_m: 5.0,
            min_satellites_anchor: 5,
            antenna_x_m: 0.0,
            fusion_gain: 0.1,
            height_gain: 0.005,
            heading_gain: 0.02,
            fusion_gate_m: 3.0,
            pose_trust_residual_m: 0.1,
            pose_jump_max_m: 0.15,
            pose_trust_pitch_deg: 1.0,
            map_follow_radius_m: 300.0,
            tilt: Default::default(),
        }
    }
}

/// One position fix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fix {
    /// Arrival time, seconds (session clock).
    pub t_s: f64,
    /// Position, ellipsoidal height.
    pub lla: Datum,
    /// GGA quality.
    pub quality: u8,
    /// Satellites used (`None`: the source does not say, as a ROS `NavSatFix`).
    pub satellites: Option<u8>,
}

/// Tracks fixes and the dual-antenna heading from a stream of sentences.
#[derive(Clone, Debug, Default)]
pub struct GnssTracker {
    cfg: GnssConfig,
    fix: Option<Fix>,
    /// (arrival time, yaw degrees clockwise from north)
    heading: Option<(f64, f64)>,
    /// (arrival time, baseline tilt degrees, positive with the primary (front) antenna higher)
    tilt: Option<(f64, f64)>,
    /// Sentences that failed to parse.
    pub bad_sentences: u32,
    /// Last parse error, for the status.
    pub last_error: Option<String>,
}

impl GnssTracker {
    /// A tracker with no fix.
    pub fn new(cfg: GnssConfig) -> Self {
        Self {
            cfg,
            ..Self::default()
        }
    }

    /// Feeds one sentence received at `t_s`. Bad sentences are counted and returned as errors;
    /// they never disturb the last good fix.
    pub fn on_sentence(&mut self, t_s: f64, text: &str) -> Result<(), NmeaError> {
        match parse_sentence(text) {
            Ok(Sentence::Gga(g)) => {
                if g.has_fix() {
                    // A GGA cut short before the geoid separation gives only the height above
                    // the geoid: within a session that is a constant offset, which the frame
                    // (ENU at a datum) does not see.
                    let h = g.alt_hae_m().or(g.alt_msl_m);
                    if let (Some(lat), Some(lon), Some(h)) = (g.lat_deg, g.lon_deg, h) {
                        self.fix = Some(Fix {
                            t_s,
                            lla: Datum {
                                lat_deg: lat,
                                lon_deg: lon,
                                h_m: h,
                            },
                            quality: g.quality,
                            satellites: Some(g.satellites.unwrap_or(0)),
                        });
                    }
                }
                Ok(())
            }
            Ok(Sentence::Avr(a)) => {
                if a.quality > 0 {
                    if let Some(yaw) = a.yaw_deg {
                        self.heading = Some((t_s, yaw));
                    }
                    if let Some(tilt) = a.tilt_deg {
                        self.tilt = Some((t_s, tilt));
                    }
                }
                Ok(())
            }
            Ok(Sentence::Hdt(h)) => {
                if let Some(yaw) = h.heading_deg {
                    self.heading = Some((t_s, yaw));
                }
                Ok(())
            }
            Ok(Sentence::Ths(h)) => {
                if let Some(yaw) = h.heading_deg {
                    self.heading = Some((t_s, yaw));
                }
                Ok(())
            }
            Ok(Sentence::Pashr(p)) => {
                if let Some(yaw) = p.usable_heading_deg() {
                    self.heading = Some((t_s, yaw));
                    // PASHR's pitch is the body's, nose up: the tilt of a fore-aft baseline.
                    if let Some(pitch) = p.pitch_deg {
                        self.tilt = Some((t_s, pitch));
                    }
                }
                Ok(())
            }
            Ok(_) => Ok(()),
            Err(e) => {
                self.bad_sentences += 1;
                self.last_error = Some(format!("GNSS: {e}"));
                Err(e)
            }
        }
    }

    /// Takes a fix a driver decoded (ROS `NavSatFix`, gpsd); one without a position only ages
    /// the last. `Err` for a non-finite or out-of-range position (counted like a bad sentence).
    pub fn on_fix(&mut self, f: &sensing::GnssFixSample) -> Result<(), String> {
        if f.quality == 0 {
            return Ok(());
        }
        let valid = f.lat_deg.is_finite()
            && f.lon_deg.is_finite()
            && f.h_m.is_finite()
            && f.lat_deg.abs() <= 90.0
            && f.lon_deg.abs() <= 180.0;
        if !valid {
            self.bad_sentences += 1;
            let e = format!(
                "GNSS: fix ({}, {}, {}) is not a position",
                f.lat_deg, f.lon_deg, f.h_m
            );
            self.last_error = Some(e.clone());
            return Err(e);
        }
        self.fix = Some(Fix {
            t_s: f.t_s,
            lla: Datum {
                lat_deg: f.lat_deg,
                lon_deg: f.lon_deg,
                h_m: f.h_m,
            },
            quality: f.quality,
            satellites: f.satellites,
        });
        Ok(())
    }

    /// Takes a true heading a driver decoded (degrees clockwise from north).
    pub fn on_heading(&mut self, h: &sensing::GnssHeadingSample) -> Result<(), String> {
        if !h.heading_deg.is_finite() {
            self.bad_sentences += 1;
            let e = "GNSS: heading is not a number".to_string();
            self.last_error = Some(e.clone());
            return Err(e);
        }
        self.heading = Some((h.t_s, h.heading_deg.rem_euclid(360.0)));
        Ok(())
    }

    /// The latest fix if it is fresh at `t_s`.
    pub fn fix(&self, t_s: f64) -> Option<Fix> {
        self.fix.filter(|f| t_s - f.t_s <= self.cfg.fix_timeout_s)
    }

    /// Fix state for the pose message.
    pub fn fix_kind(&self, t_s: f64) -> FixKind {
        self.fix(t_s)
            .map(|f| FixKind::from_gga_quality(f.quality))
            .unwrap_or_default()
    }

    /// Heading of base_link in the ENU frame (counter-clockwise from east), radians, if fresh.
    pub fn yaw_enu_rad(&self, t_s: f64) -> Option<f64> {
        self.heading
            .filter(|(t, _)| t_s - t <= self.cfg.fix_timeout_s)
            .map(|(_, yaw_cw_north_deg)| {
                common::geom::wrap_angle((90.0 - yaw_cw_north_deg).to_radians())
            })
    }

    /// Pitch of base_link from the antenna baseline's tilt, radians (positive = nose down, the
    /// right-handed rotation about y), if fresh.
    pub fn pitch_rad(&self, t_s: f64) -> Option<f64> {
        self.tilt
            .filter(|(t, _)| t_s - t <= self.cfg.fix_timeout_s)
            .map(|(_, tilt_deg)| -tilt_deg.to_radians())
    }

    /// True when an RTK fixed fix with enough satellites and a heading are both fresh: the map
    /// frame can be anchored as ENU at a datum and the initial pose taken from GNSS.
    pub fn can_anchor(&self, t_s: f64) -> bool {
        self.fix(t_s).is_some_and(|f| {
            f.quality == common::geo::nmea::QUALITY_RTK_FIXED
                && f.satellites
                    .is_none_or(|n| n >= self.cfg.min_satellites_anchor)
        }) && self.yaw_enu_rad(t_s).is_some()
    }

    /// The configuration.
    pub fn config(&self) -> &GnssConfig {
        &self.cfg
    }
}

/// Why a GNSS goal cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum GnssGoalError {
    /// The map frame is SLAM-only.
    #[error(
        "GNSS goal refused: the map frame has no datum (no RTK fix and heading at session start)"
    )]
    NoDatum,
    /// Latitude/longitude out of range or not finite.
    #[error("GNSS goal refused: lat {0}, lon {1} out of range")]
    OutOfRange(f64, f64),
}

/// A goal given as lat/lon, tracked in the map frame (docs/algorithms.md §5.2): the goal is placed
/// relative to the robot's current fix (`goal = robot + d`, d from the exact ENU difference),
/// re-evaluated at each new fix so SLAM drift does not bias it, except once within
/// `goal_freeze_distance_m`.
#[derive(Clone, Debug, PartialEq)]
pub struct GnssGoal {
    /// Target.
    pub target: Datum,
    /// Current estimate in the map frame, metres.
    pub goal_map: (f64, f64),
    /// No longer re-evaluated (close to the goal).
    pub frozen: bool,
}

impl GnssGoal {
    /// Places a GNSS goal. Without a fresh fix it goes through the datum alone.
    pub fn new(
        lat_deg: f64,
        lon_deg: f64,
        h_m: Option<f64>,
        datum: Option<&LocalFrame>,
        robot_map: (f64, f64),
        fix: Option<&Fix>,
    ) -> Result<Self, GnssGoalError> {
        if !(lat_deg.is_finite()
            && lon_deg.is_finite()
            && lat_deg.abs() <= 90.0
            && lon_deg.abs() <= 180.0)
        {
            return Err(GnssGoalError::OutOfRange(lat_deg, lon_deg));
        }
        let frame = datum.ok_or(GnssGoalError::NoDatum)?;
        let h = h_m.or(fix.map(|f| f.lla.h_m)).unwrap_or(frame.datum().h_m);
        let target = Datum {
            lat_deg,
            lon_deg,
            h_m: h,
        };
        let enu = frame.lla_to_enu(&target);
        let mut g = Self {
            target,
            goal_map: (enu.x, enu.y),
            frozen: false,
        };
        if let Some(f) = fix {
            g.refresh(robot_map, f, f64::INFINITY);
        }
        Ok(g)
    }

    /// Re-evaluates the goal with a new fix, unless closer than `freeze_m`.
    pub fn refresh(&mut self, robot_map: (f64, f64), fix: &Fix, freeze_m: f64) {
        if self.frozen {
            return;
        }
        let dist = (self.goal_map.0 - robot_map.0).hypot(self.goal_map.1 - robot_map.1);
        if dist < freeze_m {
            self.frozen = true;
            return;
        }
        let d: Vector3<f64> = LocalFrame::new(fix.lla).lla_to_enu(&self.target);
        self.goal_map = (robot_map.0 + d.x, robot_map.1 + d.y);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use common::geo::{format_gga, trimble::format_avr, Avr, Gga, UtcTime};

    fn gga(lat: f64, lon: f64, q: u8) -> String {
        format_gga(&Gga {
            talker: "GP".into(),
            time: Some(UtcTime::from_seconds_of_day(3600.0)),
            lat_deg: Some(lat),
            lon_deg: Some(lon),
            quality: q,
            satellites: Some(12),
            hdop: Some(0.8),
            alt_msl_m: Some(500.0),
            geoid_sep_m: Some(47.0),
            dgps_age_s: None,
            dgps_station: None,
        })
    }

    fn avr(yaw_deg: f64) -> String {
        format_avr(&Avr {
            time: Some(UtcTime::from_seconds_of_day(3600.0)),
            yaw_deg: Some(yaw_deg),
            tilt_deg: Some(0.0),
            roll_deg: None,
            range_m: Some(1.0),
            quality: 3,
            pdop: Some(1.5),
            satellites: Some(12),
        })
    }

    #[test]
    fn tracks_fix_heading_and_loss() {
        let mut t = GnssTracker::new(GnssConfig::default());
        assert!(!t.can_anchor(0.0));
        t.on_sentence(0.0, &gga(48.1, 11.5, 4)).unwrap();
        t.on_sentence(0.0, &avr(0.0)).unwrap();
        assert!(t.can_anchor(0.5));
        assert_eq!(t.fix_kind(0.5), FixKind::RtkFixed);
        assert!((t.fix(0.5).unwrap().lla.h_m - 547.0).abs() < 1e-9);
        // North (0 deg clockwise from north) is +90 deg counter-clockwise from east.
        assert!((t.yaw_enu_rad(0.5).unwrap() - std::f64::consts::FRAC_PI_2).abs() < 1e-9);
        assert_eq!(t.fix_kind(2.0), FixKind::None, "stale fix counts as lost");
        // A corrupt sentence is counted and leaves the fix alone.
        let mut bad = gga(48.2, 11.5, 4);
        bad.replace_range(10..11, "9");
        assert!(t.on_sentence(0.6, &bad).is_err());
        assert_eq!(t.bad_sentences, 1);
        assert!((t.fix(0.6).unwrap().lla.lat_deg - 48.1).abs() < 1e-12);
        // RTK float does not anchor.
        t.on_sentence(0.7, &gga(48.1, 11.5, 5)).unwrap();
        assert!(!t.can_anchor(0.7));
    }

    #[test]
    fn gnss_goal_follows_the_fix_until_close() {
        let datum = Datum {
            lat_deg: 48.0,
            lon_deg: 11.0,
            h_m: 500.0,
        };
        let frame = LocalFrame::new(datum);
        let target = frame.enu_to_lla(&Vector3::new(30.0, 40.0, 0.0));
        assert_eq!(
            GnssGoal::new(target.lat_deg, target.lon_deg, None, None, (0.0, 0.0), None),
            Err(GnssGoalError::NoDatum)
        );
        assert!(GnssGoal::new(95.0, 0.0, None, Some(&frame), (0.0, 0.0), None).is_err());
        let mut g = GnssGoal::new(
            target.lat_deg,
            target.lon_deg,
            Some(500.0),
            Some(&frame),
            (0.0, 0.0),
            None,
        )
        .unwrap();
        assert!((g.goal_map.0 - 30.0).abs() < 1e-6 && (g.goal_map.1 - 40.0).abs() < 1e-6);
        // SLAM drifted: the robot believes it is at (1, 0) while GNSS says (0, 0): the goal moves with it.
        let fix = Fix {
            t_s: 0.0,
            lla: datum,
            quality: 4,
            satellites: Some(12),
        };
        g.refresh((1.0, 0.0), &fix, 5.0);
        assert!((g.goal_map.0 - 31.0).abs() < 1e-3 && (g.goal_map.1 - 40.0).abs() < 1e-3);
        // Within 5 m the goal freezes.
        let near = Fix {
            lla: frame.enu_to_lla(&Vector3::new(28.0, 38.0, 0.0)),
            ..fix
        };
        g.refresh((29.0, 38.0), &near, 5.0);
        assert!(g.frozen);
        let before = g.goal_map;
        g.refresh((0.0, 0.0), &fix, 5.0);
        assert_eq!(g.goal_map, before);
    }
}
