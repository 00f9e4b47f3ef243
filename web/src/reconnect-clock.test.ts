// After the link drops and the page connects afresh (a server restart), it syncs its
// clock with the server it reaches now: the offset measured against the server before
// is not carried over (a fake WebSocket and fake timers).
import { afterEach, beforeEach, describe, expect, it, vi } from "vitest";
import { decode, encode } from "./transport/codec";
import * as M from "./transport/messages";
import { RealtimeClient } from "./transport/realtime";

class FakeSocket {
  static all: FakeSocket[] = [];
  static readonly OPEN = 1;
  readyState = 0;
  binaryType = "";
  sent: ArrayBuffer[] = [];
  onopen: (() => void) | null = null;
  onclose: ((ev: { reason: string }) => void) | null = null;
  onmessage: ((ev: { data: ArrayBuffer }) => void) | null = null;
  constructor(readonly url: string) {
    FakeSocket.all.push(this);
  }
  send(data: ArrayBuffer): void {
    this.sent.push(data);
  }
  close(): void {
    if (this.readyState === 3) return;
    this.readyState = 3;
    this.onclose?.({ reason: "" });
  }
  open(): void {
    this.readyState = 1;
    this.onopen?.();
  }
  /** The server answers every PING sent so far, its clock `offset` s ahead of the page's
   * (received and answered at once, half-way through the round trip). */
  pong(offset: number): void {
    const now = performance.now() / 1000;
    for (const d of this.sent) {
      const m = decode(d);
      if (m.type !== "PING") continue;
      const t = (m.t0 + now) / 2 + offset;
      this.onmessage?.({ data: encode(M.PONG, { seq: m.seq, t0: m.t0, t1: t, t2: t }) });
    }
    this.sent = this.sent.filter((d) => decode(d).type !== "PING");
  }
  /** client_time of the last CART_INC sent. */
  lastCommandTime(): number {
    const m = decode(this.sent.filter((d) => decode(d).type === "CART_INC").at(-1)!);
    return (m as unknown as { client_time: number }).client_time;
  }
}

describe("a fresh connection after a server restart", () => {
  beforeEach(() => {
    FakeSocket.all = [];
    vi.useFakeTimers();
    vi.stubGlobal("WebSocket", FakeSocket);
  });
  afterEach(() => {
    vi.useRealTimers();
    vi.unstubAllGlobals();
  });

  it("syncs the clock with the new server, not the one before", () => {
    const client = new RealtimeClient("ws://x/ws", "secret", {});
    client.connect();
    const old = FakeSocket.all[0]!;
    old.open();
    vi.advanceTimersByTime(1); // the first PING
    old.pong(100); // the old server's clock: 100 s ahead, round trip 0 (none better)
    expect(client.offset).toBeCloseTo(100, 6);
    old.close(); // the server is gone
    vi.advanceTimersByTime(1000); // reconnecting…
    const fresh = FakeSocket.all[1]!;
    expect(fresh).not.toBe(old);
    fresh.open(); // a new server process, its clock 5 s ahead (e.g. its machine rebooted)
    vi.advanceTimersByTime(1); // the first PING…
    vi.advanceTimersByTime(10); // …answered 10 ms later: a longer round trip than the old one's
    fresh.pong(5);
    expect(client.offset).toBeCloseTo(5, 6);
    // Commands carry their send time on the new server's clock (else it finds them
    // seconds old, or from the future, and its stale-command checks go wrong).
    client.cartesian([0.001, 0, 0], [0, 0, 0], M.Frame.BASE);
    expect(fresh.lastCommandTime() - performance.now() / 1000).toBeCloseTo(5, 2);
  });

  it("keeps the clock when the session resumes on a new connection to the same server", async () => {
    // (resume.test.ts covers the resume itself; here only that the offset stays.)
    const client = new RealtimeClient("ws://x/ws", "secret", {});
    client.connect();
    const first = FakeSocket.all[0]!;
    first.open();
    first.onmessage?.({ data: encode(M.WELCOME, { version: M.PROTOCOL_VERSION, role: 1, server_time: 0, joints: 6 }, `abc ${"k".repeat(32)}`) });
    vi.advanceTimersByTime(1);
    first.pong(7);
    vi.advanceTimersByTime(1000); // silent: stalled, resume attempts go out
    const attempt = FakeSocket.all[1]!;
    attempt.open();
    attempt.onmessage?.({ data: encode(M.WELCOME, { version: M.PROTOCOL_VERSION, role: 1, server_time: 0, joints: 6 }, `abc ${"k".repeat(32)}`) });
    expect(client.resumes).toBe(1);
    expect(client.offset).toBeCloseTo(7, 6);
  });
});
