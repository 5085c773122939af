// terranav operator UI: Leaflet map in the local metric frame of one datum (L.CRS.Simple, 1 unit =
// 1 m, lat = y north, lng = x east), live state from the station's WebSocket, commands over REST.
// Plain ES module, no build step. See README.md for the contract with the station.

import { enuToGeodetic, geodeticToEnu, hasGeodetic, formatLatLon, parsePair } from "./geo.js";
import { robotColor } from "./ui/colors.js";
import { initAlerts } from "./ui/alerts.js";
import { initZones } from "./ui/zones.js";
import { initMissions } from "./ui/missions.js";
import { initBasemap } from "./ui/basemap.js";

/* global L */

// ---------------------------------------------------------------------------------------------
// Station access (token on every request and on the WebSocket)
// ---------------------------------------------------------------------------------------------

const TOKEN = new URLSearchParams(location.search).get("token");

/** Appends the page's token to a URL (images and the WebSocket cannot carry a header). */
function withToken(url) {
  if (!TOKEN) return url;
  return url + (url.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(TOKEN);
}

class ApiError extends Error {}

/** Request headers with the page's token. */
function headers(extra = {}) {
  const h = { Accept: "application/json", ...extra };
  if (TOKEN) h.Authorization = "Bearer " + TOKEN;
  return h;
}

/** JSON request to the station; throws ApiError with the station's `{"error"}` text on failure. */
async function api(method, path, body) {
  const headers = { Accept: "application/json" };
  if (TOKEN) headers.Authorization = "Bearer " + TOKEN;
  if (body !== undefined) headers["Content-Type"] = "application/json";
  let res;
  try {
    res = await fetch(withToken(path), {
      method,
      headers,
      body: body === undefined ? undefined : JSON.stringify(body),
      cache: "no-store",
    });
  } catch (e) {
    throw new ApiError(`${method} ${path}: station unreachable (${e.message})`);
  }
  const text = await res.text();
  let data = null;
  try {
    data = text ? JSON.parse(text) : null;
  } catch {
    data = null;
  }
  if (!res.ok) {
    const reason = data && data.error ? data.error : text || res.statusText;
    throw new ApiError(`${method} ${path}: ${res.status} ${reason}`);
  }
  return data;
}

const enc = encodeURIComponent;

// ---------------------------------------------------------------------------------------------
// State
// ---------------------------------------------------------------------------------------------

const TRAIL_MAX_POINTS = 3000;
const TRAIL_MIN_STEP_M = 0.1;
const DRIVE_PERIOD_MS = 100;
const OMEGA_MAX_RPS = 0.8;
const STALE_WARN_MS = 1500;
const STALE_BAD_MS = 5000;

// The parts initialised at the end of this module (they need the map and the helpers below).
let alerts = null;
let zones = null;
let missions = null;
let basemap = null;

const state = {
  robots: new Map(), // name -> RobotView
  datums: new Map(), // datum_id -> {datum_id, lat_deg, lon_deg, h_m, tiles, bounds_m}
  datumManual: "", // "" = follow the selected robot's datum
  datumId: null, // datum currently drawn
  tileMeta: null, // {cell_size_m, tile_cells}
  tileLayer: null, // the pyramid's L.TileLayer of the drawn datum
  tileVersions: new Map(), // "tx,ty" -> merged tile version last seen
  tileBumps: new Map(), // "level/tx/ty" -> reload counter of a changed pyramid tile
  touched: new Set(), // "tx,ty" of merged tiles changed since the last reload
  mapAt: null, // Unix ms the map is drawn as it was (a scrubbed session), or null: the live map
  mapAtTimer: null,
  touchTimer: null,
  tileLoads: [], // {t_ms, level, settled, view_m} each time the pyramid layer finished loading its visible tiles
  selected: null,
  goalMode: false,
  follow: false,
  routes: [],
  routeLayers: new Map(), // route_id -> polyline
  sessions: [],
  trackLayers: new Map(), // session_id -> {layer, datum_id, robot, points, scrubT, marker}
  wsUp: false,
  stationDownSince: null, // local ms when the station stopped answering (null: it answers)
  fittedDatum: null,
  health: null,
  readOnly: false, // a monitor station: command controls off
  mode: null, // "goal" | "zone" | "mission": what a map click does
};

/** Per-robot data and its map layers. */
function robotView(name) {
  let r = state.robots.get(name);
  if (!r) {
    r = {
      name,
      online: false,
      lastSeenMs: null,
      session: null,
      datumId: null,
      pose: null,
      status: null,
      path: [],
      pathAt: 0, // local time the path last changed
      statusAt: 0, // local time of the last status
      rates: {},
      ages: {},
      trail: [],
      marker: null,
      trailLine: null,
      pathLine: null,
      goalMarker: null,
      lastError: null,
      iconKey: "",
      card: null,
      restAt: 0, // local time of the last REST refresh of this robot
    };
    state.robots.set(name, r);
  }
  return r;
}

// ---------------------------------------------------------------------------------------------
// Map
// ---------------------------------------------------------------------------------------------

const map = L.map("map", {
  crs: L.CRS.Simple,
  minZoom: -4,
  maxZoom: 7,
  zoomSnap: 0.25,
  zoomDelta: 0.5,
  wheelPxPerZoomLevel: 90,
  keyboard: false, // arrow keys drive the robot, they must not pan the map
  attributionControl: false,
  preferCanvas: false,
});
map.setView([0, 0], 2);
L.control.scale({ imperial: false, position: "bottomright" }).addTo(map);

const panes = ["tilesPane", "tracksPane", "routesPane", "pathsPane", "robotsPane"];
panes.forEach((p, i) => {
  map.createPane(p);
  map.getPane(p).style.zIndex = String(300 + i * 10);
});
map.getPane("tilesPane").style.pointerEvents = "none";

const ll = (x, y) => L.latLng(y, x);

/** The datum record for the drawn map, or null. */
function currentDatum() {
  return state.datumId ? state.datums.get(state.datumId) || null : null;
}

/** Lat/lon text for a map point in the drawn datum, or a note why there is none. */
function latLonText(x, y) {
  const d = currentDatum();
  if (!hasGeodetic(d)) return "no GNSS datum";
  const g = enuToGeodetic(d, x, y, 0);
  return formatLatLon(g.latDeg, g.lonDeg);
}

function fmtXY(x, y) {
  return `x ${x.toFixed(2)} m, y ${y.toFixed(2)} m`;
}

const readout = document.getElementById("readout");
map.on("mousemove", (ev) => {
  const x = ev.latlng.lng;
  const y = ev.latlng.lat;
  // Two short lines: one long line ran under the scale bar on a small screen.
  readout.textContent = `${fmtXY(x, y)}\n${latLonText(x, y)}` + (state.datumId ? ` · ${state.datumId}` : "");
});

let clickPopup = null;
map.on("click", (ev) => {
  const x = ev.latlng.lng;
  const y = ev.latlng.lat;
  // Drawing a zone or a mission: the click is theirs.
  if (state.mode === "zone" || state.mode === "mission") return;
  if (state.goalMode) {
    // One click, one goal: a second stray click must not re-target the robot.
    setGoalMode(false);
    sendGoal({ x, y });
    return;
  }
  const div = document.createElement("div");
  div.className = "pt-popup";
  div.innerHTML = `<div class="mono">${fmtXY(x, y)}</div><div class="mono">${esc(latLonText(x, y))}</div>`;
  if (state.selected) {
    const b = document.createElement("button");
    b.textContent = `Send ${state.selected} here`;
    b.addEventListener("click", () => {
      map.closePopup();
      sendGoal({ x, y });
    });
    div.appendChild(b);
  }
  clickPopup = L.popup({ closeButton: true, autoPan: false }).setLatLng(ev.latlng).setContent(div).openOn(map);
});

// ----- tiles ---------------------------------------------------------------------------------
// The merged map is one L.TileLayer over the station's zoom pyramid
// (`/api/map/{datum}/pyramid/{level}/{tx}/{ty}.png`, operator-station/src/pyramid): level 0 is a
// merged tile, level L the overview of 2^L x 2^L of them, every image tile_cells pixels wide.
// In CRS.Simple (2^zoom pixels per metre) a layer tile of `side0 * 2^z0` pixels covers one merged
// tile (side0 metres) at zoom z0, and 2^L of them at zoom z0 - L: Leaflet's tile coordinates at
// zoom z are the pyramid's at level z0 - z (y flipped: Leaflet's rows grow southwards).
// Beyond z0 Leaflet scales level 0 up; below z0 - PYRAMID_MAX_LEVEL it scales the top down.

const PYRAMID_MAX_LEVEL = 10;
/** Transparent 1x1 GIF for tiles without map beneath (the station answers 404). */
const EMPTY_TILE = "data:image/gif;base64,R0lGODlhAQABAAAAACH5BAEKAAEALAAAAAABAAEAAAICTAEAOw==";
let tileBumps = 0; // makes a changed tile's URL new, so that the browser loads it again

/** Native zoom of level 0 and the layer's tile size in pixels for this lattice. */
function pyramidGeometry(meta) {
  const side0 = meta.tile_cells * meta.cell_size_m;
  // Layer tiles of 128-256 screen pixels at their native zoom: few requests, little upscaling.
  const z0 = Math.max(0, Math.ceil(Math.log2(128 / side0)));
  return { side0, z0, tileSize: side0 * 2 ** z0 };
}

/** Pyramid level and tile of Leaflet tile coordinates {x, y, z} (z clamped to the native range). */
function pyramidIndex(layer, coords) {
  return { level: layer.options.z0 - coords.z, tx: coords.x, ty: -coords.y - 1 };
}

const PyramidLayer = L.TileLayer.extend({
  createTile(coords, done) {
    const img = L.TileLayer.prototype.createTile.call(this, coords, done);
    img.classList.add("map-tile");
    return img;
  },
  getTileUrl(coords) {
    const { level, tx, ty } = pyramidIndex(this, coords);
    if (state.mapAt !== null) {
      return withToken(`/api/map/${enc(this.options.datumId)}/history/${state.mapAt}/${level}/${tx}/${ty}.png`);
    }
    const bump = state.tileBumps.get(`${level}/${tx}/${ty}`);
    const url = `/api/map/${enc(this.options.datumId)}/pyramid/${level}/${tx}/${ty}.png` + (bump ? `?v=${bump}` : "");
    return withToken(url);
  },
});

/** The map's extent in metres as Leaflet bounds (tiles outside are never asked for). */
function boundsOf(b) {
  return L.latLngBounds(ll(b[0], b[1]), ll(b[2], b[3]));
}

/** Draws the pyramid of the drawn datum (once its lattice is known). */
function showPyramid(bounds) {
  const g = pyramidGeometry(state.tileMeta);
  state.tileLayer = new PyramidLayer("", {
    datumId: state.datumId,
    z0: g.z0,
    tileSize: g.tileSize,
    maxNativeZoom: g.z0,
    minNativeZoom: g.z0 - PYRAMID_MAX_LEVEL,
    // A GridLayer hides itself outside [minZoom, maxZoom] (default [0, 18]); the map goes to -4.
    minZoom: map.getMinZoom(),
    maxZoom: map.getMaxZoom(),
    bounds,
    pane: "tilesPane",
    errorTileUrl: EMPTY_TILE,
    updateWhenZooming: false,
    keepBuffer: 1,
  }).addTo(map);
  // When every visible tile has loaded (ms since the page's navigation start, and the level):
  // the browser test's "first full view", also handy in the console.
  const layer = state.tileLayer;
  layer.on("load", () => {
    if (state.tileLayer !== layer) return;
    const b = map.getBounds();
    // settled: the loaded tiles are those of the map's zoom (not the last ones of a zoom change)
    const settled = layer._tileZoom === layer._clampZoom(Math.round(map.getZoom()));
    state.tileLoads.push({ t_ms: performance.now(), level: g.z0 - layer._tileZoom, settled, view_m: [b.getWest(), b.getSouth(), b.getEast(), b.getNorth()] });
  });
}

/** Draws the pyramid layer again from scratch (another time of the map). A new layer rather than
 * `redraw()`: Leaflet 1.9's GridLayer.redraw takes the map's zoom unrounded as the tile zoom, so at
 * a fractional zoom it asks for tiles of level 2.75. */
function reloadPyramid() {
  const old = state.tileLayer;
  if (!old || !state.tileMeta) return;
  const bounds = old.options.bounds;
  old.remove();
  state.tileLayer = null;
  showPyramid(bounds);
}

/** Merged tile (tx, ty) changed: the shown pyramid tile above it is loaded again (coalesced). */
function touchTile(tx, ty) {
  const layer = state.tileLayer;
  if (!layer || !state.tileMeta) return;
  // A tile outside the drawn extent: grow it, so that the layer asks for the new area.
  const side = state.tileMeta.tile_cells * state.tileMeta.cell_size_m;
  const tb = boundsOf([tx * side, ty * side, (tx + 1) * side, (ty + 1) * side]);
  if (!layer.options.bounds || !layer.options.bounds.contains(tb)) {
    layer.options.bounds = layer.options.bounds ? L.latLngBounds(layer.options.bounds).extend(tb) : tb;
    if (layer._map) layer._update(); // Leaflet has no public "bounds changed"
  }
  state.touched.add(`${tx},${ty}`);
  if (!state.touchTimer) state.touchTimer = setTimeout(flushTouched, 250);
}

function flushTouched() {
  state.touchTimer = null;
  const layer = state.tileLayer;
  const touched = [...state.touched];
  state.touched.clear();
  // A past map does not change; the live one is drawn again when the scrub ends.
  if (state.mapAt !== null) return;
  const z = layer && layer._tileZoom;
  if (z === undefined) return;
  const level = layer.options.z0 - z;
  const done = new Set();
  for (const key of touched) {
    const [tx, ty] = key.split(",").map(Number);
    const [px, py] = [Math.floor(tx / 2 ** level), Math.floor(ty / 2 ** level)];
    const id = `${level}/${px}/${py}`;
    if (done.has(id)) continue;
    done.add(id);
    state.tileBumps.set(id, ++tileBumps);
    const coords = L.point(px, -py - 1);
    coords.z = z;
    const t = layer._tiles[layer._tileCoordsToKey(coords)];
    if (t && t.el) t.el.src = layer.getTileUrl(coords);
  }
}

function clearTiles() {
  if (state.tileLayer) state.tileLayer.remove();
  state.tileLayer = null;
  state.tileVersions.clear();
  state.tileBumps.clear();
  state.touched.clear();
}

/** Reloads the tile index of the drawn datum (on connect, datum switch, and as a slow safety net
 *  for missed live events: a tile whose version moved is loaded again). */
async function refreshTiles() {
  const datumId = state.datumId;
  if (!datumId) return;
  try {
    const idx = await api("GET", `/api/map/${enc(datumId)}/tiles`);
    if (state.datumId !== datumId) return;
    if (!state.tileMeta || state.tileMeta.cell_size_m !== idx.cell_size_m || state.tileMeta.tile_cells !== idx.tile_cells) {
      clearTiles();
      state.tileMeta = { cell_size_m: idx.cell_size_m, tile_cells: idx.tile_cells };
    }
    if (!state.tileLayer) {
      const side = idx.tile_cells * idx.cell_size_m;
      let b = null;
      for (const t of idx.tiles) {
        state.tileVersions.set(`${t.tx},${t.ty}`, t.version);
        const tb = boundsOf([t.tx * side, t.ty * side, (t.tx + 1) * side, (t.ty + 1) * side]);
        b = b ? b.extend(tb) : tb;
      }
      showPyramid(b || undefined);
      return;
    }
    for (const t of idx.tiles) upsertTile(t.tx, t.ty, t.version);
  } catch (e) {
    logMsg("warn", e.message);
  }
}

/** Merged tile (tx, ty) is now at `version` (live event or index). */
function upsertTile(tx, ty, version) {
  const key = `${tx},${ty}`;
  if ((state.tileVersions.get(key) ?? -1) >= version) return;
  state.tileVersions.set(key, version);
  touchTile(tx, ty);
}

/** Switches the drawn datum: tiles, robots, tracks and routes of other datums are hidden. */
function setDatum(datumId) {
  if (datumId === state.datumId) return;
  state.datumId = datumId;
  clearTimeout(state.mapAtTimer);
  state.mapAt = null;
  clearTiles();
  state.tileMeta = null;
  // Trails stay: they are in their robot's datum, and come back when that datum is drawn again.
  for (const r of state.robots.values()) redrawRobot(r);
  for (const [id, t] of state.trackLayers) {
    if (t.datum_id !== datumId) {
      t.layer.remove();
      if (t.marker) t.marker.remove();
      state.trackLayers.delete(id);
    }
  }
  for (const [id, layer] of state.routeLayers) {
    const rt = state.routes.find((x) => x.route_id === id);
    if (!rt || rt.datum_id !== datumId) {
      layer.remove();
      state.routeLayers.delete(id);
    }
  }
  renderDatumInfo();
  renderRoutes();
  renderSessions();
  refreshTiles();
  maybeFit();
  if (zones) zones.refresh();
  if (missions) missions.onDatum();
  if (basemap) basemap.update();
}

/** Picks the datum to draw: the operator's choice, else the selected robot's, else the first known. */
function chooseDatum() {
  let want = state.datumManual || null;
  if (!want && state.selected) want = robotView(state.selected).datumId;
  if (!want) {
    for (const r of state.robots.values()) if (r.datumId) { want = r.datumId; break; }
  }
  if (!want && state.datums.size) want = [...state.datums.keys()][0];
  if (want) setDatum(want);
}

function maybeFit() {
  if (!state.datumId || state.fittedDatum === state.datumId) return;
  const d = state.datums.get(state.datumId);
  const sel = state.selected ? robotView(state.selected) : null;
  if (sel && sel.pose && sel.datumId === state.datumId) {
    map.setView(ll(sel.pose.x_m, sel.pose.y_m), 3);
    state.fittedDatum = state.datumId;
  } else if (d && d.bounds_m && d.tiles > 0) {
    fitDatum();
    state.fittedDatum = state.datumId;
  }
}

function fitDatum() {
  const d = currentDatum();
  if (d && d.bounds_m) {
    const [x0, y0, x1, y1] = d.bounds_m;
    map.fitBounds(L.latLngBounds(ll(x0, y0), ll(x1, y1)), { padding: [20, 20], maxZoom: 4 });
  }
}

// ----- robots on the map ------------------------------------------------------------------------

function iconKey(r) {
  return `${r.name === state.selected}|${r.online && !state.stationDownSince}`;
}

function robotIcon(r) {
  const selected = r.name === state.selected;
  const online = r.online && !state.stationDownSince;
  r.iconKey = iconKey(r);
  return L.divIcon({
    className: "robot-icon",
    iconSize: [34, 34],
    iconAnchor: [17, 17],
    html:
      `<div class="robot-marker${selected ? " selected" : ""}${online ? "" : " offline"}" data-robot="${esc(r.name)}" data-online="${online}" style="--robot: ${robotColor(r.name)}">` +
      `<svg viewBox="-17 -17 34 34" width="34" height="34"><g class="arrow">` +
      `<circle r="13" class="ring"/><path d="M 12 0 L -8 -8 L -4 0 L -8 8 Z" class="body"/></g></svg>` +
      `<span class="robot-label">${esc(r.name)}</span></div>`,
  });
}

function setMarkerHeading(r) {
  const el = r.marker && r.marker.getElement();
  if (!el || !r.pose) return;
  const g = el.querySelector("g.arrow");
  // yaw is counter-clockwise from east; SVG rotation is clockwise on screen.
  if (g) g.setAttribute("transform", `rotate(${(-r.pose.yaw_rad * 180) / Math.PI})`);
}

/** Creates/updates/removes the robot's marker, trail, path and goal for the drawn datum. */
function redrawRobot(r) {
  const visible = r.pose && r.datumId && r.datumId === state.datumId;
  if (!visible) {
    for (const k of ["marker", "trailLine", "pathLine", "goalMarker"]) {
      if (r[k]) { r[k].remove(); r[k] = null; }
    }
    return;
  }
  const pos = ll(r.pose.x_m, r.pose.y_m);
  if (!r.marker) {
    r.marker = L.marker(pos, { icon: robotIcon(r), pane: "robotsPane", keyboard: false, zIndexOffset: 1000 })
      .addTo(map)
      .on("click", () => selectRobot(r.name));
    r.marker.bindTooltip(() => robotTooltip(r), { direction: "top", offset: [0, -14] });
  } else {
    r.marker.setLatLng(pos);
    // Online, offline and selection change the icon: a marker left grey after a restart
    // told the operator an online robot was gone.
    if (r.iconKey !== iconKey(r)) r.marker.setIcon(robotIcon(r));
  }
  setMarkerHeading(r);
  const color = robotColor(r.name);

  if (!r.trailLine) {
    r.trailLine = L.polyline([], { pane: "tracksPane", className: "robot-trail", color, interactive: false }).addTo(map);
  }
  r.trailLine.setLatLngs(r.trail.map(([x, y]) => ll(x, y)));

  // A path older than a status saying the mission is over is history, not a plan.
  const over = r.status && !isActiveMission(r.status.mission) && r.statusAt > r.pathAt;
  if (r.path && r.path.length >= 2 && !over) {
    const pts = r.path.map(([x, y]) => ll(x, y));
    if (!r.pathLine) {
      r.pathLine = L.polyline(pts, { pane: "pathsPane", className: "robot-path", color, interactive: false }).addTo(map);
    } else {
      r.pathLine.setLatLngs(pts);
    }
  } else if (r.pathLine) {
    r.pathLine.remove();
    r.pathLine = null;
  }

  // The goal stays on the map when there is no path to it (marked failed), so the operator
  // sees where the robot gave up.
  const goal = r.status && r.status.goal_m && isActiveMission(r.status.mission) ? r.status.goal_m : null;
  if (goal) {
    const g = ll(goal[0], goal[1]);
    const failed = r.status.mission === "NoPath";
    const key = `${failed}`;
    if (r.goalMarker && r.goalMarker.key !== key) {
      r.goalMarker.remove();
      r.goalMarker = null;
    }
    if (!r.goalMarker) {
      r.goalMarker = L.marker(g, {
        pane: "pathsPane",
        keyboard: false,
        icon: L.divIcon({
          className: "goal-icon", iconSize: [22, 22], iconAnchor: [11, 11],
          html: `<div class="goal-marker${failed ? " failed" : ""}" data-robot="${esc(r.name)}" data-state="${failed ? "no-path" : "active"}" style="--robot: ${robotColor(r.name)}">${failed ? "✖" : "⚑"}</div>`,
        }),
      }).addTo(map);
      r.goalMarker.key = key;
      r.goalMarker.bindTooltip(() => {
        const gm = r.status && r.status.goal_m;
        const why = r.status && r.status.mission === "NoPath" ? `<br><b>no path</b>: ${esc(r.status.reason)}` : "";
        return gm ? `${esc(r.name)} goal<br>${fmtXY(gm[0], gm[1])}<br>${esc(latLonText(gm[0], gm[1]))}${why}` : "";
      });
    } else {
      r.goalMarker.setLatLng(g);
    }
  } else if (r.goalMarker) {
    r.goalMarker.remove();
    r.goalMarker = null;
  }
}

function isActiveMission(m) {
  return m === "Planning" || m === "Driving" || m === "Blocked" || m === "Paused" || m === "NoPath";
}

function robotTooltip(r) {
  if (!r.pose) return esc(r.name);
  const p = r.pose;
  return `<b>${esc(r.name)}</b><br>${fmtXY(p.x_m, p.y_m)}<br>${esc(latLonText(p.x_m, p.y_m))}<br>` +
    `v ${Number(p.v_mps).toFixed(2)} m/s · yaw ${((p.yaw_rad * 180) / Math.PI).toFixed(0)}°`;
}

function onPose(name, datumId, pose) {
  const r = robotView(name);
  if (datumId && r.datumId !== datumId) {
    r.datumId = datumId;
    r.trail = [];
  }
  r.pose = pose;
  r.online = true;
  r.lastSeenMs = Date.now();
  const last = r.trail[r.trail.length - 1];
  if (!last || Math.hypot(pose.x_m - last[0], pose.y_m - last[1]) >= TRAIL_MIN_STEP_M) {
    r.trail.push([pose.x_m, pose.y_m]);
    if (r.trail.length > TRAIL_MAX_POINTS) r.trail.splice(0, r.trail.length - TRAIL_MAX_POINTS);
  }
  if (!state.selected) selectRobot(name);
  if (!state.datumId) chooseDatum();
  redrawRobot(r);
  if (r.name === state.selected) {
    maybeFit();
    if (state.follow) followRobot(r);
  }
}

function followRobot(r) {
  if (!r.pose || r.datumId !== state.datumId) return;
  const p = ll(r.pose.x_m, r.pose.y_m);
  const inner = map.getBounds().pad(-0.25);
  if (!inner.contains(p)) map.panTo(p, { animate: true, duration: 0.3 });
}

// ---------------------------------------------------------------------------------------------
// Robot list and health
// ---------------------------------------------------------------------------------------------

const robotList = document.getElementById("robot-list");

function esc(s) {
  return String(s ?? "").replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);
}

