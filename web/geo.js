// WGS-84 conversions between a datum's local ENU frame (x east, y north, z up, metres) and geodetic
// latitude/longitude. Exact (ECEF round trip), not a flat-earth approximation, so a coordinate shown
// in the browser matches what the station and the robot compute for the same point.

const A_M = 6378137.0;
const F = 1 / 298.257223563;
const E2 = F * (2 - F);
const DEG = Math.PI / 180;

/** Geodetic (degrees, metres) to ECEF [x, y, z] in metres. */
export function geodeticToEcef(latDeg, lonDeg, hM) {
  const lat = latDeg * DEG;
  const lon = lonDeg * DEG;
  const s = Math.sin(lat);
  const n = A_M / Math.sqrt(1 - E2 * s * s);
  return [
    (n + hM) * Math.cos(lat) * Math.cos(lon),
    (n + hM) * Math.cos(lat) * Math.sin(lon),
    (n * (1 - E2) + hM) * s,
  ];
}

/** ECEF (metres) to geodetic {latDeg, lonDeg, hM}; fixed-point iteration, sub-millimetre off the poles. */
export function ecefToGeodetic(x, y, z) {
  const p = Math.hypot(x, y);
  const lon = Math.atan2(y, x);
  let lat = Math.atan2(z, p * (1 - E2));
  let h = 0;
  for (let i = 0; i < 10; i++) {
    const s = Math.sin(lat);
    const n = A_M / Math.sqrt(1 - E2 * s * s);
    // Near the poles cos(lat) -> 0; the z-based form of h stays well conditioned there.
    h = Math.abs(Math.cos(lat)) > 1e-9 ? p / Math.cos(lat) - n : Math.abs(z) / Math.abs(s) - n * (1 - E2);
    const next = Math.atan2(z, p * (1 - (E2 * n) / (n + h)));
    if (Math.abs(next - lat) < 1e-14) {
      lat = next;
      break;
    }
    lat = next;
  }
  return { latDeg: lat / DEG, lonDeg: lon / DEG, hM: h };
}

/** ENU offset (metres) at `datum` {lat_deg, lon_deg, h_m} to geodetic {latDeg, lonDeg, hM}. */
export function enuToGeodetic(datum, e, n, u = 0) {
  const lat = datum.lat_deg * DEG;
  const lon = datum.lon_deg * DEG;
  const [x0, y0, z0] = geodeticToEcef(datum.lat_deg, datum.lon_deg, datum.h_m ?? 0);
  const sl = Math.sin(lat);
  const cl = Math.cos(lat);
  const so = Math.sin(lon);
  const co = Math.cos(lon);
  const dx = -so * e - sl * co * n + cl * co * u;
  const dy = co * e - sl * so * n + cl * so * u;
  const dz = cl * n + sl * u;
  return ecefToGeodetic(x0 + dx, y0 + dy, z0 + dz);
}

/** Geodetic (degrees, metres) to ENU {e, n, u} at `datum` {lat_deg, lon_deg, h_m}. */
export function geodeticToEnu(datum, latDeg, lonDeg, hM = datum.h_m ?? 0) {
  const lat = datum.lat_deg * DEG;
  const lon = datum.lon_deg * DEG;
  const [x0, y0, z0] = geodeticToEcef(datum.lat_deg, datum.lon_deg, datum.h_m ?? 0);
  const [x, y, z] = geodeticToEcef(latDeg, lonDeg, hM);
  const dx = x - x0;
  const dy = y - y0;
  const dz = z - z0;
  const sl = Math.sin(lat);
  const cl = Math.cos(lat);
  const so = Math.sin(lon);
  const co = Math.cos(lon);
  return {
    e: -so * dx + co * dy,
    n: -sl * co * dx - sl * so * dy + cl * dz,
    u: cl * co * dx + cl * so * dy + sl * dz,
  };
}

/** True when the datum carries a geodetic origin (local-only sessions have none). */
export function hasGeodetic(datum) {
  return !!datum && Number.isFinite(datum.lat_deg) && Number.isFinite(datum.lon_deg);
}

/** "47.3977420°N 8.5455940°E": 7 decimals is ~1 cm, enough for RTK positions. */
export function formatLatLon(latDeg, lonDeg) {
  const ns = latDeg >= 0 ? "N" : "S";
  const ew = lonDeg >= 0 ? "E" : "W";
  return `${Math.abs(latDeg).toFixed(7)}°${ns} ${Math.abs(lonDeg).toFixed(7)}°${ew}`;
}

/**
 * Parses "a, b" / "a b" / "a;b" into two finite numbers, or null. Used for typed goals
 * (x,y in metres or lat,lon in degrees).
 */
export function parsePair(text) {
  const parts = String(text).trim().split(/[\s,;]+/).filter((s) => s.length > 0);
  if (parts.length !== 2) return null;
  const a = Number(parts[0]);
  const b = Number(parts[1]);
  if (!Number.isFinite(a) || !Number.isFinite(b)) return null;
  return [a, b];
}
