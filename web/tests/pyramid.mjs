#!/usr/bin/env node
// The map of a whole site in the browser, against the station that tests/browser_pyramid.rs
// starts (a synthetic 1 km² merged map and one past session with a track).
//
//   node web/tests/pyramid.mjs <station url> [--tiles N]
//
// Measures (and prints, never judges on time): the time from navigation start to the first full
// view of the site (every visible pyramid tile loaded, the whole site in view) and the requests
// it took; the same on a reload (tiles revalidated: 304). Checks that zooming in reaches full
// resolution (level 0) and that the time slider of a shown session redraws its track up to t.
// Last line: JSON with the numbers. Screenshots to $TERRANAV_ARTIFACTS.

import { chromium } from "playwright-core";
import { mkdirSync, mkdtempSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import { dirname, join, resolve } from "node:path";
import { fileURLToPath } from "node:url";
import { StepFailed, logger, screenshots, sleep, until as untilHolds } from "./harness.mjs";

const here = dirname(fileURLToPath(import.meta.url));
const CHROMIUM = process.env.TERRANAV_CHROMIUM || "/usr/bin/chromium";
const ARTIFACTS = resolve(process.env.TERRANAV_ARTIFACTS || join(here, "../../artifacts/ui-pyramid"));
const argv = process.argv.slice(2);
const url = argv.find((a) => !a.startsWith("--") && /^https?:/.test(a));
const opt = (k) => { const i = argv.indexOf(k); return i >= 0 ? argv[i + 1] : null; };
const MERGED_TILES = Number(opt("--tiles") || 0);
if (!url) {
  console.error("usage: node web/tests/pyramid.mjs <station url> [--tiles N]");
  process.exit(2);
}
const t0 = Date.now();
const log = logger("pyramid", t0);
const shot = screenshots(ARTIFACTS, log);
// Finer polling than the default: the first full view is timed through it.
const until = (what, ms, fn, everyMs = 100) => untilHolds(what, ms, fn, everyMs);

/** Requests seen by the page: {url, at (epoch ms), status}. */
const requests = [];

function pyramidPath(u) {
  const m = /\/pyramid\/(\d+)\/(-?\d+)\/(-?\d+)\.png/.exec(u);
  return m ? { level: Number(m[1]) } : null;
}

/** Opens (or reloads) the page and waits for the first full view of the site. */
async function firstView(page, reload) {
  const from = requests.length;
  if (reload) await page.reload({ waitUntil: "domcontentloaded", timeout: 15000 });
  else await page.goto(url, { waitUntil: "domcontentloaded", timeout: 15000 });
  // The first time every visible tile has loaded with the whole site in view (the page may draw
  // a part of it first, at its initial zoom, before fitting the site).
  const view = await until("the pyramid layer loaded its visible tiles with the whole site in view", 30000, () => page.evaluate(() => {
    const s = window.terranav && window.terranav.state;
    const d = s && s.datumId && s.datums.get(s.datumId);
    if (!d || !d.bounds_m) return null;
    const [x0, y0, x1, y1] = d.bounds_m;
    const whole = s.tileLoads.find((l) => l.settled && l.view_m[0] <= x0 && l.view_m[1] <= y0 && l.view_m[2] >= x1 && l.view_m[3] >= y1);
    return whole ? { ...whole, origin: performance.timeOrigin } : null;
  }));
  const doneAt = view.origin + view.t_ms;
  // Responses arrive a moment after "load" is handled; wait for the ones the view asked for.
  await sleep(300);
  const mine = requests.slice(from).filter((r) => r.at <= doneAt);
  const tiles = mine.filter((r) => pyramidPath(r.url));
  const whole = await page.evaluate(() => ({
    zoom: window.terranav.map.getZoom(),
    shown: [...document.querySelectorAll("img.map-tile")].filter((i) => i.complete && i.naturalWidth > 1).length,
  }));
  if (whole.shown === 0) throw new StepFailed("no map tile image shown");
  const status = (c) => tiles.filter((r) => r.status === c).length;
  return {
    first_full_view_ms: Math.round(view.t_ms),
    level: view.level,
    zoom: whole.zoom,
    requests: mine.length,
    tile_requests: tiles.length,
    tiles_200: status(200),
    tiles_304: status(304),
    tiles_404: status(404),
    tile_images_shown: whole.shown,
  };
}

async function main() {
  mkdirSync(ARTIFACTS, { recursive: true });
  const profile = mkdtempSync(join(tmpdir(), "terranav-pyramid-"));
  const ctx = await chromium.launchPersistentContext(profile, {
    executablePath: CHROMIUM,
    headless: true,
    viewport: { width: 1400, height: 860 },
    args: [
      "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
      "--disable-background-networking", "--disable-component-update", "--disable-sync",
    ],
  });
  const pageErrors = [];
  const page = ctx.pages()[0] || (await ctx.newPage());
  page.on("pageerror", (e) => pageErrors.push(e.message));
  const consoleLines = [];
  page.on("console", (m) => consoleLines.push(`${m.type()}: ${m.text()}`));
  page.on("request", (r) => requests.push({ url: r.url(), at: Date.now(), status: null, req: r }));
  page.on("requestfailed", (r) => {
    const q = requests.find((x) => x.req === r);
    if (q) q.status = `failed ${r.failure() && r.failure().errorText}`;
  });
  page.on("response", (r) => {
    const q = requests.find((x) => x.req === r.request());
    if (q) q.status = r.status();
  });
  const out = { merged_tiles: MERGED_TILES };
  try {
    // 1. cold: the station's pyramid and the browser's cache both empty
    out.cold = await firstView(page, false);
    log(`first full view (cold) after ${out.cold.first_full_view_ms} ms: ${out.cold.tile_requests} tile requests ` +
        `(level ${out.cold.level}, ${out.cold.tiles_200} x 200, ${out.cold.tiles_404} x 404), ${out.cold.requests} requests in all; ` +
        `one PNG per merged tile would be ${MERGED_TILES}`);
    await shot(page, "site-first-view");

    // 2. full resolution when zoomed in: level 0 tiles, one image pixel per cell
    const before = requests.length;
    const z0 = await page.evaluate(() => {
      const { map, state } = window.terranav;
      state.tileLoads.length = 0;
      map.setView([10, 10], state.tileLayer.options.z0 + 1, { animate: false });
      return state.tileLayer.options.z0;
    });
    await until("level-0 tiles loaded after zooming in", 15000, () => page.evaluate(() => window.terranav.state.tileLoads.length > 0));
    const levels = new Set(requests.slice(before).map((r) => pyramidPath(r.url)).filter(Boolean).map((p) => p.level));
    if (levels.size !== 1 || !levels.has(0)) throw new StepFailed(`zoomed in past z0=${z0}, but asked for levels ${[...levels]}`);
    out.zoomed_in_tile_requests = requests.slice(before).filter((r) => pyramidPath(r.url)).length;
    log(`zoomed in: ${out.zoomed_in_tile_requests} level-0 tile requests`);
    await shot(page, "full-resolution");

    // 3. time scrubbing of the past session's track
    await page.evaluate(() => window.terranav.map.setZoom(-1, { animate: false }));
    const item = page.locator("#session-list .item").first();
    await until("the past session is listed", 10000, () => item.count());
    await item.locator("button[data-act=track]").click();
    await until("the shown track has a time slider", 10000, () => page.locator("#session-list input[data-act=scrub]").count());
    const full = await page.evaluate(() => [...window.terranav.state.trackLayers.values()][0].layer.getLatLngs().length);
    const [min, max] = await page.evaluate(() => {
      const s = document.querySelector("#session-list input[data-act=scrub]");
      return [Number(s.min), Number(s.max)];
    });
    const loadsBeforeScrub = await page.evaluate(() => window.terranav.state.tileLoads.length);
    // As a drag does: set the value, fire "input".
    await page.evaluate((v) => {
      const s = document.querySelector("#session-list input[data-act=scrub]");
      s.value = String(v);
      s.dispatchEvent(new Event("input", { bubbles: true }));
    }, Math.round((min + max) / 2));
    const half = await until("the track is cut at the slider's time", 5000, () => page.evaluate(() => {
      const t = [...window.terranav.state.trackLayers.values()][0];
      const n = t.layer.getLatLngs().length;
      return n < t.points.length && t.marker ? n : null;
    }));
    // Points are 1 s apart over 600 s: half way is point 300 (the slider steps by 100 ms).
    if (Math.abs(half - full / 2) > 2) throw new StepFailed(`scrubbed to half time: ${half} of ${full} points drawn`);
    out.scrub = { points: full, at_half: half };
    log(`scrubbed to half time: ${half} of ${full} track points drawn, pose marker shown`);
    // ... and the map as it was then: the history has the west half (tx < 0) from +60 s and the
    // east half from +450 s, so at +300 s the layer draws the past map, west half only.
    const mapAt = await until("the map is drawn as it was at the slider's time", 5000, () =>
      page.evaluate(() => window.terranav.state.mapAt));
    if (Math.abs(mapAt - (min + max) / 2) > 1000) throw new StepFailed(`map drawn at ${mapAt}, slider at ${(min + max) / 2}`);
    // Every visible tile of the past map answered (the layer fires "load" once none is pending).
    const historyReqs = await until("the layer loaded the past map's visible tiles", 15000, async () => {
      const h = requests.filter((r) => r.url.includes(`/history/${mapAt}/`));
      const loaded = await page.evaluate((n) => window.terranav.state.tileLoads.length > n, loadsBeforeScrub);
      return h.length && loaded && h.every((r) => r.status !== null) ? h : null;
    });
    const probe = await page.evaluate(async (t) => {
      const get = async (p) => (await fetch(`/api/map/d0/history/${t}/${p}`)).status;
      const info = await (await fetch("/api/map/d0/history")).json();
      return { west: await get("0/-3/0.png"), east: await get("0/3/0.png"), info };
    }, mapAt);
    const later = await page.evaluate(async (t) => (await fetch(`/api/map/d0/history/${t}/0/3/0.png`)).status, max);
    if (probe.west !== 200 || probe.east !== 404 || later !== 200) {
      throw new StepFailed(`past map at half time: west tile ${probe.west}, east tile ${probe.east} (want 200, 404); east at the end ${later} (want 200)`);
    }
    const byStatus = {};
    for (const r of historyReqs) byStatus[r.status] = (byStatus[r.status] || 0) + 1;
    if (!byStatus[200]) throw new StepFailed(`no past-map tile was drawn: ${JSON.stringify(byStatus)}, e.g. ${historyReqs[0].url}`);
    out.scrub.map_history = { tile_requests: historyReqs.length, by_status: byStatus, rows: probe.info.rows, bytes: probe.info.bytes };
    log(`past map at half time: ${historyReqs.length} history tile requests ${JSON.stringify(byStatus)}; west tile 200, east tile 404, east at the end 200; history ${probe.info.rows} rows`);
    // The screenshot after the fit to the track has settled (zoom animation, tiles).
    await sleep(1000);
    await shot(page, "scrubbed");

    // 4. warm: a reload revalidates the tiles (304, nothing rendered again)
    out.warm = await firstView(page, true);
    log(`first full view (reload) after ${out.warm.first_full_view_ms} ms: ${out.warm.tile_requests} tile requests ` +
        `(${out.warm.tiles_304} x 304, ${out.warm.tiles_200} x 200)`);

    if (pageErrors.length) throw new StepFailed(`page errors: ${pageErrors.join(" | ")}`);
    console.log(JSON.stringify(out));
  } catch (e) {
    await shot(page, "failure").catch(() => {});
    const st = await page.evaluate(() => {
      const s = window.terranav && window.terranav.state;
      return s && { datumId: s.datumId, tileMeta: s.tileMeta, layer: !!s.tileLayer, loads: s.tileLoads,
                    datums: [...s.datums.keys()], zoom: window.terranav.map.getZoom() };
    }).catch((err) => String(err));
    const byStatus = {};
    for (const r of requests) {
      const k = `${pyramidPath(r.url) ? "tile" : new URL(r.url).pathname} ${r.status}`;
      byStatus[k] = (byStatus[k] || 0) + 1;
    }
    console.error("page state:", JSON.stringify(st));
    console.error("requests:", JSON.stringify(byStatus));
    console.error("unanswered:", requests.filter((r) => r.status === null).map((r) => `${new URL(r.url).pathname} +${r.at - t0}`).join(" "));
    console.error("page errors:", pageErrors.join(" | "));
    console.error("console:", consoleLines.slice(-20).join("\n"));
    console.error(e instanceof StepFailed ? `FAILED: ${e.message}` : e.stack || String(e));
    console.log(JSON.stringify(out));
    process.exitCode = 1;
  } finally {
    await ctx.close();
    rmSync(profile, { recursive: true, force: true });
  }
}

main();