function fmtAge(ms) {
  if (ms === null || ms === undefined || !Number.isFinite(ms)) return "–";
  if (ms < 1000) return `${Math.round(ms)} ms`;
  if (ms < 120000) return `${(ms / 1000).toFixed(1)} s`;
  if (ms < 7200000) return `${Math.round(ms / 60000)} min`;
  return `${(ms / 3600000).toFixed(1)} h`;
}

function ageClass(ms) {
  if (ms === null || ms === undefined || !Number.isFinite(ms)) return "bad";
  if (ms > STALE_BAD_MS) return "bad";
  if (ms > STALE_WARN_MS) return "warn";
  return "ok";
}

const FIX_CLASS = { RtkFixed: "ok", RtkFloat: "warn", Dgps: "warn", Single: "warn", NoFix: "bad" };
const MISSION_CLASS = {
  Idle: "muted", Planning: "info", Driving: "ok", Blocked: "warn", NoPath: "bad", Reached: "ok", Stopped: "bad", Paused: "warn",
};

/** One robot's card, built once: later renders only change its text and classes, so a click
 * that lands between two renders still hits the card it was aimed at (the list used to be
 * rebuilt ~3 times a second and lost about a third of the clicks). */
function makeCard(name) {
  const el = document.createElement("div");
  el.className = "robot-card";
  el.dataset.robot = name;
  el.tabIndex = 0;
  el.style.setProperty("--robot", robotColor(name));
  el.innerHTML = `
    <div class="robot-head">
      <span class="dot" data-field="dot"></span>
      <span class="swatch" title="this robot's colour on the map"></span>
      <span class="robot-name">${esc(name)}</span>
      <span class="muted small" data-field="seen"></span>
      <span class="rec hidden" data-field="rec" title="recording a route">● REC</span>
    </div>
    <div class="kv"><span>state</span><span><b data-field="mission"></b> <span class="muted" data-field="reason"></span> <span class="muted" data-field="mode"></span></span></div>
    <div data-field="run"></div>
    <div class="details">
      <div class="kv"><span>GNSS</span><span data-field="fix"></span></div>
      <div class="kv"><span>SLAM</span><span data-field="slam"></span></div>
      <div class="kv"><span>speed</span><span data-field="speed"></span></div>
      <div class="kv" data-field="zone-row"><span>zone</span><span data-field="zone"></span></div>
      <div class="kv" data-field="route-row"><span>route</span><span data-field="route"></span></div>
      <div class="ages" data-field="ages"></div>
      <div class="counters" data-field="counters"></div>
    </div>
    <div class="robot-error hidden" data-field="error" title="last error reported by the robot"></div>`;
  return el;
}

