// The operator's background map (`--basemap PATH` at the station): Web Mercator XYZ tiles
// served by the station, placed under the traversability map in the drawn datum's local metric
// frame. Each visible tile is an image whose corners are converted from lat/lon to map x/y
// through the datum (exact WGS-84), at the zoom level whose pixels best match the screen's.
// Without GNSS (a local datum) there is nowhere to put it, and it is hidden.

import { enuToGeodetic, geodeticToEnu, hasGeodetic } from "../geo.js";

const MAX_TILES = 64;

function tileOf(lat, lon, z) {
  const n = 2 ** z;
  const x = Math.floor(((lon + 180) / 360) * n);
  const r = (lat * Math.PI) / 180;
  const y = Math.floor(((1 - Math.log(Math.tan(r) + 1 / Math.cos(r)) / Math.PI) / 2) * n);
  return [Math.min(n - 1, Math.max(0, x)), Math.min(n - 1, Math.max(0, y))];
}

function cornerOf(z, x, y) {
  const n = 2 ** z;
  const lon = (x / n) * 360 - 180;
  const lat = (Math.atan(Math.sinh(Math.PI * (1 - (2 * y) / n))) * 180) / Math.PI;
  return [lat, lon];
}

export function initBasemap(ctx) {
  const { map, L, ll, api, state, withToken, currentDatum, logMsg } = ctx;
  map.createPane("basemapPane");
  map.getPane("basemapPane").style.zIndex = "250";
  map.getPane("basemapPane").style.pointerEvents = "none";
  let info = null;
  const shown = new Map(); // "z/x/y" -> overlay
  let shownDatum = null;
  const toggle = document.getElementById("basemap-chk");

  function clear() {
    for (const o of shown.values()) o.remove();
    shown.clear();
  }

  function update() {
    const d = currentDatum();
    if (!info || !toggle.checked || !hasGeodetic(d)) {
      clear();
      return;
    }
    if (shownDatum !== state.datumId) {
      clear();
      shownDatum = state.datumId;
    }
    // Screen pixels per metre at this zoom (CRS.Simple: 2^zoom), against Web Mercator's
    // metres per pixel at the datum's latitude.
    const pxPerM = 2 ** map.getZoom();
    const cosLat = Math.cos((d.lat_deg * Math.PI) / 180);
    let z = Math.round(Math.log2(pxPerM * 156543.03392 * cosLat));
    z = Math.max(info.min_zoom, Math.min(info.max_zoom, z));
    const b = map.getBounds().pad(0.2);
    const sw = enuToGeodetic(d, b.getWest(), b.getSouth(), 0);
    const ne = enuToGeodetic(d, b.getEast(), b.getNorth(), 0);
    const [x0, y1] = tileOf(sw.latDeg, sw.lonDeg, z);
    const [x1, y0] = tileOf(ne.latDeg, ne.lonDeg, z);
    const want = new Set();
    for (let x = x0; x <= x1; x++) {
      for (let y = y0; y <= y1; y++) {
        if (want.size >= MAX_TILES) break;
        want.add(`${z}/${x}/${y}`);
      }
    }
    for (const [k, o] of shown) {
      if (!want.has(k)) {
        o.remove();
        shown.delete(k);
      }
    }
    for (const k of want) {
      if (shown.has(k)) continue;
      const [tz, tx, ty] = k.split("/").map(Number);
      const [lat0, lon0] = cornerOf(tz, tx, ty);
      const [lat1, lon1] = cornerOf(tz, tx + 1, ty + 1);
      const nw = geodeticToEnu(d, lat0, lon0);
      const se = geodeticToEnu(d, lat1, lon1);
      const o = L.imageOverlay(withToken(`/api/basemap/${k}.${info.format}`), L.latLngBounds(ll(nw.e, se.n), ll(se.e, nw.n)), {
        pane: "basemapPane", className: "basemap-tile", interactive: false, errorOverlayUrl: "data:image/gif;base64,R0lGODlhAQABAAAAACH5BAEKAAEALAAAAAABAAEAAAICTAEAOw==",
      }).addTo(map);
      shown.set(k, o);
    }
  }

  async function load() {
    try {
      info = await api("GET", "/api/basemap");
      document.getElementById("basemap-row").classList.remove("hidden");
      document.getElementById("basemap-name").textContent = `${info.name} (z${info.min_zoom}-${info.max_zoom})`;
      update();
    } catch (e) {
      info = null;
      if (!/404/.test(e.message)) logMsg("warn", e.message);
    }
  }

  map.on("moveend zoomend", update);
  toggle.addEventListener("change", update);
  load();
  return { update, load, info: () => info, shown: () => shown.size };
}
