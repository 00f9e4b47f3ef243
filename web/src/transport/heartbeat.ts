// The dead-man heartbeat is sent by the realtime worker, not the page's main thread:
// rendering (a software GPU, a synchronous WebGL call in an XR runtime) can stall the
// main thread for longer than the server's dead-man timeout, and a stalled page must
// not lose its lease for that. The arm still never moves without fresh commands from
// the main thread, and the worker stops beating once the main thread has been silent
// for PAGE_SILENCE_MS (a hung page), so the server's dead-man then stops the arm.
export const HEARTBEAT_PERIOD_MS = 50;
export const PAGE_CHECK_IN_MS = 100;
export const PAGE_SILENCE_MS = 1000;
const MIN_GAP_MS = 40; // any command counts as a heartbeat

export interface HeartbeatInputs {
  now: number; // ms, the worker's clock
  wanted: boolean; // the page holds control or is asking for it
  lastSent: number; // the last heartbeat or command
  pageSeen: number; // the main thread's last check-in
}

/** Why the worker's timer sent no heartbeat this time: nobody wants control, the page's
 * main thread has been silent too long (a hung page must let the dead-man stop the
 * arm), or another message went out less than MIN_GAP_MS ago. */
export type BeatSkip = "unwanted" | "pageSilent" | "recent";

export function heartbeatSkip(i: HeartbeatInputs): BeatSkip | null {
  if (!i.wanted) return "unwanted";
  if (i.now - i.pageSeen > PAGE_SILENCE_MS) return "pageSilent";
  if (i.now - i.lastSent < MIN_GAP_MS) return "recent";
  return null;
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