function setText(card, field, text, cls) {
  const e = card.querySelector(`[data-field="${field}"]`);
  if (!e) return;
  if (e.textContent !== text) e.textContent = text;
  if (cls !== undefined && e.className !== cls) e.className = cls;
}

function setHtml(card, field, html) {
  const e = card.querySelector(`[data-field="${field}"]`);
  if (e && e.dataset.html !== html) {
    e.innerHTML = html;
    e.dataset.html = html;
  }
}

function renderRobots() {
  const names = [...state.robots.keys()].sort();
  const down = state.stationDownSince !== null;
  document.getElementById("robot-count").textContent = names.length
    ? down ? `(${names.length}, state unknown)` : `(${names.filter((n) => state.robots.get(n).online).length}/${names.length} online)`
    : "";
  document.getElementById("stop-all-scope").textContent = `${names.length} robot${names.length === 1 ? "" : "s"}`;
  if (!names.length) {
    if (!robotList.querySelector(".muted")) robotList.innerHTML = `<div class="muted">waiting for robots…</div>`;
    return;
  }
  const placeholder = robotList.querySelector(":scope > .muted");
  if (placeholder) placeholder.remove();
  const now = Date.now();
  // With many robots only the selected card shows its details: the command panel stays in reach.
  const compact = names.length > 4;
  names.forEach((n, i) => {
    const r = state.robots.get(n);
    if (!r.card) r.card = makeCard(n);
    const card = r.card;
    if (robotList.children[i] !== card) robotList.insertBefore(card, robotList.children[i] || null);
    const s = r.status;
    card.classList.toggle("selected", n === state.selected);
    card.classList.toggle("offline", !r.online);
    card.classList.toggle("stale", down);
    card.classList.toggle("compact", compact && n !== state.selected);
    // While the station is unreachable nothing here is known to be current: say so, and let
    // the ages grow instead of showing the last fresh ones.
    const since = down ? now - state.stationDownSince : 0;
    const seen = r.lastSeenMs ? Math.max(0, now - r.lastSeenMs) : null;
    setText(card, "dot", "", `dot ${down ? "muted" : r.online ? "ok" : "bad"}`);
    setText(card, "seen", down
      ? `station unreachable for ${fmtAge(since)} · last known ${r.online ? "online" : "offline"}`
      : `${r.online ? "online" : "offline"} · ${seen === null ? "never seen" : fmtAge(seen) + " ago"}`);
    card.querySelector('[data-field="rec"]').classList.toggle("hidden", !(s && s.recording));
    const mission = s ? s.mission : "–";
    setText(card, "mission", mission, MISSION_CLASS[mission] || "");
    setText(card, "reason", s && s.reason ? s.reason : "");
    setText(card, "mode", s ? `(${s.mode})` : "");
    setHtml(card, "run", missions ? missions.cardLine(n) : "");
    const fix = (r.pose && r.pose.fix) || (s && s.fix) || "NoFix";
    setText(card, "fix", `${fix}${s && s.gnss_lost ? " · LOST" : ""}`, FIX_CLASS[fix] || "");
    const slam = s ? s.slam : null;
    setText(card, "slam", !slam ? "–" : slam.ok ? `ok ${Math.round(slam.inlier_ratio * 100)}%${slam.degenerate ? " degenerate" : ""}` : `FAIL (${slam.failures})`,
      !slam ? "muted" : slam.ok && !slam.degenerate ? "ok" : slam.ok ? "warn" : "bad");
    setText(card, "speed", `${r.pose ? Number(r.pose.v_mps).toFixed(2) : "–"} m/s${s ? ` · limit ${Number(s.speed_limit_mps).toFixed(2)}` : ""}${s && s.speed_max_mps ? ` (max ${Number(s.speed_max_mps).toFixed(2)})` : ""}${s && s.scan_hz ? ` · scan ${s.scan_hz.toFixed(1)} Hz` : ""}`);
    card.querySelector('[data-field="zone-row"]').classList.toggle("hidden", !(s && s.zone));
    setText(card, "zone", s && s.zone ? s.zone : "");
    card.querySelector('[data-field="route-row"]').classList.toggle("hidden", !(s && s.route));
    setText(card, "route", s && s.route ? `${s.route.name || s.route.route_id} ${s.route.waypoint}/${s.route.waypoints} · ${Number(s.route.distance_left_m).toFixed(1)} m left${s.route.detours ? ` · ${s.route.detours} detours` : ""}` : "");
    setHtml(card, "ages", ["pose", "status", "tile"].map((k) => {
      const a0 = r.ages ? r.ages[k] : undefined;
      const a = down && Number.isFinite(a0) ? a0 + (now - r.restAt) : a0;
      const hz = !down && r.rates && Number.isFinite(r.rates[k]) ? ` ${r.rates[k].toFixed(1)}Hz` : "";
      return `<span class="age ${down ? "muted" : ageClass(a)}" title="${k}: last message age and rate">${k} ${fmtAge(a)}${hz}</span>`;
    }).join(""));
    setHtml(card, "counters", s ? [
      s.collisions ? `<span class="bad">collisions ${s.collisions}</span>` : "",
      s.commands_refused ? `<span class="warn">refused ${s.commands_refused}</span>` : "",
      s.decode_errors ? `<span class="warn">decode err ${s.decode_errors}</span>` : "",
    ].filter(Boolean).join(" ") : "");
    const errEl = card.querySelector('[data-field="error"]');
    errEl.classList.toggle("hidden", !(s && s.last_error));
    setText(card, "error", s && s.last_error ? `⚠ ${s.last_error}` : "");
  });
  for (const el of [...robotList.querySelectorAll(".robot-card")]) {
    if (!state.robots.has(el.dataset.robot)) el.remove();
  }
}

