// The dead-man heartbeat is sent by the realtime worker, not the page's main thread:
// rendering (a software GPU, a synchronous WebGL call in an XR runtime) can stall the
// main thread for longer than the server's dead-man timeout, and a stalled page must
// not lose its lease for that. The arm still never moves without fresh commands from
// the main thread, and the worker stops beating once the main thread has been silent
// for PAGE_SILENCE_MS, so the server's dead-man then stops the arm.
//
// A page silent that long is mostly not hung but waiting for the CPU: on a loaded 2-core
// machine the main thread stood still for 1–6 s at a time (issue 55: 6.1 s with a
// policy supervised; docs/PERFORMANCE.md: up to 4.3 s), and the server took the lease
// after its grace (2 s) from an operator holding the dead-man, a correction's with it
// (the policy paused). So when the dead-man was held at the page's last check-in, once
// the server has said it stopped the arm (a STATE with HALTED stamped after the beats
// stopped: PageSilence), the worker beats again and the page keeps its lease, the arm
// still stopped: only the main thread sends commands, it is silent, and one it sent
// before the silence is stale by then (the server refuses it). Past PAGE_HUNG_MS the
// page is taken for hung: no heartbeat, and the lease lapses after the server's grace.
// With the dead-man let go, a silent page loses its lease after the grace as before.
import { StateFlags } from "./messages";

export const HEARTBEAT_PERIOD_MS = 50;
export const PAGE_CHECK_IN_MS = 100;
export const PAGE_SILENCE_MS = 1000;
export const PAGE_HUNG_MS = 10_000;
const MIN_GAP_MS = 40; // any command counts as a heartbeat

export interface HeartbeatInputs {
  now: number; // ms, the worker's clock
  wanted: boolean; // the page holds control or is asking for it
  lastSent: number; // the last heartbeat or command
  pageSeen: number; // the main thread's last check-in
  /** The page holds control with the dead-man held, and the server has stopped its arm
   * since the page went silent past PAGE_SILENCE_MS (PageSilence): the lease is kept. */
  armStopped?: boolean;
}

/** Why the worker's timer sent no heartbeat this time: nobody wants control, the page's
 * main thread has been silent too long (past PAGE_SILENCE_MS until the server has
 * stopped the arm: a silent page must let the dead-man stop it; past PAGE_HUNG_MS for
 * good: a hung page loses its lease), or another message went out less than MIN_GAP_MS
 * ago. */
export type BeatSkip = "unwanted" | "pageSilent" | "recent";

export function heartbeatSkip(i: HeartbeatInputs): BeatSkip | null {
  if (!i.wanted) return "unwanted";
  const silent = i.now - i.pageSeen;
  if (silent > PAGE_HUNG_MS || (silent > PAGE_SILENCE_MS && !i.armStopped)) return "pageSilent";
  if (i.now - i.lastSent < MIN_GAP_MS) return "recent";
  return null;
}

/** The page's main thread as the worker sees it: its last check-in, whether its
 * dead-man was held then, and whether the server has stopped this page's arm since the
 * page went silent. The beats stop when the page has been silent PAGE_SILENCE_MS; a STATE
 * stamped after that moment that says this page has control and its arm is HALTED is the
 * server's dead-man having stopped the arm for that silence (or after it): from then on,
 * with the dead-man held, the heartbeats keep the lease (heartbeatSkip's `armStopped`)
 * until the page checks in again or PAGE_HUNG_MS. */
export class PageSilence {
  private stopped = false;
  /** The dead-man (a key, the gamepad's, an XR grip) is held, as the page said last. */
  deadman = false;

  constructor(public seen: number) {}

  /** The main thread checked in (any message) at `now` (ms, the worker's clock). */
  checkIn(now: number): void {
    this.seen = now;
    this.stopped = false;
  }

