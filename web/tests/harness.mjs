// What the browser scripts share: a step failure, polling until a condition holds, timestamped
// logs and numbered screenshots.
import { join } from "node:path";

/** A check that failed: ends the step with this message (not retried by `until`). */
export class StepFailed extends Error {}

/** Resolves after `ms` milliseconds. */
export const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

/** A logger whose lines read `[tag +12.3s] ...`, seconds since `t0` (epoch ms). */
export function logger(tag, t0) {
  return (...a) => console.log(`[${tag} +${((Date.now() - t0) / 1000).toFixed(1)}s]`, ...a);
}

/**
 * Polls `fn` every `everyMs` until it returns a truthy value (returned) or `ms` passes, then fails
 * the step with `what` and the last value or error seen. A `StepFailed` thrown by `fn` ends the
 * wait at once.
 */
export async function until(what, ms, fn, everyMs = 200) {
  const end = Date.now() + ms;
  let last;
  for (;;) {
    try {
      last = await fn();
      if (last) return last;
    } catch (e) {
      if (e instanceof StepFailed) throw e;
      last = e.message;
    }
    if (Date.now() > end) throw new StepFailed(`${what} (waited ${(ms / 1000).toFixed(1)} s; last: ${JSON.stringify(last)})`);
    await sleep(everyMs);
  }
}

/** A screenshot taker: `shot(page, name, path?)` writes `dir/NN-name.png` (or `path`) and logs it. */
export function screenshots(dir, log) {
  let n = 0;
  return async (page, name, path) => {
    const file = path || join(dir, `${String(++n).padStart(2, "0")}-${name}.png`);
    await page.screenshot({ path: file });
    log("screenshot", file);
  };
}