robotList.addEventListener("click", (ev) => {
  const act = ev.target.closest("button[data-mission-act]");
  const card = ev.target.closest(".robot-card");
  if (act && card && missions) {
    missions.runAction(card.dataset.robot, act.dataset.missionAct);
    return;
  }
  if (card) selectRobot(card.dataset.robot);
});

function selectRobot(name) {
  if (state.selected === name) return;
  const prev = state.selected ? state.robots.get(state.selected) : null;
  state.selected = name;
  for (const r of [prev, robotView(name)]) {
    if (r && r.marker) r.marker.setIcon(robotIcon(r)), setMarkerHeading(r);
  }
  document.getElementById("cmd-robot").textContent = name;
  document.getElementById("goal-banner-robot").textContent = name;
  // The STOP button says whom it stops, in that robot's colour: only the selected robot.
  const stopBtn = document.getElementById("stop-btn");
  document.getElementById("stop-scope").textContent = `${name} only`;
  stopBtn.style.setProperty("--robot", robotColor(name));
  stopBtn.title = `Stop ${name} only (Space). STOP ALL stops every robot (Shift+Space).`;
  stopBtn.dataset.robot = name;
  const r = robotView(name);
  if (r.status) syncSpeedSlider(r.status);
  if (!state.datumManual) {
    if (r.datumId) setDatum(r.datumId);
    else chooseDatum();
  }
  renderRobots();
  renderSessions();
  refreshSessions();
  updateRecordButton();
}

