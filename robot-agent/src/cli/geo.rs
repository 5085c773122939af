//! `robot-agent geo`: WGS-84 conversions on the command line.
//!
//! Each subcommand prints its three results on one line, separated by spaces, in Rust's
//! shortest round-trip form (full `f64` precision). Angles are degrees, lengths metres, heights
//! above the WGS-84 ellipsoid.

use anyhow::ensure;
use common::geo::wgs84::{ecef_to_geodetic, geodetic_to_ecef, LocalFrame};
use common::msg::Datum;
use nalgebra::Vector3;

/// Arguments of `robot-agent geo`.
#[derive(Debug, clap::Args)]
pub struct GeoArgs {
    #[command(subcommand)]
    command: GeoCommand,
}

#[derive(Debug, clap::Subcommand)]
enum GeoCommand {
    /// Geodetic (LAT LON H) -> ECEF (X Y Z).
    #[command(allow_negative_numbers = true)]
    Lla2ecef {
        /// Latitude, degrees north.
        lat: f64,
        /// Longitude, degrees east.
        lon: f64,
        /// Height above the ellipsoid, metres.
        h: f64,
    },
    /// ECEF (X Y Z) -> geodetic (LAT LON H).
    #[command(allow_negative_numbers = true)]
    Ecef2lla {
        /// ECEF x, metres.
        x: f64,
        /// ECEF y, metres.
        y: f64,
        /// ECEF z, metres.
        z: f64,
    },
    /// Geodetic point -> ENU (E N U) at a geodetic reference.
    #[command(allow_negative_numbers = true)]
    Lla2enu {
        /// Reference latitude, degrees.
        lat0: f64,
        /// Reference longitude, degrees.
        lon0: f64,
        /// Reference height, metres.
        h0: f64,
        /// Point latitude, degrees.
        lat: f64,
        /// Point longitude, degrees.
        lon: f64,
        /// Point height, metres.
        h: f64,
    },
    /// ENU (E N U) at a geodetic reference -> geodetic point (LAT LON H).
    #[command(allow_negative_numbers = true)]
    Enu2lla {
        /// Reference latitude, degrees.
        lat0: f64,
        /// Reference longitude, degrees.
        lon0: f64,
        /// Reference height, metres.
        h0: f64,
        /// East, metres.
        e: f64,
        /// North, metres.
        n: f64,
        /// Up, metres.
        u: f64,
    },
    /// ECEF point -> ENU (E N U) at a reference given in ECEF.
    #[command(allow_negative_numbers = true)]
    Ecef2enu {
        /// Reference ECEF x, metres.
        x0: f64,
        /// Reference ECEF y, metres.
        y0: f64,
        /// Reference ECEF z, metres.
        z0: f64,
        /// Point ECEF x, metres.
        x: f64,
        /// Point ECEF y, metres.
        y: f64,
        /// Point ECEF z, metres.
        z: f64,
    },
}

fn datum(lat_deg: f64, lon_deg: f64, h_m: f64) -> anyhow::Result<Datum> {
    ensure!(
        lat_deg.is_finite() && (-90.0..=90.0).contains(&lat_deg),
        "latitude {lat_deg} is not in -90..=90 degrees"
    );
    ensure!(
        lon_deg.is_finite() && h_m.is_finite(),
        "longitude and height must be finite numbers"
    );
    Ok(Datum {
        lat_deg,
        lon_deg,
        h_m,
    })
}

fn finite(v: [f64; 3]) -> anyhow::Result<Vector3<f64>> {
    ensure!(
        v.iter().all(|x| x.is_finite()),
        "coordinates must be finite numbers"
    );
    Ok(Vector3::new(v[0], v[1], v[2]))
}

/// The three numbers of a result, on one line.
fn line(a: f64, b: f64, c: f64) -> String {
    format!("{a} {b} {c}")
}

