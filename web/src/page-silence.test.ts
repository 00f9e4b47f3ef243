// The worker's heartbeats for a page whose main thread stands still (issue 55): the
// dead-man stops the arm first, then, with the dead-man held, the lease is kept, up to
// PAGE_HUNG_MS. Unit cases, then the rule over generated sequences: a simulated server
// (its dead-man and grace, its STATEs stamped on its own clock) and the worker's
// PageSilence, over random main-thread stalls, dead-man presses, timer lateness and link
// delays.
import { describe, expect, it } from "vitest";
import { HEARTBEAT_PERIOD_MS, PAGE_CHECK_IN_MS, PAGE_HUNG_MS, PAGE_SILENCE_MS, PageSilence, heartbeatSkip } from "./transport/heartbeat";
import { StateFlags } from "./transport/messages";

const MINE = StateFlags.YOU_HAVE_CONTROL | StateFlags.SOMEONE_HAS_CONTROL;
const HALTED = MINE | StateFlags.HALTED;

describe("a silent page: the dead-man stops the arm, then the lease is kept", () => {
  it("stops beating past PAGE_SILENCE_MS until the server says the arm stopped", () => {
    const page = new PageSilence(0);
    page.deadman = true;
    const silent = PAGE_SILENCE_MS + 100;
    expect(page.skip(silent, true, true, 0)).toBe("pageSilent");
    expect(page.state(HALTED, PAGE_SILENCE_MS - 1)).toBe(false); // said before the silence
    expect(page.state(MINE, silent)).toBe(false); // not halted
    expect(page.state(HALTED, null)).toBe(false); // when, unknown (no clock sync yet)
    expect(page.skip(silent, true, true, 0)).toBe("pageSilent");
    expect(page.state(HALTED, PAGE_SILENCE_MS)).toBe(true); // stopped: beat at once
    expect(page.skip(silent, true, true, 0)).toBe(null);
    expect(page.skip(silent, true, false, 0)).toBe("pageSilent"); // control went meanwhile
    expect(page.skip(silent, false, true, 0)).toBe("unwanted"); // a hidden page
    expect(page.skip(PAGE_HUNG_MS + 1, true, true, 0)).toBe("pageSilent"); // hung: for good
    page.deadman = false; // let go before the page went silent: it loses the lease as before
    expect(page.skip(silent, true, true, 0)).toBe("pageSilent");
  });

  it("needs this page's control in the same STATE, and a check-in starts afresh", () => {
    const page = new PageSilence(0);
    page.deadman = true;
    expect(page.state(StateFlags.SOMEONE_HAS_CONTROL | StateFlags.HALTED, PAGE_SILENCE_MS)).toBe(false);
    expect(page.state(HALTED, PAGE_SILENCE_MS)).toBe(true);
    page.checkIn(5_000);
    expect(page.armStopped).toBe(false);
    expect(page.skip(5_000 + PAGE_SILENCE_MS + 1, true, true, 0)).toBe("pageSilent");
  });

  it("heartbeatSkip alone keeps today's answer for a silent page", () => {
    const base = { now: 10_000, wanted: true, lastSent: 9_950 };
    expect(heartbeatSkip({ ...base, pageSeen: base.now - PAGE_SILENCE_MS - 1 })).toBe("pageSilent");
    expect(heartbeatSkip({ ...base, pageSeen: base.now - PAGE_SILENCE_MS - 1, armStopped: true })).toBe(null);
    expect(heartbeatSkip({ ...base, pageSeen: base.now - PAGE_HUNG_MS - 1, armStopped: true })).toBe("pageSilent");
  });
});

// ------------------------------------------------------------ generated sequences

