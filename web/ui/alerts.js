// The alert list: what the station raised (stuck, mission failed, offline, GNSS degraded),
// newest first, until the operator acknowledges it. A new alert also pops a toast; the list is
// what stays.

const KIND_LABEL = { stuck: "STUCK", mission_failed: "MISSION FAILED", offline: "OFFLINE", gnss_degraded: "GNSS" };

export function initAlerts(ctx) {
  const { api, esc, logMsg, showToast } = ctx;
  const listEl = document.getElementById("alert-list");
  const countEl = document.getElementById("alert-count");
  const ackAllBtn = document.getElementById("alert-ack-all");
  let alerts = [];
  const seen = new Set();

  function render() {
    const open = alerts.filter((a) => !a.acked_unix_ms);
    countEl.textContent = open.length ? String(open.length) : "";
    countEl.classList.toggle("hidden", !open.length);
    document.getElementById("alerts-panel").classList.toggle("has-open", open.length > 0);
    if (!alerts.length) {
      listEl.innerHTML = `<div class="muted">no alerts</div>`;
      return;
    }
    listEl.innerHTML = alerts.slice(0, 100).map((a) => {
      const t = new Date(a.raised_unix_ms).toTimeString().slice(0, 8);
      return `<div class="alert-item ${a.acked_unix_ms ? "acked" : "open"} ${a.active ? "active" : "resolved"}" data-alert="${a.id}" data-kind="${esc(a.kind)}">
        <div class="alert-head"><span class="alert-kind">${esc(KIND_LABEL[a.kind] || a.kind)}</span>
          <b>${esc(a.robot)}</b> <span class="muted small">${t}${a.active ? "" : " · resolved"}</span>
          ${a.acked_unix_ms ? `<span class="muted small ack-note">acknowledged</span>` : `<button class="ack-btn" data-act="ack">ack</button>`}</div>
        <div class="alert-msg">${esc(a.message)}</div></div>`;
    }).join("");
  }

  function upsert(a) {
    const i = alerts.findIndex((x) => x.id === a.id);
    if (i >= 0) alerts[i] = a;
    else alerts.unshift(a);
    alerts.sort((x, y) => y.id - x.id);
    if (!seen.has(a.id)) {
      seen.add(a.id);
      if (a.active && !a.acked_unix_ms) {
        logMsg("error", `ALERT ${a.message}`, false);
        showToast("error", `ALERT ${a.message}`);
      }
    }
    render();
  }

  async function refresh() {
    try {
      const list = (await api("GET", "/api/alerts")) || [];
      for (const a of list) seen.add(a.id);
      alerts = list;
      render();
    } catch (e) {
      logMsg("warn", e.message);
    }
  }

  listEl.addEventListener("click", async (ev) => {
    const btn = ev.target.closest("button[data-act=ack]");
    const item = ev.target.closest(".alert-item");
    if (!btn || !item) return;
    try {
      const r = await api("POST", `/api/alerts/${item.dataset.alert}/ack`);
      if (r && r.alert) upsert(r.alert);
    } catch (e) {
      logMsg("error", e.message);
    }
  });
  ackAllBtn.addEventListener("click", async () => {
    try {
      await api("POST", "/api/alerts/ack");
      await refresh();
    } catch (e) {
      logMsg("error", e.message);
    }
  });

  render();
  return {
    refresh,
    onAlert: upsert,
    list: () => alerts,
  };
}
