#!/usr/bin/env node
// Browser test of the operator UI against a running station (`operator-station demo`).
//
//   node web/tests/ui.mjs <station url> [--since-ms <unix ms when the demo was started>]
//
// Drives Debian's chromium (/usr/bin/chromium, never a downloaded browser) through playwright-core:
// page loads -> map tiles and a robot marker appear (within 10 s of the demo start) -> keyboard drive
// sends deadman commands -> clicking the map in goal mode sends a goal and the planned path appears
// -> STOP stops the robot (UI and GET /api/robots agree). Screenshots of every step go to
// <repo>/artifacts/ui/ (or $TERRANAV_ARTIFACTS). Exit code 1 with a message naming the failed step.

import { chromium } from "playwright-core";
import { mkdirSync, mkdtempSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import { dirname, join, resolve } from "node:path";
import { fileURLToPath } from "node:url";
import { StepFailed, logger, screenshots, sleep, until } from "./harness.mjs";

const here = dirname(fileURLToPath(import.meta.url));
const CHROMIUM = process.env.TERRANAV_CHROMIUM || "/usr/bin/chromium";
const ARTIFACTS = resolve(process.env.TERRANAV_ARTIFACTS || join(here, "../../artifacts/ui"));
const FIRST_VIEW_S = Number(process.env.TERRANAV_FIRST_VIEW_S || 10);

const argv = process.argv.slice(2);
const url = argv.find((a) => !a.startsWith("--"));
const sinceIdx = argv.indexOf("--since-ms");
const t0 = sinceIdx >= 0 ? Number(argv[sinceIdx + 1]) : Date.now();
if (!url || !Number.isFinite(t0)) {
  console.error("usage: node web/tests/ui.mjs <station url> [--since-ms <unix ms of demo start>]");
  process.exit(2);
}
const base = new URL(url);
const token = base.searchParams.get("token");

const log = logger("ui", t0);
const shot = screenshots(ARTIFACTS, log);

async function robotsRest(page) {
  const headers = token ? { Authorization: `Bearer ${token}` } : {};
  const res = await page.request.get(new URL("/api/robots", base).href, { headers });
  if (!res.ok()) throw new Error(`GET /api/robots -> ${res.status()}`);
  return res.json();
}

async function main() {
  mkdirSync(ARTIFACTS, { recursive: true });
  const profile = mkdtempSync(join(tmpdir(), "terranav-ui-"));
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
  const consoleErrors = [];
  const page = ctx.pages()[0] || (await ctx.newPage());
  page.on("pageerror", (e) => pageErrors.push(e.message));
  page.on("console", (m) => { if (m.type() === "error") consoleErrors.push(m.text()); });
  const posts = [];
  page.on("request", (r) => {
    if (r.method() === "POST") posts.push({ url: r.url(), body: r.postData(), at: Date.now() });
  });
  const responses = [];
  page.on("response", (r) => {
    if (r.request().method() === "POST") responses.push({ url: r.url(), status: r.status() });
  });

  try {
    // 1. page loads
    await page.goto(url, { waitUntil: "domcontentloaded", timeout: 15000 });
    await until("page script started (window.terranav)", 10000, () => page.evaluate(() => !!window.terranav));
    log("page loaded");
    await shot(page, "loaded");

    // 2. tiles and a robot marker within FIRST_VIEW_S of the demo start
    const deadline = t0 + FIRST_VIEW_S * 1000;
    const seen = await until(`map tiles and a robot marker visible within ${FIRST_VIEW_S} s of the demo start`,
      Math.max(1000, deadline - Date.now()), () => page.evaluate(() => {
        const tiles = [...document.querySelectorAll("img.map-tile")].filter((i) => i.complete && i.naturalWidth > 0);
        const marker = document.querySelector(".robot-marker[data-robot]");
        return tiles.length > 0 && marker ? { tiles: tiles.length, robot: marker.dataset.robot } : null;
      }));
    const robot = seen.robot;
    log(`first view after ${((Date.now() - t0) / 1000).toFixed(1)} s: ${seen.tiles} tiles, robot ${robot}`);
    await shot(page, "tiles-and-robot");

    // lat/lon readout follows the cursor
    const mapBox = await page.locator("#map").boundingBox();
    await page.mouse.move(mapBox.x + mapBox.width / 2, mapBox.y + mapBox.height / 2);
    const readout = await until("cursor readout shows map x/y and lat/lon", 3000, async () => {
      const t = await page.locator("#readout").textContent();
      return /x -?\d+\.\d+ m, y -?\d+\.\d+ m/.test(t) && /°[NS] .*°[EW]|no GNSS datum/.test(t) ? t : null;
    });
    log("readout:", readout);

    // 3. keyboard drive: holding a key sends drive commands every 100 ms; release sends deadman:false
    await page.locator("#map").click({ position: { x: 5, y: mapBox.height - 60 } }); // focus the page, not an input
    await page.keyboard.press("Escape");
    const before = posts.length;
    await page.keyboard.down("ArrowUp");
    await sleep(650);
    await page.keyboard.up("ArrowUp");
    await sleep(300);
    const drives = posts.slice(before).filter((p) => p.url.includes(`/api/robots/${robot}/drive`));
    if (drives.length < 4) throw new StepFailed(`keyboard drive: expected >= 4 drive POSTs in 650 ms, got ${drives.length}`);
    const lastDrive = JSON.parse(drives[drives.length - 1].body || "{}");
    if (lastDrive.deadman !== false || lastDrive.v_mps !== 0) throw new StepFailed(`keyboard drive: release must send a zero command with deadman false, got ${JSON.stringify(lastDrive)}`);
    const driveFail = responses.filter((r) => r.url.includes("/drive") && r.status !== 202);
    if (driveFail.length) throw new StepFailed(`keyboard drive: station answered ${driveFail[0].status} to a drive command`);
    log(`keyboard drive: ${drives.length} commands, release sent deadman=false`);

    // 4. goal by clicking the map; try a few directions until the robot plans a path
    const pose = await until(`pose of ${robot} in GET /api/robots`, 5000, async () => {
      const r = (await robotsRest(page)).find((x) => x.robot === robot);
      return r && r.pose;
    });
    let goalOk = null;
    for (const [dist, dAng] of [[5, 0], [5, Math.PI / 3], [5, -Math.PI / 3], [4, Math.PI], [8, 0], [3, Math.PI / 2], [3, -Math.PI / 2]]) {
      const gx = pose.x_m + dist * Math.cos(pose.yaw_rad + dAng);
      const gy = pose.y_m + dist * Math.sin(pose.yaw_rad + dAng);
      const pt = await page.evaluate(([x, y]) => {
        const { map, ll } = window.terranav;
        map.setView(ll(x, y), Math.max(map.getZoom(), 3), { animate: false });
        const p = map.latLngToContainerPoint(ll(x, y));
        return { x: p.x, y: p.y };
      }, [gx, gy]);
      const goalBtn = page.locator("#goal-mode-btn");
      if (!(await goalBtn.getAttribute("class")).includes("active")) await goalBtn.click();
      const n0 = responses.length;
      await page.mouse.click(mapBox.x + pt.x, mapBox.y + pt.y);
      const resp = await until("goal POST answered", 5000, () => responses.slice(n0).find((r) => r.url.includes(`/api/robots/${robot}/goal`)));
      if (resp.status !== 202) throw new StepFailed(`goal: station answered ${resp.status} to the goal POST`);
      log(`goal sent by map click at (${gx.toFixed(2)}, ${gy.toFixed(2)})`);
      try {
        goalOk = await until("planned path drawn on the map", 12000, async () => {
          const drawn = await page.evaluate(() => {
            const p = document.querySelector("path.robot-path");
            const d = p && p.getAttribute("d");
            return d && (d.match(/L/g) || []).length >= 1 ? d.length : 0;
          });
          const r = (await robotsRest(page)).find((x) => x.robot === robot);
          const m = r && r.status && r.status.mission;
          if (m === "NoPath") throw new StepFailed("NoPath");
          return drawn && r && r.path && r.path.length >= 2 ? { pts: r.path.length, mission: m } : null;
        }, 300);
      } catch (e) {
        log(`no path to (${gx.toFixed(2)}, ${gy.toFixed(2)}): ${e.message}; trying another direction`);
        continue;
      }
      break;
    }
    if (!goalOk) throw new StepFailed("goal: no goal around the robot produced a planned path on the map");
    log(`path appeared: ${goalOk.pts} points, mission ${goalOk.mission}`);
    // Frame robot and path for the screenshot, with the cursor away from tooltips.
    await page.mouse.move(mapBox.x + mapBox.width - 5, mapBox.y + 5);
    await page.evaluate(() => {
      const { map } = window.terranav;
      const p = document.querySelector("path.robot-path");
      const r = [...window.terranav.state.robots.values()].find((x) => x.pathLine);
      if (p && r) map.fitBounds(r.pathLine.getBounds().pad(0.6), { animate: false, maxZoom: 5 });
    });
    await sleep(400);
    await shot(page, "goal-path");
    await sleep(1500);
    await shot(page, "driving");

    // 5. STOP (one click) -> status Stopped in the REST API and in the robot card
    await page.locator("#stop-btn").click();
    const stopped = await until("robot status Stopped after STOP (GET /api/robots and the robot card)", 5000, async () => {
      const r = (await robotsRest(page)).find((x) => x.robot === robot);
      const ui = await page.locator(`.robot-card[data-robot="${robot}"] [data-field=mission]`).textContent();
      return r && r.status && r.status.mission === "Stopped" && ui === "Stopped" ? r : null;
    });
    const stopResp = responses.find((r) => r.url.includes(`/api/robots/${robot}/stop`));
    if (!stopResp || stopResp.status !== 202) throw new StepFailed(`stop: POST answered ${stopResp && stopResp.status}`);
    await until("robot at standstill after STOP (|v| < 0.1 m/s)", 5000, async () => {
      const r = (await robotsRest(page)).find((x) => x.robot === robot);
      return r && r.pose && Math.abs(r.pose.v_mps) < 0.1;
    });
    log(`stopped: mission ${stopped.status.mission}, reason "${stopped.status.reason}"`);
    await sleep(300);
    await shot(page, "stopped");

    if (pageErrors.length) throw new StepFailed(`uncaught errors in the page: ${pageErrors.join(" | ")}`);
    if (consoleErrors.length) log(`console errors (not fatal): ${consoleErrors.slice(0, 5).join(" | ")}`);
    log("PASS");
    return 0;
  } catch (e) {
    try {
      await shot(page, "failure");
    } catch {
      // the screenshot is best effort; the step's message matters more
    }
    const logText = await page.locator("#log").innerText().catch(() => "");
    console.error(`UI TEST FAILED: ${e instanceof StepFailed ? e.message : e.stack || e}`);
    if (pageErrors.length) console.error(`page errors: ${pageErrors.join(" | ")}`);
    if (logText) console.error(`UI log:\n${logText.split("\n").slice(0, 15).join("\n")}`);
    return 1;
  } finally {
    await ctx.close().catch(() => {});
    rmSync(profile, { recursive: true, force: true });
  }
}

main().then((code) => process.exit(code), (e) => {
  console.error(`UI TEST FAILED: ${e.stack || e}`);
  process.exit(1);
});