/** A small seeded generator (mulberry32): the same sequences every run. */
function rng(seed: number): () => number {
  let a = seed >>> 0;
  return () => {
    a = (a + 0x6d2b79f5) >>> 0;
    let t = a;
    t = Math.imul(t ^ (t >>> 15), t | 1);
    t ^= t + Math.imul(t ^ (t >>> 7), t | 61);
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
}

const LIMIT = 180; // the server's dead-man (ms; the longest the settings allow)
const GRACE = 2000; // its lease grace (the plain one: the extension only lengthens it)
const TICK = 10; // its dead-man's check
const STATE_EVERY = 20; // its STATEs (50 Hz)
const STEP = 5; // the simulation's step (ms)

interface Run {
  /** When the server's arm was stopped by the dead-man: [from, until a message was heard). */
  stops: { from: number; until: number }[];
  /** When the lease lapsed (null: kept to the end). */
  lapsed: number | null;
  /** Beats sent while the page was silent past PAGE_SILENCE_MS with the arm not stopped
   * by the server at any moment since then. */
  unsafeBeats: number;
  /** Beats sent while the page was silent past PAGE_HUNG_MS. */
  hungBeats: number;
  /** The page's silences: [its last check-in, when it checked in again] (ms). */
  silences: [number, number][];
}

/** A stand-still of the page's main thread: [start, length] (ms), the dead-man held through it. */
type Stall = [number, number, boolean];

/** One sequence: a page holding control for `durationMs`, its main thread standing
 * still for the `stalls`, its worker's timer late by up to `lateMs`, each message on
 * the way up to `delayMs`. Times are the worker's clock; the server stamps its STATEs on
 * its own, `offset` ahead (known to the worker: synced). */
function simulate(r: () => number, stalls: Stall[], durationMs: number, lateMs: number, delayMs: number): Run {
  const offset = 1e6 * r();
  const delay = () => 1 + r() * delayMs;
  const run: Run = { stops: [], lapsed: null, unsafeBeats: 0, hungBeats: 0, silences: [] };
  const page = new PageSilence(0);
  // The server: the holder's last message heard, the dead-man's stop.
  let lastHeard = 0;
  let holder = true;
  let nextTick = 0;
  let nextState = 0;
  const stopped = () => run.stops.at(-1)?.until === Infinity;
  const toServer: number[] = []; // arrival times of the worker's messages
  const toWorker: { at: number; flags: number; stamp: number }[] = [];
  // The worker.
  let hasControl = true;
  let lastSent = 0;
  let nextTimer = HEARTBEAT_PERIOD_MS;
  let nextCheckIn = PAGE_CHECK_IN_MS;
  const send = (now: number, beat: boolean) => {
    lastSent = now;
    toServer.push(now + delay());
    if (!beat) return;
    const silentSince = page.seen + PAGE_SILENCE_MS;
    if (now - page.seen > PAGE_HUNG_MS) run.hungBeats += 1;
    if (now > silentSince && !run.stops.some((s) => s.from <= now && s.until > silentSince)) run.unsafeBeats += 1;
  };
  let stalled: Stall | null = null;
  for (let now = 0; now <= durationMs; now += STEP) {
    // The main thread: checks in every PAGE_CHECK_IN_MS unless it stands still, saying
    // the dead-man as it is (as it will be held through the next stall).
    const stall = stalls.find(([s, len]) => now >= s && now < s + len) ?? null;
    if (stall !== stalled) {
      if (stall) run.silences.push([page.seen, stall[0] + stall[1]]);
      stalled = stall;
    }
    if (!stall && now >= nextCheckIn) {
      page.checkIn(now);
      page.deadman = stalls.find(([s]) => s > now)?.[2] ?? true;
      nextCheckIn = now + PAGE_CHECK_IN_MS;
      if (r() < 0.5 && hasControl) send(now, false); // a command, the dead-man held
    }
    // The server: messages heard (any ends the dead-man's stop, as the server's does; the
    // arm itself moves again only on a fresh command), STATEs, its dead-man.
    while (toServer.length && toServer[0]! <= now) {
      toServer.shift();
      if (!holder) continue;
      lastHeard = now;
      if (stopped()) run.stops.at(-1)!.until = now;
    }
    if (now >= nextState) {
      nextState += STATE_EVERY;
      const flags = (holder ? MINE : StateFlags.SOMEONE_HAS_CONTROL) | (stopped() ? StateFlags.HALTED : 0);
      const at = Math.max(now + delay(), toWorker.at(-1)?.at ?? 0); // in order (TCP)
      toWorker.push({ at, flags, stamp: now + offset });
    }
    if (now >= nextTick) {
      nextTick += TICK;
      if (holder && now - lastHeard > LIMIT + GRACE) {
        holder = false;
        if (stopped()) run.stops.at(-1)!.until = now;
        run.lapsed = now;
      } else if (holder && !stopped() && now - lastHeard > LIMIT) run.stops.push({ from: now, until: Infinity });
    }
    // The worker: STATEs in (the news of a stop beats at once), its heartbeat timer.
    while (toWorker.length && toWorker[0]!.at <= now) {
      const s = toWorker.shift()!;
      hasControl = (s.flags & StateFlags.YOU_HAVE_CONTROL) !== 0;
      if (page.state(s.flags, s.stamp - offset) && page.skip(now, hasControl, hasControl, lastSent) === null) send(now, true);
    }
    if (now >= nextTimer) {
      nextTimer = now + HEARTBEAT_PERIOD_MS + (r() < 0.2 ? r() * lateMs : 0);
      if (page.skip(now, hasControl, hasControl, lastSent) === null) send(now, true);
    }
  }
  return run;
}

function stallsFor(r: () => number, durationMs: number, longestMs: number, held = () => r() < 0.7): Stall[] {
  const stalls: Stall[] = [];
  let t = 500 + r() * 2000;
  while (t < durationMs - longestMs - 3000) {
    const len = r() < 0.5 ? 200 + r() * 1500 : r() * longestMs;
    stalls.push([t, len, held()]);
    t += len + 300 + r() * 3000;
  }
  return stalls;
}

describe("the rule over generated sequences", () => {
  it("a beat for a page silent past PAGE_SILENCE_MS only once the dead-man has stopped the arm; none past PAGE_HUNG_MS", () => {
    for (let seed = 1; seed <= 120; seed++) {
      const r = rng(seed);
      const run = simulate(r, stallsFor(r, 40_000, PAGE_HUNG_MS + 4000), 40_000, 500, 400);
      expect(run.unsafeBeats, `seed ${seed}`).toBe(0);
      expect(run.hungBeats, `seed ${seed}`).toBe(0);
      // Every silence long enough for the dead-man saw the arm stopped during it.
      for (const [from, to] of run.silences) {
        if (run.lapsed !== null && run.lapsed < to) break;
        if (to - from > PAGE_SILENCE_MS + LIMIT + 2 * 400 + 500 + TICK) {
          expect(run.stops.some((h) => h.from >= from && h.from <= to), `seed ${seed}: silence ${from}–${to}`).toBe(true);
        }
      }
    }
  });

  it("a page that stands still for less than PAGE_HUNG_MS, the dead-man held, keeps its lease; one hung for longer loses it", () => {
    for (let seed = 1; seed <= 120; seed++) {
      const r = rng(1000 + seed);
      const kept = simulate(r, stallsFor(r, 40_000, PAGE_HUNG_MS - 500, () => true), 40_000, 300, 300);
      expect(kept.lapsed, `seed ${seed}`).toBe(null);
      const hungAt = 2000 + r() * 3000;
      const hung = simulate(r, [[hungAt, 30_000, true]], 40_000, 300, 300);
      expect(hung.lapsed, `seed ${seed}`).not.toBe(null);
      expect(hung.lapsed!).toBeGreaterThan(hungAt + PAGE_HUNG_MS);
      expect(hung.lapsed!).toBeLessThan(hungAt + PAGE_HUNG_MS + LIMIT + GRACE + 1000);
    }
  });

  it("with the dead-man let go, a page that stands still loses its lease after the server's grace, as before", () => {
    for (let seed = 1; seed <= 60; seed++) {
      const r = rng(2000 + seed);
      const at = 2000 + r() * 3000;
      const run = simulate(r, [[at, 8000, false]], 15_000, 300, 300);
      expect(run.lapsed, `seed ${seed}`).not.toBe(null);
      expect(run.lapsed!).toBeLessThan(at + PAGE_SILENCE_MS + LIMIT + GRACE + 1000);
    }
  });
});
