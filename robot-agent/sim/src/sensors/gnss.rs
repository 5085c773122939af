//! The dual-antenna RTK receiver: fix state, sky shading near structures, GGA and AVR sentences.

use super::GnssConfig;
use crate::world::{SolidKind, World};
use common::geo::{format_avr, format_gga, Avr, Gga, LocalFrame, UtcTime};
use nalgebra::{Isometry3, Point3, Vector3};
use rand::rngs::SmallRng;
use rand::Rng;
use rand_distr::StandardNormal;
use sensing::GnssSentence;

/// RTK state of the simulated receiver.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GnssFix {
    /// No position.
    None,
    /// Autonomous single-point fix (GGA quality 1).
    Single,
    /// RTK float (GGA 5).
    Float,
    /// RTK fixed (GGA 4).
    Fixed,
}

impl GnssFix {
    /// Quality order: None < Single < Float < Fixed.
    fn rank(self) -> u8 {
        match self {
            GnssFix::None => 0,
            GnssFix::Single => 1,
            GnssFix::Float => 2,
            GnssFix::Fixed => 3,
        }
    }
}

/// Dual-antenna GNSS receiver emitting GGA + `$PTNL,AVR`.
pub(crate) struct Gnss {
    cfg: GnssConfig,
    frame: LocalFrame,
    primary: Vector3<f64>,
    secondary: Vector3<f64>,
    next_t_s: f64,
    bias: Vector3<f64>,
    last_loss_t_s: f64,
    pub(crate) fix: GnssFix,
    /// Scenario areas without RTK: polygon (map frame) and the best fix inside.
    denied: Vec<(Vec<(f64, f64)>, GnssFix)>,
}

impl Gnss {
    pub(crate) fn new(
        cfg: &GnssConfig,
        datum: common::msg::Datum,
        primary: [f64; 3],
        secondary: [f64; 3],
    ) -> Self {
        Self {
            cfg: cfg.clone(),
            frame: LocalFrame::new(datum),
            primary: Vector3::from(primary),
            secondary: Vector3::from(secondary),
            next_t_s: 0.0,
            bias: Vector3::zeros(),
            last_loss_t_s: cfg.initial_float_s - cfg.float_after_loss_s,
            fix: GnssFix::Fixed,
            denied: Vec::new(),
        }
    }

    /// Adds the scenario's `gnss_denied` areas: inside one the fix is at best its `fix`.
    pub(crate) fn with_denied_areas(mut self, areas: &[crate::scenario::GnssDeniedSpec]) -> Self {
        self.denied = areas
            .iter()
            .map(|a| {
                let fix = match a.fix {
                    crate::scenario::DeniedFix::None => GnssFix::None,
                    crate::scenario::DeniedFix::Single => GnssFix::Single,
                };
                (a.polygon(), fix)
            })
            .collect();
        self
    }

    /// The best fix the denied areas allow at (x, y) (`Fixed` outside all of them).
    fn denied_cap(&self, x: f64, y: f64) -> GnssFix {
        let mut cap = GnssFix::Fixed;
        for (poly, fix) in &self.denied {
            if common::zone::contains(poly, (x, y)) && fix.rank() < cap.rank() {
                cap = *fix;
            }
        }
        cap
    }

    /// Distance from (x, y) to the nearest structure tall enough to shade the sky.
    fn sky_block_distance(world: &World, x: f64, y: f64) -> f64 {
        let mut best = f64::INFINITY;
        for s in world.solids() {
            if !matches!(s.kind, SolidKind::Wall | SolidKind::Box) || s.z1_m - s.z0_m < 2.0 {
                continue;
            }
            best = best.min(s.footprint_distance(x, y));
        }
        best
    }