  /** A STATE's flags, stamped `at` (its server time on the worker's clock, ms; null: the
   * clock is not synced yet, so when it was said is unknown). True when it is the news
   * that the arm is stopped during this silence (beat at once: the lease is kept). */
  state(flags: number, at: number | null): boolean {
    if (this.stopped || at === null || at < this.seen + PAGE_SILENCE_MS) return false;
    const halted = StateFlags.YOU_HAVE_CONTROL | StateFlags.HALTED;
    this.stopped = (flags & halted) === halted;
    return this.stopped;
  }

  /** The server has stopped the arm since the page went silent. */
  get armStopped(): boolean {
    return this.stopped;
  }

  /** The heartbeat due at `now` (null: send one), or why not: `wanted`, the page holds
   * control or asks for it (and is visible); `hasControl`, the last STATE said it holds
   * it; `lastSent`, the last message that counts as a heartbeat went out then. */
  skip(now: number, wanted: boolean, hasControl: boolean, lastSent: number): BeatSkip | null {
    const armStopped = hasControl && this.deadman && this.stopped;
    return heartbeatSkip({ now, wanted, lastSent, pageSeen: this.seen, armStopped });
  }
}

export function heartbeatDue(i: HeartbeatInputs): boolean {
  return heartbeatSkip(i) === null;
}

/** How long a late heartbeat timer is remembered (and said) after it was late. */
export const LATE_MEMORY_MS = 3000;

/** How late the worker's heartbeat timer fired, worst of the last LATE_MEMORY_MS: the
 * page's own share of a dead-man halt. A timer 100+ ms late means this computer did
 * not give the worker its turn (a software GPU or another program taking the cores);
 * a halt with the timer on time means the network or the server held the heartbeats. */
export class TimerLateness {
  private last: number | null = null;
  private worst = 0;
  private worstAt = -Infinity;

  /** The timer fired at `now` (ms); it was set for every `period` ms. */
  fired(now: number, period: number): void {
    if (this.last !== null) {
      const late = Math.max(0, now - this.last - period);
      if (late >= this.worst || now - this.worstAt > LATE_MEMORY_MS) {
        this.worst = late;
        this.worstAt = now;
      }
    }
    this.last = now;
  }

  /** The worst lateness (ms) seen in the last LATE_MEMORY_MS, at `now`, or the timer's
   * lateness right now if it is overdue (a worker that has just got its turn may handle
   * the server's news of a halt before its late timer fires). */
  recent(now: number, period: number): number {
    const overdue = this.last === null ? 0 : Math.max(0, now - this.last - period);
    return Math.max(overdue, now - this.worstAt <= LATE_MEMORY_MS ? this.worst : 0);
  }
}

/** What the worker's heartbeats did: the worst gap between two messages that went out
 * (the server's dead-man sees the same gaps, plus the network's), and the timer's
 * firings that sent nothing, by reason. With the timer on time, a long gap here says
 * the worker chose not to send (its reason counted); a halt with short gaps here was
 * held on the way (Chromium's socket, the network or the server). */
export class BeatRecord {
  readonly skips: Record<BeatSkip, number> = { unwanted: 0, pageSilent: 0, recent: 0 };
  private gaps = new TimerLateness();
  private lastSeen: number | null = null;

  /** The timer fired; it sent nothing for `skip` (null: it sent), and the last message
   * that counts as a heartbeat went out at `lastSent` (ms). Gaps are counted only while
   * control is wanted: a page that does not want it sends nothing, by design. */
  fired(skip: BeatSkip | null, lastSent: number): void {
    if (skip !== null) this.skips[skip] += 1;
    if (skip === "unwanted") {
      this.gaps = new TimerLateness();
      this.lastSeen = null;
    } else if (lastSent !== this.lastSeen) {
      this.gaps.fired(lastSent, 0);
      this.lastSeen = lastSent;
    }
  }

  /** The worst gap between messages sent (ms) in the last LATE_MEMORY_MS, at `now`, or
   * the current one if nothing has gone out for longer. */
  worstGap(now: number): number {
    return this.lastSeen === null ? 0 : this.gaps.recent(now, 0);
  }
}
