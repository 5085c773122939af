//! WGS-84 geodetic <-> ECEF <-> local ENU conversions.
//!
//! Geodetic points are [`Datum`]s: latitude and longitude in degrees, height in metres above the
//! WGS-84 ellipsoid (not above mean sea level: add the geoid separation of a GGA first). ECEF and
//! ENU vectors are metres. Everything is exact on the ellipsoid; the inverse (ECEF -> geodetic)
//! iterates Bowring's formula to convergence, which is good to far below 1e-9 deg / 1 mm from the
//! Earth's surface out to geostationary heights, poles included.

use nalgebra::{Matrix3, Vector3};

use crate::msg::Datum;

/// Semi-major axis `a`, metres.
pub const A_M: f64 = 6_378_137.0;
/// Flattening `f`.
pub const F: f64 = 1.0 / 298.257_223_563;
/// Semi-minor axis `b = a (1 - f)`, metres.
pub const B_M: f64 = A_M * (1.0 - F);
/// First eccentricity squared `e^2 = f (2 - f)`.
pub const E2: f64 = F * (2.0 - F);
/// Second eccentricity squared `e'^2 = e^2 / (1 - e^2)`.
pub const EP2: f64 = E2 / (1.0 - E2);

/// Geodetic (lat, lon degrees, ellipsoidal height m) -> ECEF (m).
pub fn geodetic_to_ecef(p: &Datum) -> Vector3<f64> {
    let (sin_lat, cos_lat) = p.lat_deg.to_radians().sin_cos();
    let (sin_lon, cos_lon) = p.lon_deg.to_radians().sin_cos();
    // Prime-vertical radius of curvature.
    let n = A_M / (1.0 - E2 * sin_lat * sin_lat).sqrt();
    Vector3::new(
        (n + p.h_m) * cos_lat * cos_lon,
        (n + p.h_m) * cos_lat * sin_lon,
        (n * (1.0 - E2) + p.h_m) * sin_lat,
    )
}

/// ECEF (m) -> geodetic (lat, lon degrees, ellipsoidal height m).
///
/// Bowring's iteration on the parametric latitude; it converges in two or three steps for any
/// point outside a few hundred km of the Earth's centre. At the poles longitude is `atan2(y, x)`
/// (0 on the axis). Never panics; NaN in gives NaN out.
pub fn ecef_to_geodetic(ecef: &Vector3<f64>) -> Datum {
    let (x, y, z) = (ecef.x, ecef.y, ecef.z);
    let p = x.hypot(y);
    let lon = y.atan2(x);
    let lat_from_beta = |beta: f64| {
        let (sb, cb) = beta.sin_cos();
        (z + EP2 * B_M * sb * sb * sb).atan2(p - E2 * A_M * cb * cb * cb)
    };
    let mut beta = z.atan2((1.0 - F) * p);
    let mut lat = lat_from_beta(beta);
    for _ in 0..10 {
        let (sl, cl) = lat.sin_cos();
        let next_beta = ((1.0 - F) * sl).atan2(cl);
        let converged = (next_beta - beta).abs() <= 1e-15;
        beta = next_beta;
        lat = lat_from_beta(beta);
        if converged {
            break;
        }
    }
    let (sl, cl) = lat.sin_cos();
    // This form of h is well conditioned at every latitude, poles included (no 1/cos(lat)).
    let h = p * cl + z * sl - A_M * (1.0 - E2 * sl * sl).sqrt();
    Datum {
        lat_deg: lat.to_degrees(),
        lon_deg: lon.to_degrees(),
        h_m: h,
    }
}

/// Rotation taking ECEF vectors into the local East-North-Up frame at `lat_deg`, `lon_deg`.
pub fn rotation_enu_from_ecef(lat_deg: f64, lon_deg: f64) -> Matrix3<f64> {
    let (sl, cl) = lat_deg.to_radians().sin_cos();
    let (so, co) = lon_deg.to_radians().sin_cos();
    Matrix3::new(
        -so,
        co,
        0.0, //
        -sl * co,
        -sl * so,
        cl, //
        cl * co,
        cl * so,
        sl,
    )
}

/// A local East-North-Up frame anchored at a datum, with its ECEF origin and rotation
/// precomputed so that repeated conversions (every GNSS fix, every operator click) cost a
/// matrix-vector product plus, for the inverse, one [`ecef_to_geodetic`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalFrame {
    datum: Datum,
    origin_ecef: Vector3<f64>,
    enu_from_ecef: Matrix3<f64>,
}

