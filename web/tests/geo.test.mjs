// WGS-84 helpers of the UI against the same reference vectors the Rust geodesy uses
// (../shared/data/geodesy/vectors.tsv: gpsd, GeographicLib, IOGP 373-7-2), plus round trips.
// Run: node --test web/tests/
import { test } from "node:test";
import assert from "node:assert/strict";
import { existsSync, readFileSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";
import { enuToGeodetic, geodeticToEcef, ecefToGeodetic, geodeticToEnu, parsePair, formatLatLon } from "../geo.js";

const here = dirname(fileURLToPath(import.meta.url));
const vectors = join(here, "../../../shared/data/geodesy/vectors.tsv");

test("reference vectors reproduce within tolerance", (t) => {
  if (!existsSync(vectors)) {
    t.skip("../shared/data is absent");
    return;
  }
  const nums = (s) => s.trim().split(/\s+/).map(Number);
  let checked = 0;
  for (const line of readFileSync(vectors, "utf8").split("\n")) {
    if (!line.trim() || line.startsWith("#")) continue;
    const [kind, inputs, expected, tol] = line.split("\t");
    const want = nums(expected);
    let got;
    if (kind === "lla2ecef") {
      const [lat, lon, h] = nums(inputs);
      got = geodeticToEcef(lat, lon, h);
      const back = ecefToGeodetic(...got);
      assert.ok(Math.abs(back.latDeg - lat) < 1e-11 && Math.abs(back.lonDeg - lon) < 1e-11 && Math.abs(back.hM - h) < 1e-6, line);
    } else if (kind === "lla2enu") {
      const [r, p] = inputs.split("|").map(nums);
      const enu = geodeticToEnu({ lat_deg: r[0], lon_deg: r[1], h_m: r[2] }, p[0], p[1], p[2]);
      got = [enu.e, enu.n, enu.u];
      // and back: ENU at the datum to geodetic gives the point
      const g = enuToGeodetic({ lat_deg: r[0], lon_deg: r[1], h_m: r[2] }, enu.e, enu.n, enu.u);
      assert.ok(Math.abs(g.latDeg - p[0]) < 1e-10 && Math.abs(g.lonDeg - p[1]) < 1e-10 && Math.abs(g.hM - p[2]) < 1e-5, line);
    } else {
      continue; // ecef2enu: the UI never starts from ECEF
    }
    const err = Math.max(...got.map((v, i) => Math.abs(v - want[i])));
    assert.ok(err <= Number(tol), `${line}: got ${got}, error ${err}`);
    checked++;
  }
  assert.equal(checked, 6);
});

test("ENU round trip near a field site, 10 km out, and at the poles", () => {
  const d = { lat_deg: 47.3977, lon_deg: 8.5456, h_m: 412.5 };
  for (const [e, n] of [[0, 0], [12.34, -5.67], [10000, 10000], [-3000, 7000]]) {
    const g = enuToGeodetic(d, e, n, 0);
    const back = geodeticToEnu(d, g.latDeg, g.lonDeg, g.hM);
    assert.ok(Math.abs(back.e - e) < 1e-6 && Math.abs(back.n - n) < 1e-6 && Math.abs(back.u) < 1e-6, `${e},${n}`);
  }
  // 1 m north is ~9e-6 degrees of latitude: catches a swapped or flat-earth conversion
  const north = enuToGeodetic(d, 0, 1, 0);
  assert.ok(Math.abs(north.latDeg - d.lat_deg - 8.99e-6) < 0.05e-6, String(north.latDeg - d.lat_deg));
  assert.ok(Math.abs(north.lonDeg - d.lon_deg) < 1e-12);
  const pole = ecefToGeodetic(0, 0, 6356752.314245 + 100);
  assert.ok(Math.abs(pole.latDeg - 90) < 1e-12 && Math.abs(pole.hM - 100) < 1e-6, JSON.stringify(pole));
});

test("typed coordinate pairs", () => {
  assert.deepEqual(parsePair("12.5, -3"), [12.5, -3]);
  assert.deepEqual(parsePair(" 47.1 8.2 "), [47.1, 8.2]);
  assert.deepEqual(parsePair("1;2"), [1, 2]);
  assert.equal(parsePair("1"), null);
  assert.equal(parsePair("a, b"), null);
  assert.equal(parsePair("1, 2, 3"), null);
  assert.equal(formatLatLon(-33.5, -70.25), "33.5000000°S 70.2500000°W");
});