fn compute(command: &GeoCommand) -> anyhow::Result<String> {
    Ok(match *command {
        GeoCommand::Lla2ecef { lat, lon, h } => {
            let x = geodetic_to_ecef(&datum(lat, lon, h)?);
            line(x.x, x.y, x.z)
        }
        GeoCommand::Ecef2lla { x, y, z } => {
            let p = ecef_to_geodetic(&finite([x, y, z])?);
            line(p.lat_deg, p.lon_deg, p.h_m)
        }
        GeoCommand::Lla2enu {
            lat0,
            lon0,
            h0,
            lat,
            lon,
            h,
        } => {
            let enu = LocalFrame::new(datum(lat0, lon0, h0)?).lla_to_enu(&datum(lat, lon, h)?);
            line(enu.x, enu.y, enu.z)
        }
        GeoCommand::Enu2lla {
            lat0,
            lon0,
            h0,
            e,
            n,
            u,
        } => {
            let p = LocalFrame::new(datum(lat0, lon0, h0)?).enu_to_lla(&finite([e, n, u])?);
            line(p.lat_deg, p.lon_deg, p.h_m)
        }
        GeoCommand::Ecef2enu {
            x0,
            y0,
            z0,
            x,
            y,
            z,
        } => {
            let enu =
                LocalFrame::from_ecef(&finite([x0, y0, z0])?).ecef_to_enu(&finite([x, y, z])?);
            line(enu.x, enu.y, enu.z)
        }
    })
}

/// Runs `robot-agent geo`.
pub fn run(args: GeoArgs) -> anyhow::Result<()> {
    println!("{}", compute(&args.command)?);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(flatten)]
        geo: GeoArgs,
    }

    fn run_args(args: &[&str]) -> anyhow::Result<String> {
        let cli = Cli::try_parse_from(std::iter::once("geo").chain(args.iter().copied()))?;
        compute(&cli.geo.command)
    }

    fn nums(s: &str) -> Vec<f64> {
        s.split(' ').filter_map(|t| t.parse().ok()).collect()
    }

    #[test]
    fn negative_arguments_parse_and_round_trip() {
        let ecef = run_args(&["lla2ecef", "-33.3", "-44.4", "-6000"]).expect("lla2ecef");
        let v = nums(&ecef);
        assert_eq!(v.len(), 3, "{ecef}");
        let back = run_args(&[
            "ecef2lla",
            &v[0].to_string(),
            &v[1].to_string(),
            &v[2].to_string(),
        ])
        .expect("ecef2lla");
        let p = nums(&back);
        assert!(
            (p[0] + 33.3).abs() < 1e-12 && (p[1] + 44.4).abs() < 1e-12,
            "{back}"
        );
        assert!((p[2] + 6000.0).abs() < 1e-6, "{back}");
    }

    #[test]
    fn enu_matches_geographiclib_example() {
        let out =
            run_args(&["lla2enu", "33", "44", "20", "33.3", "44.4", "6000"]).expect("lla2enu");
        let v = nums(&out);
        for (got, want) in v.iter().zip([37288.97, 33374.29, 5783.64]) {
            assert!((got - want).abs() < 0.01, "{out}");
        }
        let back = run_args(&[
            "enu2lla",
            "33",
            "44",
            "20",
            &v[0].to_string(),
            &v[1].to_string(),
            &v[2].to_string(),
        ])
        .expect("enu2lla");
        let p = nums(&back);
        assert!(
            (p[0] - 33.3).abs() < 1e-9
                && (p[1] - 44.4).abs() < 1e-9
                && (p[2] - 6000.0).abs() < 1e-3
        );
    }

    #[test]
    fn bad_latitude_is_an_error() {
        assert!(run_args(&["lla2ecef", "91", "0", "0"]).is_err());
        assert!(run_args(&["lla2ecef", "NaN", "0", "0"]).is_err());
        assert!(run_args(&["lla2ecef", "1", "0"]).is_err());
    }
}
