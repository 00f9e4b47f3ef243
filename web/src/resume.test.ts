// The realtime client resumes its session on a new connection when its link stalls
// (a fake WebSocket and fake timers: what it sends, which socket it keeps).
import { afterEach, beforeEach, describe, expect, it, vi } from "vitest";
import { decode, encode } from "./transport/codec";
import * as M from "./transport/messages";
import { RESUME_ATTEMPTS, RESUME_EVERY_MS, RESUME_GIVE_UP_MS, RealtimeClient, STALL_MS } from "./transport/realtime";

class FakeSocket {
  static all: FakeSocket[] = [];
  static readonly OPEN = 1;
  readyState = 0;
  binaryType = "";
  sent: ArrayBuffer[] = [];
  closed = false;
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
    if (this.closed) return;
    this.closed = true;
    this.readyState = 3;
    this.onclose?.({ reason: "" });
  }
  open(): void {
    this.readyState = 1;
    this.onopen?.();
  }
  deliver(data: ArrayBuffer): void {
    this.onmessage?.({ data });
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
  hellos(): { flags: number; token: string }[] {
    return this.sent
      .map((d) => decode(d))
      .filter((m) => m.type === "HELLO")
      .map((m) => {
        const h = m as unknown as { flags: number; token: Uint8Array };
        return { flags: h.flags, token: new TextDecoder().decode(h.token).replace(/\0+$/, "") };
      });
  }
}

const welcome = (text: string) => encode(M.WELCOME, { version: M.PROTOCOL_VERSION, role: 1, server_time: 0, joints: 6, arms: 1 }, text);
const KEY = "k".repeat(32);

// Every test: a fake WebSocket and fake timers.
beforeEach(() => {
  FakeSocket.all = [];
  vi.useFakeTimers();
  vi.stubGlobal("WebSocket", FakeSocket);
});
afterEach(() => {
  vi.useRealTimers();
  vi.unstubAllGlobals();
});

/** A client connected and welcomed on the first fake socket. */
function connected() {
  const seen: string[] = [];
  const client = new RealtimeClient("ws://x/ws", "secret", { connection: (up, why) => seen.push(`${up} ${why}`) });
  client.connect();
  const first = FakeSocket.all[0]!;
  first.open();
  first.deliver(welcome(`abc ${KEY}`));
  return { client, first, seen };
}