// ---------------------------------------------------------------------------------------------
// Log and toasts (errors are never swallowed)
// ---------------------------------------------------------------------------------------------

const logEl = document.getElementById("log");
const toastsEl = document.getElementById("toasts");

function logMsg(level, text, toast = level === "error") {
  const li = document.createElement("li");
  li.className = level;
  const t = new Date();
  li.innerHTML = `<span class="ts">${t.toTimeString().slice(0, 8)}</span> ${esc(text)}`;
  logEl.prepend(li);
  while (logEl.children.length > 200) logEl.lastChild.remove();
  if (level === "error" || level === "warn") console.warn(text);
  if (toast) showToast(level, text);
}

function showToast(level, text) {
  const div = document.createElement("div");
  div.className = `toast ${level}`;
  div.textContent = text;
  div.title = "click to dismiss";
  div.addEventListener("click", () => div.remove());
  toastsEl.prepend(div);
  while (toastsEl.children.length > 5) toastsEl.lastChild.remove();
  setTimeout(() => div.remove(), level === "error" ? 12000 : 4000);
}

/** A robot-side error, from WS `error` or from `status.last_error`: logged and popped once when
 * it changes, never again for the same text (it used to pop every 30 s for as long as the robot
 * kept reporting it). */
function robotError(name, message, toast = true) {
  const r = robotView(name);
  if (!message) {
    r.lastError = null;
    return;
  }
  if (r.lastError === message) return;
  r.lastError = message;
  logMsg("error", `${name}: ${message}`, toast);
}

document.getElementById("log-clear").addEventListener("click", () => (logEl.innerHTML = ""));

// ---------------------------------------------------------------------------------------------
// Commands
// ---------------------------------------------------------------------------------------------

async function command(name, what, body, { quiet = false } = {}) {
  if (state.readOnly) {
    logMsg("warn", "monitor (read-only): no commands from here", true);
    return false;
  }
  if (!name) {
    logMsg("warn", "select a robot first", true);
    return false;
  }
  try {
    await api("POST", `/api/robots/${enc(name)}/${what}`, body);
    if (!quiet) logMsg("info", `${name}: ${what} ${summarize(body)} sent`);
    return true;
  } catch (e) {
    logMsg("error", e.message);
    return false;
  }
}

function summarize(body) {
  if (!body) return "";
  if (body.action) return body.action + (body.direction ? ` ${body.direction}` : "") + (body.name ? ` "${body.name}"` : "");
  if ("x" in body) return `(${body.x.toFixed(2)}, ${body.y.toFixed(2)})`;
  if ("lat" in body) return `(${body.lat.toFixed(7)}, ${body.lon.toFixed(7)})`;
  if ("limit_mps" in body) return `${body.limit_mps} m/s`;
  return "";
}

let pendingGoal = null;

/**
 * Sends a goal to the selected robot. `target` is {x, y} in the drawn map (`frame: "map"`, a click),
 * {x, y} in the robot's own frame (`frame: "robot"`, typed), or {lat, lon}.
 */
async function sendGoal(target, frame = "map") {
  const name = state.selected;
  if (!name) {
    logMsg("warn", "select a robot first", true);
    return;
  }
  const r = robotView(name);
  const sameFrame = !r.datumId || !state.datumId || r.datumId === state.datumId;
  let body;
  let xy = null; // where to mark the goal in the drawn map
  if ("x" in target && (frame === "robot" || sameFrame)) {
    body = { x: target.x, y: target.y };
    if (sameFrame) xy = [target.x, target.y];
  } else if ("x" in target) {
    // The drawn map is another datum than the robot's: map x,y would land somewhere else in the
    // robot's frame. Through lat/lon the point is the same on the ground; without GNSS, refuse.
    const d = currentDatum();
    if (!hasGeodetic(d)) {
      logMsg("error", `goal refused: the map shows ${state.datumId} but ${name} is in ${r.datumId}; switch the map datum`);
      return;
    }
    const g = enuToGeodetic(d, target.x, target.y, 0);
    body = { lat: g.latDeg, lon: g.lonDeg };
    xy = [target.x, target.y];
  } else {
    body = { lat: target.lat, lon: target.lon };
    const d = currentDatum();
    if (hasGeodetic(d)) {
      const e = geodeticToEnu(d, target.lat, target.lon);
      xy = [e.e, e.n];
    }
  }
  if (pendingGoal) pendingGoal.remove();
  if (xy) {
    pendingGoal = L.circleMarker(ll(xy[0], xy[1]), { pane: "pathsPane", radius: 7, className: "pending-goal" })
      .bindTooltip(`goal sent<br>${fmtXY(xy[0], xy[1])}<br>${esc(latLonText(xy[0], xy[1]))}`)
      .addTo(map);
    const pg = pendingGoal;
    setTimeout(() => { if (pendingGoal === pg) { pg.remove(); pendingGoal = null; } }, 5000);
  }
  await command(name, "goal", body);
}

async function stopRobot(name, reason) {
  await command(name, "stop", { reason });
}

document.getElementById("stop-btn").addEventListener("click", () => {
  // The button says whom it stops; with no robot selected there is no one to stop.
  if (state.selected) stopRobot(state.selected, "operator STOP button");
  else logMsg("warn", "no robot selected: STOP ALL stops every robot", true);
});
document.getElementById("stop-all-btn").addEventListener("click", stopAll);
function stopAll() {
  const names = [...state.robots.keys()].filter((n) => state.robots.get(n).online);
  if (!names.length) logMsg("warn", "no online robots to stop", true);
  for (const n of names) stopRobot(n, "operator STOP ALL");
}

// goal mode
const goalBtn = document.getElementById("goal-mode-btn");
function setGoalMode(on) {
  if (on) {
    if (zones && zones.drawing()) zones.cancel();
    if (missions && missions.adding()) missions.stopAdding();
  }
  state.goalMode = on && !!state.selected;
  if (on && !state.selected) logMsg("warn", "select a robot first", true);
  goalBtn.classList.toggle("active", state.goalMode);
  document.getElementById("goal-banner").classList.toggle("hidden", !state.goalMode);
  document.getElementById("map").classList.toggle("goal-cursor", state.goalMode);
}
goalBtn.addEventListener("click", () => setGoalMode(!state.goalMode));

document.getElementById("goal-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  const kind = document.getElementById("goal-kind").value;
  const pair = parsePair(document.getElementById("goal-input").value);
  if (!pair) {
    logMsg("error", "goal: type two numbers, e.g. \"12.5, -3\"");
    return;
  }
  if (kind === "xy") {
    // Typed x,y are in the robot's own map frame (what its status and logs show).
    sendGoal({ x: pair[0], y: pair[1] }, "robot");
  } else {
    const [lat, lon] = pair;
    if (Math.abs(lat) > 90 || Math.abs(lon) > 180) {
      logMsg("error", "goal: latitude must be within ±90°, longitude within ±180°");
      return;
    }
    sendGoal({ lat, lon });
  }
});

// follow
const followChk = document.getElementById("follow-chk");
followChk.addEventListener("change", () => {
  state.follow = followChk.checked;
  if (state.follow && state.selected) followRobot(robotView(state.selected));
});

// speed limit
const speedSlider = document.getElementById("speed-slider");
const speedValue = document.getElementById("speed-value");
let speedDragging = false;
speedSlider.addEventListener("input", () => {
  speedDragging = true;
  speedValue.textContent = `${Number(speedSlider.value).toFixed(2)} m/s`;
});
speedSlider.addEventListener("change", async () => {
  speedDragging = false;
  await command(state.selected, "speed", { limit_mps: Number(speedSlider.value) });
});
/** The slider offers what the robot can do: up to its own top speed (it used to offer 2 m/s to a
 * robot capped at 0.5, and snap back in silence). */
function syncSpeedSlider(s) {
  const max = Number(s.speed_max_mps);
  if (Number.isFinite(max) && max > 0) {
    if (Number(speedSlider.max) !== max) speedSlider.max = String(max);
    document.getElementById("speed-max").textContent = `max ${max.toFixed(2)}`;
  }
  const limit = Number(s.speed_limit_mps);
  if (speedDragging || !Number.isFinite(limit) || limit <= 0) return;
  speedSlider.value = String(limit);
  speedValue.textContent = `${limit.toFixed(2)} m/s`;
}