impl LocalFrame {
    /// The ENU frame whose origin is `datum` (its ellipsoidal height included).
    pub fn new(datum: Datum) -> Self {
        Self {
            datum,
            origin_ecef: geodetic_to_ecef(&datum),
            enu_from_ecef: rotation_enu_from_ecef(datum.lat_deg, datum.lon_deg),
        }
    }

    /// The frame anchored at an ECEF point (converted to geodetic first).
    pub fn from_ecef(origin_ecef: &Vector3<f64>) -> Self {
        Self::new(ecef_to_geodetic(origin_ecef))
    }

    /// The datum this frame is anchored at.
    pub fn datum(&self) -> Datum {
        self.datum
    }

    /// The frame origin in ECEF, metres.
    pub fn origin_ecef(&self) -> Vector3<f64> {
        self.origin_ecef
    }

    /// The rotation ECEF -> ENU (its transpose is ENU -> ECEF).
    pub fn enu_from_ecef(&self) -> Matrix3<f64> {
        self.enu_from_ecef
    }

    /// ECEF point -> ENU offset from the origin, metres.
    pub fn ecef_to_enu(&self, ecef: &Vector3<f64>) -> Vector3<f64> {
        self.enu_from_ecef * (ecef - self.origin_ecef)
    }

    /// ENU offset from the origin -> ECEF point, metres.
    pub fn enu_to_ecef(&self, enu: &Vector3<f64>) -> Vector3<f64> {
        self.origin_ecef + self.enu_from_ecef.transpose() * enu
    }

    /// Geodetic point -> ENU offset (east, north, up) from the origin, metres.
    pub fn lla_to_enu(&self, p: &Datum) -> Vector3<f64> {
        self.ecef_to_enu(&geodetic_to_ecef(p))
    }

    /// ENU offset (east, north, up) from the origin -> geodetic point.
    pub fn enu_to_lla(&self, enu: &Vector3<f64>) -> Datum {
        ecef_to_geodetic(&self.enu_to_ecef(enu))
    }
}

/// Geodetic point `p` -> ENU offset (east, north, up) from `reference`, metres.
///
/// For many points at one reference, build a [`LocalFrame`] once instead.
pub fn lla_to_enu(reference: &Datum, p: &Datum) -> Vector3<f64> {
    LocalFrame::new(*reference).lla_to_enu(p)
}

/// ENU offset (east, north, up) from `reference`, metres -> geodetic point.
pub fn enu_to_lla(reference: &Datum, enu: &Vector3<f64>) -> Datum {
    LocalFrame::new(*reference).enu_to_lla(enu)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn d(lat_deg: f64, lon_deg: f64, h_m: f64) -> Datum {
        Datum {
            lat_deg,
            lon_deg,
            h_m,
        }
    }

    #[test]
    fn equator_and_poles_are_on_the_axes() {
        let e = geodetic_to_ecef(&d(0.0, 0.0, 0.0));
        assert!((e - Vector3::new(A_M, 0.0, 0.0)).norm() < 1e-9);
        let n = geodetic_to_ecef(&d(90.0, 0.0, 0.0));
        assert!(n.x.abs() < 1e-6 && (n.z - B_M).abs() < 1e-9, "{n:?}");
        let back = ecef_to_geodetic(&Vector3::new(0.0, 0.0, -B_M - 10.0));
        assert_eq!(back.lat_deg, -90.0);
        assert!((back.h_m - 10.0).abs() < 1e-9, "{back:?}");
    }

    #[test]
    fn enu_axes_point_east_north_up() {
        let frame = LocalFrame::new(d(45.0, 7.0, 100.0));
        let north = frame.lla_to_enu(&d(45.001, 7.0, 100.0));
        assert!(north.y > 100.0 && north.x.abs() < 1e-6, "{north:?}");
        let east = frame.lla_to_enu(&d(45.0, 7.001, 100.0));
        assert!(east.x > 70.0 && east.y.abs() < 0.01, "{east:?}");
        let up = frame.lla_to_enu(&d(45.0, 7.0, 110.0));
        assert!((up - Vector3::new(0.0, 0.0, 10.0)).norm() < 1e-9, "{up:?}");
    }

    #[test]
    fn centre_of_the_earth_does_not_panic() {
        let p = ecef_to_geodetic(&Vector3::zeros());
        assert!(p.h_m < 0.0);
        let q = ecef_to_geodetic(&Vector3::new(f64::NAN, 0.0, 0.0));
        assert!(q.lat_deg.is_nan() || q.h_m.is_nan());
    }
}