describe("a stalled link", () => {
  it("asks for a resume key and, silent past the stall limit, resumes on the first new connection to open", () => {
    const { client, first, seen } = connected();
    expect(first.hellos()[0]).toEqual({ flags: M.HelloFlags.SYNCED_CLOCK | M.HelloFlags.RESUMABLE, token: "secret" });
    vi.advanceTimersByTime(STALL_MS - 100);
    expect(FakeSocket.all).toHaveLength(1); // not stalled yet
    vi.advanceTimersByTime(200 + 2 * RESUME_EVERY_MS);
    const attempts = FakeSocket.all.slice(1);
    expect(attempts.length).toBeGreaterThanOrEqual(2); // in parallel: a SYN may be lost
    attempts[1]!.open(); // the second opens first: it resumes, alone
    attempts[0]!.open();
    expect(attempts[1]!.hellos()).toEqual([{ flags: M.HelloFlags.SYNCED_CLOCK | M.HelloFlags.RESUMABLE | M.HelloFlags.RESUME, token: KEY }]);
    expect(attempts[0]!.hellos()).toEqual([]);
    expect(attempts[0]!.closed).toBe(true);
    vi.advanceTimersByTime(5 * RESUME_EVERY_MS); // no new attempts while one is resuming
    expect(FakeSocket.all.length).toBe(1 + attempts.length);
    attempts[1]!.deliver(welcome(`abc ${KEY}`));
    expect(first.closed).toBe(true);
    expect(client.resumes).toBe(1);
    expect(seen.at(-1)).toMatch(/^true resumed on a new connection after \d+ ms/);
    client.heartbeat(); // the new connection carries what follows
    expect(decode(attempts[1]!.sent.at(-1)!).type).toBe("HEARTBEAT");
    expect(seen.filter((s) => s.startsWith("false"))).toEqual([]); // never said "down"
  });

  it("still resumes when the old connection's news gets through first, but tries no more", () => {
    // (Our side of the old connection may still wait on TCP's retransmission timer.)
    const { client, first } = connected();
    vi.advanceTimersByTime(STALL_MS + 200);
    const attempt = FakeSocket.all[1]!;
    first.deliver(welcome(`abc ${KEY}`)); // any message: the server's side is back
    expect(attempt.closed).toBe(false);
    vi.advanceTimersByTime(STALL_MS - 100);
    expect(FakeSocket.all).toHaveLength(2); // heard from: no new attempt
    attempt.open();
    expect(attempt.hellos()[0]!.flags & M.HelloFlags.RESUME).toBeTruthy();
    attempt.deliver(welcome(`abc ${KEY}`));
    expect(client.resumes).toBe(1);
    expect(first.closed).toBe(true);
  });

  it("keeps at most RESUME_ATTEMPTS connections opening, and starts afresh after RESUME_GIVE_UP_MS", () => {
    const { first, seen } = connected();
    vi.advanceTimersByTime(STALL_MS + 20 * RESUME_EVERY_MS); // none of them ever opens
    const attempts = FakeSocket.all.slice(1);
    expect(attempts.length).toBeGreaterThan(RESUME_ATTEMPTS);
    expect(attempts.filter((a) => !a.closed)).toHaveLength(RESUME_ATTEMPTS); // the oldest closed
    vi.advanceTimersByTime(RESUME_GIVE_UP_MS);
    expect(first.closed).toBe(true);
    expect(seen.at(-1)).toBe("false the link stalled too long; reconnecting…");
    expect(FakeSocket.all.slice(1, -1).every((a) => a.closed)).toBe(true);
    vi.advanceTimersByTime(1);
    const fresh = FakeSocket.all.at(-1)!;
    fresh.open();
    expect(fresh.hellos()[0]!.token).toBe("secret"); // a new session, not a resume
  });

  it("takes the next key from each resume's WELCOME: a key resumes once", () => {
    const { client, first } = connected();
    vi.advanceTimersByTime(STALL_MS + 200);
    const attempt = FakeSocket.all[1]!;
    attempt.open();
    expect(attempt.hellos()[0]!.token).toBe(KEY);
    const next = "n".repeat(32);
    attempt.deliver(welcome(`abc ${next}`));
    expect(first.closed).toBe(true);
    vi.advanceTimersByTime(STALL_MS + 200); // stalled again: resumed with the new key
    const again = FakeSocket.all.at(-1)!;
    expect(again).not.toBe(attempt);
    again.open();
    expect(again.hellos()[0]!.token).toBe(next);
    again.deliver(welcome(`abc ${"m".repeat(32)}`));
    expect(client.resumes).toBe(2);
  });

  it("the server closing the old connection before the resume's WELCOME arrives is no reason to start afresh", () => {
    const { client, first, seen } = connected();
    vi.advanceTimersByTime(STALL_MS + 200);
    const attempt = FakeSocket.all[1]!;
    attempt.open(); // its HELLO resumes: the server closes the old connection at once…
    first.close();
    vi.advanceTimersByTime(50);
    attempt.deliver(welcome(`abc ${"n".repeat(32)}`)); // …and then welcomes the new one
    expect(client.resumes).toBe(1);
    vi.advanceTimersByTime(2000);
    expect(FakeSocket.all.filter((s) => s.hellos().some((h) => h.token === "secret"))).toEqual([first]); // no fresh session
    expect(seen.filter((s) => s.startsWith("false"))).toEqual([]);
    client.heartbeat();
    expect(decode(attempt.sent.at(-1)!).type).toBe("HEARTBEAT");
  });

  it("starts afresh when the old connection is gone and the resume closes before its WELCOME", () => {
    const { first, seen } = connected();
    vi.advanceTimersByTime(STALL_MS + 200);
    const attempt = FakeSocket.all[1]!;
    attempt.open();
    first.close();
    attempt.close(); // the key may be spent (the server took the resume): a fresh session
    expect(seen.at(-1)).toBe("false the connection closed while resuming; reconnecting…");
    vi.advanceTimersByTime(1);
    const fresh = FakeSocket.all.at(-1)!;
    fresh.open();
    expect(fresh.hellos()[0]!.token).toBe("secret");
  });

  it("connects afresh when the server says the session has ended", () => {
    const { first, seen } = connected();
    vi.advanceTimersByTime(STALL_MS + 200);
    const attempt = FakeSocket.all[1]!;
    attempt.open();
    attempt.deliver(encode(M.ERROR, { seq: 0, code: M.ERROR_CODES.not_allowed }, "no session to resume with this key"));
    expect(first.closed).toBe(true);
    expect(seen.at(-1)).toBe("false no session to resume with this key; reconnecting…");
    vi.advanceTimersByTime(1);
    expect(FakeSocket.all.at(-1)!.hellos).toBeDefined();
    FakeSocket.all.at(-1)!.open();
    expect(FakeSocket.all.at(-1)!.hellos()[0]!.token).toBe("secret"); // a fresh session
  });
});

// After the link drops and the page connects afresh (a server restart), it syncs its
// clock with the server it reaches now: the offset measured against the server before
// is not carried over.
describe("a fresh connection after a server restart", () => {
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
    // (the resume itself is the tests above; here only that the offset stays.)
    const client = new RealtimeClient("ws://x/ws", "secret", {});
    client.connect();
    const first = FakeSocket.all[0]!;
    first.open();
    first.onmessage?.({ data: welcome(`abc ${KEY}`) });
    vi.advanceTimersByTime(1);
    first.pong(7);
    vi.advanceTimersByTime(1000); // silent: stalled, resume attempts go out
    const attempt = FakeSocket.all[1]!;
    attempt.open();
    attempt.onmessage?.({ data: welcome(`abc ${KEY}`) });
    expect(client.resumes).toBe(1);
    expect(client.offset).toBeCloseTo(7, 6);
  });
});

// The dead-man's heartbeat is put off by any message the server counts as one, never by
// the clock sync's PING (the server does not count it).
describe("what counts as a heartbeat", () => {
  it("a PING does not put off the next heartbeat; a command does", () => {
    const { client } = connected();
    client.heartbeat();
    const beat = client.lastSent;
    vi.advanceTimersByTime(30);
    client.ping();
    expect(client.lastSent).toBe(beat);
    client.lease(1);
    expect(client.lastSent).toBeGreaterThan(beat);
  });
});