// pause / resume / cancel
for (const action of ["pause", "resume", "cancel"]) {
  document.getElementById(`${action}-btn`).addEventListener("click", () => command(state.selected, "route", { action }));
}

// recording
const recordBtn = document.getElementById("record-btn");
function isRecording() {
  const r = state.selected ? state.robots.get(state.selected) : null;
  return !!(r && r.status && r.status.recording);
}
function updateRecordButton() {
  const rec = isRecording();
  recordBtn.textContent = rec ? "■ Stop recording" : "● Record";
  recordBtn.classList.toggle("recording", rec);
  document.getElementById("record-name").disabled = rec || state.readOnly;
}
document.getElementById("record-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  if (isRecording()) {
    await command(state.selected, "route", { action: "stop_recording" });
  } else {
    const input = document.getElementById("record-name");
    const name = input.value.trim() || `route ${new Date().toISOString().slice(0, 16).replace("T", " ")}`;
    await command(state.selected, "route", { action: "record", name });
  }
});

// ---------------------------------------------------------------------------------------------
// Keyboard drive with deadman: commands flow every 100 ms while a key is held; release -> stop.
// ---------------------------------------------------------------------------------------------

const DRIVE_KEYS = {
  ArrowUp: "fwd", KeyW: "fwd", ArrowDown: "back", KeyS: "back", ArrowLeft: "left", KeyA: "left", ArrowRight: "right", KeyD: "right",
};
const held = new Set();
let driveTimer = null;
let driveSeq = 0;
let driveErrorAt = 0;
const hud = document.getElementById("drive-hud");

function driveVector() {
  const limit = Number(speedSlider.value) || 0.5;
  const f = (held.has("fwd") ? 1 : 0) - (held.has("back") ? 1 : 0);
  const t = (held.has("left") ? 1 : 0) - (held.has("right") ? 1 : 0);
  return { v_mps: f * limit, omega_rps: t * OMEGA_MAX_RPS };
}

async function driveTick() {
  const name = state.selected;
  if (!name) return;
  const v = driveVector();
  driveSeq++;
  hud.textContent = `DRIVE ${name} · v ${v.v_mps.toFixed(2)} m/s · ω ${v.omega_rps.toFixed(2)} rad/s`;
  try {
    await api("POST", `/api/robots/${enc(name)}/drive`, { v_mps: v.v_mps, omega_rps: v.omega_rps, deadman: true });
  } catch (e) {
    // Every 100 ms would flood the log; one toast per 2 s is enough to be seen.
    if (Date.now() - driveErrorAt > 2000) {
      driveErrorAt = Date.now();
      logMsg("error", e.message);
    }
  }
}

function driveStart() {
  if (!state.selected) {
    logMsg("warn", "select a robot first", true);
    held.clear();
    return;
  }
  if (driveTimer) return;
  hud.classList.remove("hidden");
  driveTick();
  driveTimer = setInterval(driveTick, DRIVE_PERIOD_MS);
}

function driveRelease() {
  if (!driveTimer) return;
  clearInterval(driveTimer);
  driveTimer = null;
  hud.classList.add("hidden");
  const name = state.selected;
  // Explicit zero command with the deadman released, so the robot stops at once instead of
  // waiting for its 300 ms silence timeout.
  if (name) {
    api("POST", `/api/robots/${enc(name)}/drive`, { v_mps: 0, omega_rps: 0, deadman: false }).catch((e) => logMsg("error", e.message));
  }
}

function typingInField(ev) {
  const t = ev.target;
  return t && (t.tagName === "INPUT" && t.type !== "range" && t.type !== "checkbox" || t.tagName === "TEXTAREA" || t.tagName === "SELECT");
}

window.addEventListener("keydown", (ev) => {
  if (typingInField(ev) || ev.ctrlKey || ev.metaKey || ev.altKey) return;
  const dir = DRIVE_KEYS[ev.code];
  // A monitor commands nothing: no drive, STOP or goal-mode keys.
  if (state.readOnly && (dir || ev.code === "Space" || ev.code === "KeyG")) return;
  if (dir) {
    ev.preventDefault();
    if (!held.has(dir)) {
      held.add(dir);
      driveStart();
    }
    return;
  }
  if (ev.repeat) return;
  if (ev.code === "Space") {
    ev.preventDefault();
    if (ev.shiftKey) stopAll();
    else document.getElementById("stop-btn").click();
  } else if (ev.code === "KeyG") {
    setGoalMode(!state.goalMode);
  } else if (ev.code === "KeyF") {
    followChk.checked = !followChk.checked;
    followChk.dispatchEvent(new Event("change"));
  } else if (ev.code === "Escape") {
    setGoalMode(false);
    map.closePopup();
  }
});

window.addEventListener("keyup", (ev) => {
  const dir = DRIVE_KEYS[ev.code];
  if (!dir) return;
  held.delete(dir);
  if (held.size === 0) driveRelease();
});

// Losing focus loses keyups: treat it as releasing every key (deadman).
window.addEventListener("blur", () => {
  held.clear();
  driveRelease();
});
document.addEventListener("visibilitychange", () => {
  if (document.hidden) {
    held.clear();
    driveRelease();
  }
});

// ---------------------------------------------------------------------------------------------
// Routes and sessions
// ---------------------------------------------------------------------------------------------

const routeList = document.getElementById("route-list");

async function refreshRoutes() {
  try {
    state.routes = (await api("GET", "/api/routes")) || [];
    renderRoutes();
  } catch (e) {
    logMsg("warn", e.message);
  }
}

function renderRoutes() {
  if (!state.routes.length) {
    routeList.innerHTML = `<div class="muted">no routes yet</div>`;
    return;
  }
  routeList.innerHTML = state.routes.map((rt) => {
    const shown = state.routeLayers.has(rt.route_id);
    const other = rt.datum_id !== state.datumId;
    return `<div class="item" data-route="${esc(rt.route_id)}">
      <div class="item-head"><b>${esc(rt.name || rt.route_id)}</b> <span class="muted small">${esc(rt.robot)} · ${Number(rt.length_m).toFixed(0)} m · ${rt.points} pts${other ? ` · ${esc(rt.datum_id)}` : ""}</span></div>
      <div class="row tight">
        <button data-act="show" class="${shown ? "active" : ""}">${shown ? "hide" : "show"}</button>
        <button data-act="reverse" title="Drive the route backwards to its start (return)">⟲ return</button>
        <button data-act="forward" title="Drive the route again from its start">⟳ repeat</button>
        <a class="small" href="${esc(withToken(`/api/routes/${enc(rt.route_id)}/gpx`))}" download>gpx</a>
      </div></div>`;
  }).join("");
}

routeList.addEventListener("click", async (ev) => {
  const btn = ev.target.closest("button");
  const item = ev.target.closest(".item");
  if (!btn || !item) return;
  const id = item.dataset.route;
  const act = btn.dataset.act;
  if (act === "show") toggleRoute(id);
  else if (act === "reverse" || act === "forward") {
    await command(state.selected, "route", { action: "repeat", route_id: id, direction: act });
    if (!state.routeLayers.has(id)) toggleRoute(id);
  }
});

async function toggleRoute(id) {
  const existing = state.routeLayers.get(id);
  if (existing) {
    existing.remove();
    state.routeLayers.delete(id);
    renderRoutes();
    return;
  }
  const summary = state.routes.find((r) => r.route_id === id);
  try {
    const route = await api("GET", `/api/routes/${enc(id)}`);
    if (summary && summary.datum_id && summary.datum_id !== state.datumId) {
      state.datumManual = summary.datum_id;
      document.getElementById("datum-select").value = summary.datum_id;
      setDatum(summary.datum_id);
    }
    const pts = (route.points || []).map((p) => ll(p.x_m, p.y_m));
    const line = L.polyline(pts, { pane: "routesPane", className: "route-line" })
      .bindTooltip(`route ${esc(route.name || id)}`, { sticky: true });
    const layer = L.featureGroup([line]);
    if (pts.length) {
      layer.addLayer(L.circleMarker(pts[0], { pane: "routesPane", radius: 5, className: "route-start" }).bindTooltip(`start of ${esc(route.name || id)}`));
    }
    layer.addTo(map);
    state.routeLayers.set(id, layer);
    renderRoutes();
  } catch (e) {
    logMsg("error", e.message);
  }
}

const sessionList = document.getElementById("session-list");
const sessionsSelectedOnly = document.getElementById("sessions-selected-only");
sessionsSelectedOnly.addEventListener("change", () => refreshSessions());

async function refreshSessions() {
  const q = sessionsSelectedOnly.checked && state.selected ? `?robot=${enc(state.selected)}` : "";
  try {
    state.sessions = (await api("GET", `/api/sessions${q}`)) || [];
    renderSessions();
  } catch (e) {
    logMsg("warn", e.message);
  }
}

