// Keep-out and slow zones: drawn on the map (click the corners, double-click or "Finish" to
// close, Esc to give up), imported from a GeoJSON file, listed with delete; shown as red
// (keep-out) or amber (slow) polygons in the drawn datum's map frame. The station stores them
// and sends each robot its own copy; the robots enforce them.

export function initZones(ctx) {
  const { map, L, ll, api, esc, logMsg, state, enc } = ctx;
  const listEl = document.getElementById("zone-list");
  const speedEl = document.getElementById("zone-speed");
  const nameEl = document.getElementById("zone-name");
  const fileEl = document.getElementById("zone-file");
  const layers = new Map(); // zone_id -> layer
  let zones = []; // features in the drawn datum's map frame
  let draw = null; // {kind, pts: [[x,y]], line, markers}

  map.createPane("zonesPane");
  map.getPane("zonesPane").style.zIndex = "305";

  function clearLayers() {
    for (const l of layers.values()) l.remove();
    layers.clear();
  }

  function render() {
    clearLayers();
    for (const f of zones) {
      const p = f.properties || {};
      const ring = (f.geometry && f.geometry.coordinates && f.geometry.coordinates[0]) || [];
      const latlngs = ring.map(([x, y]) => ll(x, y));
      const slow = p.kind === "slow";
      const layer = L.polygon(latlngs, {
        pane: "zonesPane",
        className: slow ? "zone-slow" : "zone-keepout",
        interactive: true,
      }).bindTooltip(`${slow ? "slow zone" : "keep-out zone"} <b>${esc(p.name)}</b>${slow ? ` · ${Number(p.speed_mps).toFixed(2)} m/s` : ""}`, { sticky: true });
      layer.addTo(map);
      const el = layer.getElement && layer.getElement();
      if (el) el.setAttribute("data-zone", p.zone_id);
      layers.set(p.zone_id, layer);
    }
    if (!zones.length) {
      listEl.innerHTML = `<div class="muted">no zones${state.datumId ? "" : " (no map yet)"}</div>`;
      return;
    }
    listEl.innerHTML = zones.map((f) => {
      const p = f.properties || {};
      const slow = p.kind === "slow";
      return `<div class="item zone-item" data-zone="${esc(p.zone_id)}">
        <span class="zone-sw ${slow ? "slow" : "keepout"}"></span> <b>${esc(p.name)}</b>
        <span class="muted small">${slow ? `slow ${Number(p.speed_mps).toFixed(2)} m/s` : "keep-out"}</span>
        <button class="small-btn" data-act="delete" title="Delete this zone">delete</button></div>`;
    }).join("");
  }

  async function refresh() {
    if (!state.datumId) {
      zones = [];
      render();
      return;
    }
    try {
      const fc = await api("GET", `/api/zones?frame=map&datum_id=${enc(state.datumId)}`);
      zones = (fc && fc.features) || [];
      render();
    } catch (e) {
      logMsg("warn", e.message);
    }
  }

  // ---- drawing ----
  function startDraw(kind) {
    if (!state.datumId) {
      logMsg("warn", "no map to draw on yet", true);
      return;
    }
    cancelDraw();
    ctx.setMode("zone");
    map.doubleClickZoom.disable();
    draw = { kind, pts: [], line: L.polyline([], { pane: "zonesPane", className: `zone-draft ${kind}`, interactive: false }).addTo(map), markers: [] };
    document.getElementById("map").classList.add("goal-cursor");
    showBanner();
  }

  function showBanner() {
    const b = document.getElementById("mode-banner");
    b.classList.toggle("hidden", !draw);
    if (draw) {
      b.innerHTML = `Drawing a ${draw.kind === "slow" ? "slow" : "keep-out"} zone: click the corners (${draw.pts.length} so far), double-click or <button id="zone-finish-btn">Finish</button> · <kbd>Esc</kbd> cancels`;
      document.getElementById("zone-finish-btn").addEventListener("click", (e) => { e.stopPropagation(); finishDraw(); });
    }
  }

  function cancelDraw() {
    if (!draw) return;
    draw.line.remove();
    for (const m of draw.markers) m.remove();
    draw = null;
    map.doubleClickZoom.enable();
    document.getElementById("map").classList.remove("goal-cursor");
    ctx.setMode(null);
    showBanner();
  }

  function addPoint(x, y) {
    // The two clicks of a double-click land on the same spot: one corner.
    const last = draw.pts[draw.pts.length - 1];
    if (last && Math.hypot(last[0] - x, last[1] - y) < 0.05) return;
    draw.pts.push([x, y]);
    draw.line.setLatLngs([...draw.pts, draw.pts[0]].map(([a, b]) => ll(a, b)));
    draw.markers.push(L.circleMarker(ll(x, y), { pane: "zonesPane", radius: 4, className: "zone-vertex", interactive: false }).addTo(map));
    showBanner();
  }

  async function finishDraw() {
    if (!draw) return;
    const { kind, pts } = draw;
    if (pts.length < 3) {
      logMsg("warn", "a zone needs at least 3 corners", true);
      return;
    }
    const name = nameEl.value.trim() || `${kind === "slow" ? "slow" : "keep-out"} ${zones.length + 1}`;
    const props = { kind: kind === "slow" ? "slow" : "keep_out", name };
    if (kind === "slow") props.speed_mps = Number(speedEl.value) || 0.2;
    const feature = { type: "Feature", properties: props, geometry: { type: "Polygon", coordinates: [[...pts, pts[0]]] } };
    const datumId = state.datumId;
    cancelDraw();
    await postZone(JSON.stringify(feature), `?frame=map&datum_id=${enc(datumId)}`);
  }

  async function postZone(body, query) {
    try {
      const r = await fetch(ctx.withToken(`/api/zones${query}`), { method: "POST", headers: ctx.headers({ "Content-Type": "application/geo+json" }), body });
      const j = await r.json().catch(() => null);
      if (!r.ok) throw new Error(`POST /api/zones: ${r.status} ${(j && j.error) || r.statusText}`);
      logMsg("info", `zone stored: ${(j.features || []).map((f) => f.properties.name).join(", ")}`, true);
      await refresh();
    } catch (e) {
      logMsg("error", e.message);
    }
  }

  map.on("click", (ev) => {
    if (!draw) return;
    addPoint(ev.latlng.lng, ev.latlng.lat);
  });
  map.on("dblclick", (ev) => {
    if (!draw) return;
    L.DomEvent.stop(ev);
    finishDraw();
  });
  window.addEventListener("keydown", (ev) => {
    if (draw && ev.code === "Escape") cancelDraw();
    if (draw && ev.code === "Enter") finishDraw();
  });

  document.getElementById("zone-keepout-btn").addEventListener("click", () => startDraw("keep_out"));
  document.getElementById("zone-slow-btn").addEventListener("click", () => startDraw("slow"));
  fileEl.addEventListener("change", async () => {
    const f = fileEl.files && fileEl.files[0];
    if (!f) return;
    const text = await f.text();
    fileEl.value = "";
    await postZone(text, state.datumId ? `?datum_id=${enc(state.datumId)}` : "");
  });
  listEl.addEventListener("click", async (ev) => {
    const btn = ev.target.closest("button[data-act=delete]");
    const item = ev.target.closest(".zone-item");
    if (!btn || !item) return;
    try {
      await api("DELETE", `/api/zones/${enc(item.dataset.zone)}`);
      logMsg("info", "zone deleted");
      await refresh();
    } catch (e) {
      logMsg("error", e.message);
    }
  });

  return { refresh, drawing: () => !!draw, cancel: cancelDraw };
}
