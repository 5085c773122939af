// Waypoint missions: draw them on the map (click to add, drag to move, the list to reorder,
// delete and give each waypoint its actions: wait N s, set speed, pause for the operator),
// save them in the station, import/export GPX and GeoJSON, run one on the selected robot and
// watch it on the map: done waypoints green, the current one ringed in the robot's colour,
// the rest numbered, with distance and ETA on the robot's card.

export function initMissions(ctx) {
  const { map, L, ll, api, esc, logMsg, state, enc, robotColor } = ctx;
  const listEl = document.getElementById("mission-list");
  const wpEl = document.getElementById("mission-waypoints");
  const nameEl = document.getElementById("mission-name");
  const frameEl = document.getElementById("mission-frame");
  const addBtn = document.getElementById("mission-add-btn");
  const fileEl = document.getElementById("mission-file");
  const exportEl = document.getElementById("mission-export");

  map.createPane("missionPane");
  map.getPane("missionPane").style.zIndex = "335";

  let missions = []; // summaries
  const runs = new Map(); // robot -> run
  const runLayers = new Map(); // robot -> layer group
  let edit = newMission();
  let adding = false;
  let editLayer = null;

  function newMission() {
    return { mission_id: "", name: "", frame: "map", datum_id: state.datumId, waypoints: [] };
  }

  // ---- editor -------------------------------------------------------------------------------

  function wpIcon(i, cls = "") {
    return L.divIcon({ className: "wp-icon", iconSize: [24, 24], iconAnchor: [12, 12], html: `<div class="wp-marker ${cls}" data-wp="${i}">${i + 1}</div>` });
  }

  function drawEdit() {
    if (editLayer) editLayer.remove();
    editLayer = L.layerGroup().addTo(map);
    if (edit.datum_id && edit.datum_id !== state.datumId) return;
    const pts = edit.waypoints.map((w) => ll(w.x_m, w.y_m));
    if (pts.length > 1) L.polyline(pts, { pane: "missionPane", className: "mission-draft-line", interactive: false }).addTo(editLayer);
    edit.waypoints.forEach((w, i) => {
      const m = L.marker(ll(w.x_m, w.y_m), { icon: wpIcon(i, "draft"), draggable: true, pane: "missionPane", keyboard: false }).addTo(editLayer);
      m.on("dragend", () => {
        const p = m.getLatLng();
        w.x_m = p.lng;
        w.y_m = p.lat;
        renderEditor();
      });
    });
  }

  function renderEditor() {
    nameEl.value = edit.name;
    frameEl.value = edit.frame;
    addBtn.classList.toggle("active", adding);
    addBtn.textContent = adding ? "■ Done adding" : "+ Add waypoints";
    if (!edit.waypoints.length) {
      wpEl.innerHTML = `<div class="muted small">no waypoints: "+ Add waypoints", then click the map</div>`;
    } else {
      wpEl.innerHTML = edit.waypoints.map((w, i) => `<div class="wp-row" data-i="${i}">
        <span class="wp-num">${i + 1}</span>
        <span class="mono small">${w.x_m.toFixed(1)}, ${w.y_m.toFixed(1)}</span>
        <label title="wait here, seconds">wait <input data-f="wait_s" type="number" min="0" step="1" value="${w.wait_s || 0}"></label>
        <label title="set the speed limit here, m/s (empty: keep)">v <input data-f="speed_mps" type="number" min="0.05" step="0.05" value="${w.speed_mps ?? ""}"></label>
        <label title="wait for the operator to continue"><input data-f="pause" type="checkbox" ${w.pause ? "checked" : ""}>pause</label>
        <button data-act="up" title="earlier">↑</button><button data-act="down" title="later">↓</button><button data-act="del" title="delete">✕</button>
      </div>`).join("");
    }
    const saved = edit.mission_id;
    exportEl.innerHTML = saved
      ? `<a href="${esc(ctx.withToken(`/api/missions/${enc(saved)}/gpx`))}" download>gpx</a> · <a href="${esc(ctx.withToken(`/api/missions/${enc(saved)}/geojson`))}" download>geojson</a>`
      : `<span class="muted">save to export</span>`;
    drawEdit();
  }

  wpEl.addEventListener("change", (ev) => {
    const row = ev.target.closest(".wp-row");
    if (!row) return;
    const w = edit.waypoints[Number(row.dataset.i)];
    const f = ev.target.dataset.f;
    if (f === "pause") w.pause = ev.target.checked;
    else if (f === "wait_s") w.wait_s = Math.max(0, Number(ev.target.value) || 0);
    else if (f === "speed_mps") w.speed_mps = ev.target.value === "" ? null : Number(ev.target.value);
  });
  wpEl.addEventListener("click", (ev) => {
    const btn = ev.target.closest("button");
    const row = ev.target.closest(".wp-row");
    if (!btn || !row) return;
    const i = Number(row.dataset.i);
    const w = edit.waypoints;
    if (btn.dataset.act === "del") w.splice(i, 1);
    else if (btn.dataset.act === "up" && i > 0) [w[i - 1], w[i]] = [w[i], w[i - 1]];
    else if (btn.dataset.act === "down" && i < w.length - 1) [w[i + 1], w[i]] = [w[i], w[i + 1]];
    renderEditor();
  });
  nameEl.addEventListener("input", () => { edit.name = nameEl.value; });
  frameEl.addEventListener("change", () => { edit.frame = frameEl.value; });

  function setAdding(on) {
    adding = on && !!state.datumId;
    if (on && !state.datumId) logMsg("warn", "no map to draw on yet", true);
    if (adding) {
      ctx.setMode("mission");
      if (!edit.datum_id || !edit.waypoints.length) edit.datum_id = state.datumId;
    } else if (ctx.mode() === "mission") ctx.setMode(null);
    document.getElementById("map").classList.toggle("goal-cursor", adding);
    const b = document.getElementById("mode-banner");
    b.classList.toggle("hidden", !adding);
    if (adding) b.innerHTML = `Adding waypoints: click the map · drag a number to move it · <kbd>Esc</kbd> when done`;
    renderEditor();
  }
  addBtn.addEventListener("click", () => setAdding(!adding));
  map.on("click", (ev) => {
    if (!adding) return;
    if (edit.datum_id && edit.datum_id !== state.datumId) {
      logMsg("warn", `this mission is drawn on ${edit.datum_id}; switch the map datum or start a new mission`, true);
      return;
    }
    edit.waypoints.push({ x_m: ev.latlng.lng, y_m: ev.latlng.lat, wait_s: 0, speed_mps: null, pause: false });
    renderEditor();
  });
  window.addEventListener("keydown", (ev) => {
    if (adding && ev.code === "Escape") setAdding(false);
  });

  document.getElementById("mission-new-btn").addEventListener("click", () => {
    edit = newMission();
    setAdding(false);
  });

  async function save() {
    edit.name = nameEl.value.trim() || `mission ${new Date().toISOString().slice(0, 16).replace("T", " ")}`;
    edit.datum_id = edit.datum_id || state.datumId;
    const body = {
      name: edit.name, datum_id: edit.datum_id, frame: edit.frame,
      waypoints: edit.waypoints.map((w) => ({ x_m: w.x_m, y_m: w.y_m, wait_s: Number(w.wait_s) || 0, speed_mps: w.speed_mps || null, pause: !!w.pause })),
    };
    const saved = edit.mission_id
      ? await api("PUT", `/api/missions/${enc(edit.mission_id)}`, body)
      : await api("POST", "/api/missions", body);
    edit = { ...saved, waypoints: saved.waypoints.map((w) => ({ ...w })) };
    logMsg("info", `mission "${saved.name}" saved (${saved.waypoints.length} waypoints)`);
    await refresh();
    renderEditor();
    return saved;
  }
  document.getElementById("mission-save-btn").addEventListener("click", async () => {
    try {
      setAdding(false);
      await save();
    } catch (e) {
      logMsg("error", e.message);
    }
  });
  document.getElementById("mission-run-btn").addEventListener("click", async () => {
    try {
      setAdding(false);
      const saved = await save();
      await start(saved.mission_id);
    } catch (e) {
      logMsg("error", e.message);
    }
  });

  async function start(missionId) {
    const robot = state.selected;
    if (!robot) {
      logMsg("warn", "select a robot first", true);
      return;
    }
    const r = await api("POST", `/api/robots/${enc(robot)}/mission`, { mission_id: missionId });
    if (r && r.run) onRun(r.run);
    logMsg("info", `${robot}: mission started`);
  }

  fileEl.addEventListener("change", async () => {
    const f = fileEl.files && fileEl.files[0];
    if (!f) return;
    fileEl.value = "";
    if (!state.datumId) {
      logMsg("warn", "no map yet to place the mission on", true);
      return;
    }
    const text = await f.text();
    const format = /\.gpx$/i.test(f.name) ? "gpx" : "geojson";
    const name = f.name.replace(/\.[^.]*$/, "");
    try {
      const res = await fetch(ctx.withToken(`/api/missions/import?format=${format}&datum_id=${enc(state.datumId)}&name=${enc(name)}`),
        { method: "POST", headers: ctx.headers({ "Content-Type": "application/octet-stream" }), body: text });
      const j = await res.json().catch(() => null);
      if (!res.ok) throw new Error(`import: ${res.status} ${(j && j.error) || res.statusText}`);
      edit = { ...j, waypoints: j.waypoints.map((w) => ({ ...w })) };
      logMsg("info", `mission "${j.name}" imported (${j.waypoints.length} waypoints)`, true);
      await refresh();
      renderEditor();
    } catch (e) {
      logMsg("error", e.message);
    }
  });

  // ---- saved list ---------------------------------------------------------------------------

  async function refresh() {
    try {
      missions = (await api("GET", "/api/missions")) || [];
      renderList();
    } catch (e) {
      logMsg("warn", e.message);
    }
  }

  function renderList() {
    if (!missions.length) {
      listEl.innerHTML = `<div class="muted">no saved missions</div>`;
      return;
    }
    listEl.innerHTML = missions.map((m) => `<div class="item mission-item" data-mission="${esc(m.mission_id)}">
      <b>${esc(m.name)}</b> <span class="muted small">${m.waypoints} wp · ${Number(m.length_m).toFixed(0)} m · ${esc(m.frame)} · ${esc(m.datum_id)}</span>
      <div class="row tight"><button data-act="edit">edit</button><button data-act="run" title="Run on the selected robot">▶ run</button><button data-act="delete">delete</button></div></div>`).join("");
  }

  listEl.addEventListener("click", async (ev) => {
    const btn = ev.target.closest("button");
    const item = ev.target.closest(".mission-item");
    if (!btn || !item) return;
    const id = item.dataset.mission;
    try {
      if (btn.dataset.act === "edit") {
        const m = await api("GET", `/api/missions/${enc(id)}`);
        edit = { ...m, waypoints: m.waypoints.map((w) => ({ ...w })) };
        if (m.datum_id !== state.datumId) ctx.showDatum(m.datum_id);
        renderEditor();
      } else if (btn.dataset.act === "run") {
        await start(id);
      } else if (btn.dataset.act === "delete") {
        await api("DELETE", `/api/missions/${enc(id)}`);
        await refresh();
      }
    } catch (e) {
      logMsg("error", e.message);
    }
  });

  // ---- runs ---------------------------------------------------------------------------------

  function onRun(run) {
    const prev = runs.get(run.robot);
    runs.set(run.robot, run);
    if (prev && prev.phase.state !== run.phase.state) {
      const ph = run.phase;
      if (ph.state === "finished") logMsg("info", `${run.robot}: mission "${run.mission.name}" finished`, true);
      else if (ph.state === "paused") logMsg("warn", `${run.robot}: mission "${run.mission.name}" waits for you at waypoint ${run.index + 1} (Continue on its card)`, true);
      else if (ph.state === "failed") logMsg("error", `${run.robot}: mission "${run.mission.name}" failed: ${ph.reason}`, false);
    }
    drawRun(run);
    ctx.renderRobots();
  }

  function drawRun(run) {
    const old = runLayers.get(run.robot);
    if (old) old.remove();
    runLayers.delete(run.robot);
    const m = run.mission;
    if (m.datum_id !== state.datumId || ["cancelled"].includes(run.phase.state)) return;
    const color = robotColor(run.robot);
    const g = L.layerGroup().addTo(map);
    const pts = m.waypoints.map((w) => ll(w.x_m, w.y_m));
    const ended = ["finished", "failed"].includes(run.phase.state);
    L.polyline(pts, { pane: "missionPane", className: "mission-line", color, interactive: false }).addTo(g);
    m.waypoints.forEach((w, i) => {
      const done = !!run.reached_unix_ms[i];
      const cls = done ? "done" : !ended && i === run.index ? "current" : "next";
      L.marker(ll(w.x_m, w.y_m), { icon: wpIcon(i, `${cls}`), pane: "missionPane", keyboard: false, interactive: true })
        .bindTooltip(`${esc(m.name)} · waypoint ${i + 1} (${cls})${w.wait_s ? ` · wait ${w.wait_s} s` : ""}${w.speed_mps ? ` · ${w.speed_mps} m/s` : ""}${w.pause ? " · pause" : ""}`)
        .addTo(g);
      const el = g.getLayers().slice(-1)[0].getElement();
      if (el) el.querySelector(".wp-marker").style.setProperty("--robot", color);
    });
    runLayers.set(run.robot, g);
  }

  async function refreshRuns() {
    try {
      const list = (await api("GET", "/api/missions/runs")) || [];
      for (const r of list) onRun(r);
    } catch (e) {
      logMsg("warn", e.message);
    }
  }

  function fmtEta(s) {
    if (s === null || s === undefined || !Number.isFinite(s)) return "–";
    const m = Math.floor(s / 60);
    return `${m}:${String(Math.round(s % 60)).padStart(2, "0")}`;
  }

  /** The mission line of a robot's card (HTML), or "". */
  function cardLine(robot) {
    const run = runs.get(robot);
    if (!run) return "";
    const ph = run.phase;
    const n = run.mission.waypoints.length;
    const done = run.reached_unix_ms.filter(Boolean).length;
    let what;
    switch (ph.state) {
      case "going": case "starting": what = `→ waypoint ${run.index + 1}/${n} · ${run.distance_left_m.toFixed(1)} m · ETA ${fmtEta(run.eta_s)}`; break;
      case "waiting": what = `waiting at waypoint ${run.index + 1}/${n}`; break;
      case "paused": what = `<b class="warn">paused at waypoint ${run.index + 1}/${n}</b> <button data-mission-act="continue">Continue</button>`; break;
      case "finished": what = `<span class="ok">finished (${done}/${n})</span>`; break;
      case "failed": what = `<span class="bad">failed: ${esc(ph.reason)}</span>`; break;
      case "cancelled": what = `<span class="muted">cancelled</span>`; break;
      default: what = esc(ph.state);
    }
    const live = !["finished", "failed", "cancelled"].includes(ph.state);
    return `<div class="kv mission-line-kv" data-field="mission-run" data-state="${esc(ph.state)}"><span>mission</span><span>${esc(run.mission.name)}: ${what}${live ? ` <button data-mission-act="cancel" title="Cancel the mission (stops the robot)">✕</button>` : ""}</span></div>`;
  }

  async function runAction(robot, action) {
    try {
      const r = await api("POST", `/api/robots/${enc(robot)}/mission/${action}`);
      if (r && r.run) onRun(r.run);
    } catch (e) {
      logMsg("error", e.message);
    }
  }

  function onDatum() {
    for (const r of runs.values()) drawRun(r);
    drawEdit();
  }

  renderEditor();
  return { refresh, refreshRuns, onRun, cardLine, runAction, onDatum, adding: () => adding, stopAdding: () => setAdding(false), runs };
}