function renderSessions() {
  // Re-rendering under a dragged slider would end the drag.
  if (document.activeElement && document.activeElement.dataset && document.activeElement.dataset.act === "scrub") return;
  if (!state.sessions.length) {
    sessionList.innerHTML = `<div class="muted">no sessions</div>`;
    return;
  }
  sessionList.innerHTML = state.sessions.slice(0, 50).map((s) => {
    const shown = state.trackLayers.get(s.session_id);
    const start = new Date(s.start_unix_ms);
    const dur = s.last_unix_ms && s.start_unix_ms ? fmtAge(s.last_unix_ms - s.start_unix_ms) : "–";
    return `<div class="item" data-session="${esc(s.session_id)}">
      <div class="item-head">${s.live ? `<span class="live">LIVE</span>` : ""} <b>${esc(s.robot)}</b>
        <span class="muted small">${start.toLocaleDateString()} ${start.toTimeString().slice(0, 5)} · ${dur} · ${esc(s.source)} · ${esc(s.datum_id)}</span></div>
      <div class="row tight"><button data-act="track" class="${shown ? "active" : ""}">${shown ? "hide track" : "show track"}</button>
      <span class="muted small mono">${esc(s.session_id)}</span></div>${shown ? scrubHtml(shown) : ""}</div>`;
  }).join("");
}

// ----- time scrubbing of a shown track ------------------------------------------------------------
// The slider shows the track as it was at time t: the points up to t and the robot's pose then,
// and the merged map as it was then (the station's tile history, one version per tile per history
// period: README, "Time scrubbing"). At the end of a live session's slider the map is live again.

function scrubHtml(t) {
  const first = t.points[0][0];
  const last = t.points[t.points.length - 1][0];
  const at = t.scrubT ?? last;
  return `<div class="row tight scrub"><input type="range" data-act="scrub" min="${first}" max="${last}" step="100" value="${at}">
    <span class="small mono scrub-time">${scrubLabel(first, at)}</span></div>
    <div class="muted small scrub-map">${mapAtLabel()}</div>`;
}

function mapAtLabel() {
  return state.mapAt === null ? "map: live" : `map: as at ${new Date(state.mapAt).toTimeString().slice(0, 8)}`;
}

/** Draws the map as it was at `t` (Unix ms), or live (null); the tiles reload once the slider rests. */
function setMapAt(t) {
  clearTimeout(state.mapAtTimer);
  state.mapAtTimer = setTimeout(() => {
    if (state.mapAt === t) return;
    state.mapAt = t;
    reloadPyramid();
    for (const el of sessionList.querySelectorAll(".scrub-map")) el.textContent = mapAtLabel();
  }, 200);
}

function scrubLabel(first, t) {
  return `${new Date(t).toTimeString().slice(0, 8)} (+${((t - first) / 1000).toFixed(1)} s)`;
}

/** Draws session `id`'s track as it was at `t` (Unix ms). */
function scrubTrack(id, t) {
  const tr = state.trackLayers.get(id);
  if (!tr) return;
  tr.scrubT = t;
  // Points are in time order: the last one at or before t ends the drawn track.
  let lo = 0;
  let hi = tr.points.length;
  while (lo < hi) {
    const mid = (lo + hi) >> 1;
    if (tr.points[mid][0] <= t) lo = mid + 1;
    else hi = mid;
  }
  const upto = tr.points.slice(0, Math.max(1, lo));
  tr.layer.setLatLngs(upto.map((p) => ll(p[1], p[2])));
  const p = upto[upto.length - 1];
  if (!tr.marker) {
    tr.marker = L.circleMarker(ll(p[1], p[2]), { pane: "tracksPane", radius: 6, className: "scrub-pose" }).addTo(map);
  } else tr.marker.setLatLng(ll(p[1], p[2]));
  tr.marker.bindTooltip(`${esc(tr.robot)} at ${new Date(p[0]).toTimeString().slice(0, 8)}`);
  const label = sessionList.querySelector(`.item[data-session="${CSS.escape(id)}"] .scrub-time`);
  if (label) label.textContent = scrubLabel(tr.points[0][0], t);
  if (tr.datum_id === state.datumId) {
    const s = state.sessions.find((x) => x.session_id === id);
    const atEnd = t >= tr.points[tr.points.length - 1][0];
    setMapAt(s && s.live && atEnd ? null : Math.round(t));
  }
}

sessionList.addEventListener("click", (ev) => {
  const btn = ev.target.closest("button");
  const item = ev.target.closest(".item");
  if (btn && item) toggleTrack(item.dataset.session);
});

sessionList.addEventListener("input", (ev) => {
  const item = ev.target.closest(".item");
  if (item && ev.target.dataset.act === "scrub") scrubTrack(item.dataset.session, Number(ev.target.value));
});

async function toggleTrack(id) {
  const existing = state.trackLayers.get(id);
  if (existing) {
    existing.layer.remove();
    if (existing.marker) existing.marker.remove();
    state.trackLayers.delete(id);
    if (![...state.trackLayers.values()].some((t) => t.scrubT !== null)) setMapAt(null);
    renderSessions();
    return;
  }
  try {
    const tr = await api("GET", `/api/sessions/${enc(id)}/track`);
    if (tr.datum_id && tr.datum_id !== state.datumId) {
      state.datumManual = tr.datum_id;
      document.getElementById("datum-select").value = tr.datum_id;
      setDatum(tr.datum_id);
    }
    const pts = (tr.points || []).map((p) => ll(p[1], p[2]));
    if (!pts.length) {
      logMsg("warn", `session ${id} has no track points`, true);
      return;
    }
    const layer = L.polyline(pts, { pane: "tracksPane", className: "session-track" })
      .bindTooltip(`${esc(tr.robot)} · ${esc(id)}`, { sticky: true })
      .addTo(map);
    state.trackLayers.set(id, { layer, datum_id: tr.datum_id, robot: tr.robot, points: tr.points, scrubT: null, marker: null });
    map.fitBounds(layer.getBounds(), { padding: [30, 30], maxZoom: 4 });
    renderSessions();
  } catch (e) {
    logMsg("error", e.message);
  }
}

// ---------------------------------------------------------------------------------------------
// Datums
// ---------------------------------------------------------------------------------------------

const datumSelect = document.getElementById("datum-select");
datumSelect.addEventListener("change", () => {
  state.datumManual = datumSelect.value;
  if (state.datumManual) setDatum(state.datumManual);
  else chooseDatum();
});
document.getElementById("fit-btn").addEventListener("click", fitDatum);

async function refreshDatums() {
  try {
    const list = (await api("GET", "/api/datums")) || [];
    state.datums = new Map(list.map((d) => [d.datum_id, d]));
    const cur = datumSelect.value;
    datumSelect.innerHTML = `<option value="">auto (selected robot)</option>` +
      list.map((d) => `<option value="${esc(d.datum_id)}">${esc(d.datum_id)} · ${d.tiles} tiles</option>`).join("");
    datumSelect.value = state.datums.has(cur) ? cur : "";
    if (!state.datumId) chooseDatum();
    maybeFit();
    renderDatumInfo();
  } catch (e) {
    logMsg("warn", e.message);
  }
}

function renderDatumInfo() {
  const d = currentDatum();
  const el = document.getElementById("datum-info");
  if (!state.datumId) el.textContent = "no map yet";
  else if (!d) el.textContent = state.datumId;
  else if (hasGeodetic(d)) el.textContent = `${d.datum_id}: origin ${formatLatLon(d.lat_deg, d.lon_deg)}, h ${Number(d.h_m).toFixed(2)} m · ${d.tiles} tiles`;
  else el.textContent = `${d.datum_id}: local frame without GNSS · ${d.tiles} tiles`;
}

// ---------------------------------------------------------------------------------------------
// REST polling (health, message ages) and the WebSocket (live updates)
// ---------------------------------------------------------------------------------------------

function applyRobotRest(j) {
  const r = robotView(j.robot);
  r.online = !!j.online;
  r.lastSeenMs = j.last_seen_unix_ms ?? r.lastSeenMs;
  r.session = j.session ?? r.session;
  if (j.datum_id && j.datum_id !== r.datumId) {
    r.datumId = j.datum_id;
    r.trail = [];
  }
  if (j.pose && (!r.pose || j.pose.t_unix_ms >= r.pose.t_unix_ms)) r.pose = j.pose;
  if (j.status) applyStatus(r, j.status);
  if (Array.isArray(j.path)) setPath(r, j.path);
  r.rates = j.rates_hz || {};
  r.ages = j.ages_ms || {};
  r.restAt = Date.now();
}