    /// Emits the sentences of an epoch if one falls at or before `t_s`.
    pub(crate) fn step(
        &mut self,
        world: &World,
        t_s: f64,
        base: &Isometry3<f64>,
        rng: &mut SmallRng,
    ) -> Vec<GnssSentence> {
        if t_s + 1e-9 < self.next_t_s {
            return Vec::new();
        }
        let dt = 1.0 / self.cfg.rate_hz;
        self.next_t_s += dt;
        if self.next_t_s < t_s {
            self.next_t_s = t_s + dt;
        }
        let p1 = base * Point3::from(self.primary);
        let p2 = base * Point3::from(self.secondary);
        let d = Self::sky_block_distance(world, p1.x, p1.y);
        let cap = self.denied_cap(p1.x, p1.y);
        let fix = if d < self.cfg.no_fix_distance_m || cap == GnssFix::None {
            GnssFix::None
        } else if d < self.cfg.rtk_loss_distance_m || cap == GnssFix::Single {
            GnssFix::Single
        } else if t_s - self.last_loss_t_s < self.cfg.float_after_loss_s {
            GnssFix::Float
        } else {
            GnssFix::Fixed
        };
        if matches!(fix, GnssFix::None | GnssFix::Single) {
            self.last_loss_t_s = t_s;
        }
        // Gauss-Markov bias per fix type: corrections drift slowly, single-point wanders.
        let (sigma, tau) = match fix {
            GnssFix::Fixed => (self.cfg.rtk_sigma_m, 5.0),
            GnssFix::Float => (self.cfg.float_sigma_m, 10.0),
            GnssFix::Single | GnssFix::None => (self.cfg.single_sigma_m, 60.0),
        };
        if fix != self.fix {
            self.bias *= 0.0;
        }
        self.fix = fix;
        let a = (-dt / tau).exp();
        let q = sigma * (1.0 - a * a).sqrt();
        let mut gauss = || -> f64 { rng.sample(StandardNormal) };
        self.bias = self.bias * a + Vector3::new(gauss() * q, gauss() * q, gauss() * q * 1.5);
        let white = Vector3::new(gauss(), gauss(), gauss() * 1.5) * (0.3 * sigma);
        let meas = p1.coords + self.bias + white;
        let lla = self.frame.enu_to_lla(&meas);
        let time = Some(UtcTime::from_seconds_of_day(self.cfg.utc_start_s + t_s));
        let (quality, sats, hdop, age) = match fix {
            GnssFix::Fixed => (4, 16, 0.7, Some(1.0)),
            GnssFix::Float => (5, 14, 0.9, Some(1.0)),
            GnssFix::Single => (1, 7, 2.4, None),
            GnssFix::None => (0, 0, 0.0, None),
        };
        let has = fix != GnssFix::None;
        let gga = Gga {
            talker: "GP".into(),
            time,
            lat_deg: has.then_some(lla.lat_deg),
            lon_deg: has.then_some(lla.lon_deg),
            quality,
            satellites: Some(sats),
            hdop: has.then_some(hdop),
            alt_msl_m: has.then_some(lla.h_m - self.cfg.geoid_separation_m),
            geoid_sep_m: has.then_some(self.cfg.geoid_separation_m),
            dgps_age_s: age,
            dgps_station: age.map(|_| 1),
        };
        let rtk = matches!(fix, GnssFix::Fixed | GnssFix::Float);
        let bl = p1 - p2;
        let hsig = if fix == GnssFix::Fixed {
            self.cfg.heading_sigma_deg
        } else {
            5.0 * self.cfg.heading_sigma_deg
        };
        let yaw_enu_deg = bl.y.atan2(bl.x).to_degrees() + gauss() * hsig;
        let tilt_deg = bl.z.atan2(bl.x.hypot(bl.y)).to_degrees() + gauss() * hsig;
        let avr = Avr {
            time,
            yaw_deg: rtk.then_some((90.0 - yaw_enu_deg).rem_euclid(360.0)),
            tilt_deg: rtk.then_some(tilt_deg),
            roll_deg: None,
            range_m: rtk.then_some(bl.norm() + gauss() * 0.002),
            quality: match fix {
                GnssFix::Fixed => 3,
                GnssFix::Float => 4,
                _ => 0,
            },
            pdop: has.then_some(hdop * 1.4),
            satellites: Some(sats),
        };
        vec![
            GnssSentence {
                t_s,
                text: format_gga(&gga).trim_end().to_string(),
            },
            GnssSentence {
                t_s,
                text: format_avr(&avr).trim_end().to_string(),
            },
        ]
    }
}
