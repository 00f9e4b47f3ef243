// The page's estimate of the server's clock, from PING/PONG exchanges (NTP's rule: the
// offset of the exchange with the least round trip is the most trustworthy). Only the
// last WINDOW exchanges count, so the estimate follows two clocks that drift apart (a
// 100 ppm drift is 0.36 s an hour: a fixed offset would make every command look
// stale to the server's age check, which compares our send time with its clock).
export const WINDOW = 16; // exchanges; pinged every PING_EVERY_MS: ~30 s of history
export const PING_EVERY_MS = 2000;

export interface Exchange {
  rtt: number; // s, without the server's own processing time
  offset: number; // server clock − page clock (s)
}

export class ClockSync {
  private readonly recent: Exchange[] = [];

  /** One exchange: sent at page time t0, the server received at t1 and answered at t2
   * (its clock), back at page time t3. */
  add(t0: number, t1: number, t2: number, t3: number): void {
    const rtt = t3 - t0 - (t2 - t1);
    if (!Number.isFinite(rtt) || rtt < 0) return;
    this.recent.push({ rtt, offset: (t1 - t0 + (t2 - t3)) / 2 });
    if (this.recent.length > WINDOW) this.recent.shift();
  }

  /** True once one exchange came back: until then the page cannot say when, on the
   * server's clock, it sends anything. */
  get synced(): boolean {
    return this.recent.length > 0;
  }

  private best(): Exchange | undefined {
    let best: Exchange | undefined;
    for (const e of this.recent) if (!best || e.rtt < best.rtt) best = e;
    return best;
  }

  /** The least round trip among the recent exchanges (s); Infinity before any. */
  get bestRtt(): number {
    return this.best()?.rtt ?? Infinity;
  }

  /** Server clock − page clock (s); 0 before any exchange. */
  get offset(): number {
    return this.best()?.offset ?? 0;
  }
}