function samePath(a, b) {
  if (a.length !== b.length) return false;
  if (!a.length) return true;
  const [a0, a1, b0, b1] = [a[0], a[a.length - 1], b[0], b[b.length - 1]];
  return a0[0] === b0[0] && a0[1] === b0[1] && a1[0] === b1[0] && a1[1] === b1[1];
}

function setPath(r, points) {
  if (samePath(r.path, points)) return;
  r.path = points;
  r.pathAt = Date.now();
}

function applyStatus(r, s) {
  const first = !r.status;
  if (!r.status || s.t_unix_ms !== r.status.t_unix_ms) r.statusAt = Date.now();
  r.status = s;
  // An error that predates the page goes to the log and the robot card, a new one also pops up.
  robotError(r.name, s.last_error, !first);
  if (r.name === state.selected) {
    syncSpeedSlider(s);
    updateRecordButton();
  }
}

async function refreshRobots() {
  try {
    const list = (await api("GET", "/api/robots")) || [];
    stationBack();
    for (const j of list) applyRobotRest(j);
    if (!state.selected && list.length) selectRobot([...list].sort((a, b) => Number(b.online) - Number(a.online))[0].robot);
    if (!state.datumId) chooseDatum();
    for (const r of state.robots.values()) redrawRobot(r);
    maybeFit();
    renderRobots();
  } catch (e) {
    logMsg("warn", e.message);
  }
}

/**
 * A monitor station (`serve --monitor`) sends no commands: its API refuses them
 * (`monitor_read_only`), so the command controls are disabled and the top bar says so.
 */
function applyRole(h) {
  const readOnly = h.role === "monitor";
  if (readOnly === state.readOnly) return;
  state.readOnly = readOnly;
  document.body.classList.toggle("read-only", readOnly);
  const badge = document.getElementById("role-badge");
  badge.textContent = readOnly ? `monitor (read-only)${h.monitor ? ` · ${h.monitor}` : ""}` : "";
  badge.classList.toggle("hidden", !readOnly);
  const controls = document.querySelectorAll(
    "#topbar .stop-row button, #command-panel button, #command-panel input, #command-panel select, " +
      "#zones-panel button, #zones-panel input, #mission-run-btn, #record-form button, #record-form input",
  );
  for (const el of controls) {
    el.disabled = readOnly;
    if (readOnly) el.title = "monitor (read-only): commands are sent from the operator station";
  }
  if (readOnly) setGoalMode(false);
}

async function refreshHealth() {
  try {
    const h = await api("GET", "/api/health");
    state.health = h;
    applyRole(h);
    const r = h.restore;
    const restoring = r && !r.finished ? ` · restoring the stored map ${r.done} / ${r.tiles} tiles` : "";
    document.getElementById("footer").textContent =
      `station ${h.version ?? "?"} · ${h.robots_online} online · ${h.tiles} tiles · ${h.decode_errors} decode errors` +
      restoring + (TOKEN ? " · token" : "");
  } catch (e) {
    document.getElementById("footer").textContent = `station unreachable: ${e.message}`;
  }
}

async function refreshAll() {
  await Promise.all([refreshDatums(), refreshRobots(), refreshRoutes(), refreshHealth(), alerts.refresh(), missions.refresh(), missions.refreshRuns()]);
  await Promise.all([refreshTiles(), refreshSessions(), zones.refresh()]);
}

/** The station answers again: cards are current once more. */
function stationBack() {
  if (state.stationDownSince === null) return;
  state.stationDownSince = null;
  for (const r of state.robots.values()) redrawRobot(r);
  renderRobots();
}

/** The station stopped answering: what the cards show is no longer known to be current. */
function stationDown() {
  if (state.stationDownSince !== null) return;
  state.stationDownSince = Date.now();
  for (const r of state.robots.values()) redrawRobot(r);
  renderRobots();
}

const connEl = document.getElementById("conn");
const banner = document.getElementById("banner");
let ws = null;
let wsBackoffMs = 500;
let renderQueued = false;

function queueRender() {
  if (renderQueued) return;
  renderQueued = true;
  setTimeout(() => {
    renderQueued = false;
    renderRobots();
  }, 250);
}

function setConn(up, text) {
  state.wsUp = up;
  connEl.textContent = text;
  connEl.className = `conn ${up ? "conn-up" : "conn-down"}`;
  banner.classList.toggle("hidden", up);
  if (!up) banner.textContent = `Connection to the station lost (${text}); retrying… The robot keeps its last command until its own timeouts stop it.`;
  if (!up && text !== "connecting") stationDown();
}

function connectWs() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  ws = new WebSocket(withToken(`${proto}//${location.host}/api/ws`));
  ws.onopen = () => {
    wsBackoffMs = 500;
    setConn(true, "live");
  };
  ws.onmessage = (ev) => {
    let m;
    try {
      m = JSON.parse(ev.data);
    } catch {
      logMsg("warn", "unreadable WebSocket message from the station");
      return;
    }
    handleWs(m);
  };
  ws.onclose = (ev) => {
    setConn(false, ev.code === 1008 || ev.code === 4401 ? "unauthorized" : "offline");
    setTimeout(connectWs, wsBackoffMs);
    wsBackoffMs = Math.min(wsBackoffMs * 2, 5000);
  };
  ws.onerror = () => {
    // onclose follows and reconnects.
  };
}

function handleWs(m) {
  switch (m.type) {
    case "hello":
      logMsg("info", `connected to station ${m.version ?? ""}`);
      refreshAll();
      break;
    case "robot": {
      const r = robotView(m.robot);
      const was = r.online;
      r.online = !!m.online;
      r.lastSeenMs = m.last_seen_unix_ms ?? r.lastSeenMs;
      if (was !== r.online) logMsg(r.online ? "info" : "warn", `${m.robot} is ${r.online ? "online" : "OFFLINE"}`, !r.online);
      if (r.marker) r.marker.setIcon(robotIcon(r)), setMarkerHeading(r);
      queueRender();
      break;
    }
    case "session": {
      const r = robotView(m.robot);
      r.session = m.session;
      if (m.datum_id && m.datum_id !== r.datumId) {
        r.datumId = m.datum_id;
        r.trail = [];
      }
      logMsg("info", `${m.robot}: new session ${m.session && m.session.session_id}`);
      refreshDatums();
      refreshSessions();
      if (!state.datumManual && m.robot === state.selected) setDatum(m.datum_id);
      queueRender();
      break;
    }
    case "pose":
      onPose(m.robot, m.datum_id, m.pose);
      break;
    case "status": {
      const r = robotView(m.robot);
      applyStatus(r, m.status);
      redrawRobot(r);
      queueRender();
      break;
    }
    case "path": {
      const r = robotView(m.robot);
      setPath(r, m.points || []);
      redrawRobot(r);
      break;
    }
    case "tile":
      if (m.datum_id === state.datumId) {
        if (state.tileMeta) upsertTile(m.tx, m.ty, m.version);
        else refreshTiles();
      }
      if (!state.datums.has(m.datum_id)) refreshDatums();
      break;
    case "route":
      logMsg("info", `route stored: ${m.route && (m.route.name || m.route.route_id)}`, true);
      refreshRoutes();
      break;
    case "error":
      robotError(m.robot, m.message);
      break;
    case "alert":
      if (m.alert) alerts.onAlert(m.alert);
      break;
    case "alerts":
      alerts.refresh();
      break;
    case "zones":
      zones.refresh();
      break;
    case "missions":
      missions.refresh();
      break;
    case "mission_run":
      if (m.run) missions.onRun(m.run);
      break;
    default:
      break;
  }
}

// Health and message ages come from REST once a second; the tile index and datum bounds slowly,
// as a safety net for WebSocket messages lost while reconnecting.
setInterval(() => { if (state.stationDownSince !== null) renderRobots(); refreshRobots(); }, 1000);
setInterval(() => { refreshHealth(); refreshDatums(); refreshTiles(); }, 5000);
setInterval(() => { refreshSessions(); }, 15000);

// ---------------------------------------------------------------------------------------------
// Alerts, zones, missions, background map
// ---------------------------------------------------------------------------------------------

const ctx = {
  map, L, ll, api, esc, logMsg, showToast, state, enc, withToken, headers, robotColor, currentDatum,
  renderRobots: () => queueRender(),
  setMode: (m) => { state.mode = m; if (m) setGoalMode(false); },
  mode: () => state.mode,
  showDatum: (id) => {
    state.datumManual = id;
    document.getElementById("datum-select").value = id;
    setDatum(id);
  },
};
alerts = initAlerts(ctx);
zones = initZones(ctx);
missions = initMissions(ctx);
basemap = initBasemap(ctx);

setConn(false, "connecting");
connectWs();
refreshAll();

// Handle for the browser tests and for poking around in the console; not used by the page itself.
window.terranav = { map, state, ll, alerts, zones, missions, basemap, robotColor };
