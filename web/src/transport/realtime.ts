// The binary WebSocket channel (docs/protocol.md): hello, lease, commands,
// heartbeat, e-stop, clock sync; state, forces, events, errors and acks in.
import { decode, encode, type ForceSample } from "./codec";
import * as M from "./messages";
import type { RobotStatusName, StateMessage } from "./messages";
import { Rolling } from "../stats";
import { ClockSync, PING_EVERY_MS } from "./clocksync";

/** Shown for a status index the generated list does not have. */
export const UNKNOWN_STATUS = "?";

export interface RobotState {
  status: RobotStatusName | typeof UNKNOWN_STATUS;
  joints: number[];
  position: [number, number, number];
  /** The tool's orientation: a 3×3 rotation matrix, rows (base frame). */
  rotation: [number, number, number][];
  flags: number;
  serverTime: number;
  /** Whose state (ARM's index, 1…N; the pose is in that arm's own base frame). */
  arm: number;
}

/** One arm the server drives, as its ARM message (after WELCOME) says. */
export interface ArmAnnouncement {
  index: number;
  joints: number;
  name: string;
}

/** No message for this long (ms) on an open connection: the link has stalled (the
 * server sends STATE at 50 Hz). The session is then resumed on a new connection, which
 * gets through as soon as the link is back, where the old one may wait out TCP's
 * doubling retransmission timeout (0.2, 0.6, 1.4, 3 s): the lease, kept by the server
 * for its grace, survives a short cut. */
export const STALL_MS = 400;
/** While stalled, a new resume attempt this often (ms), at most RESUME_ATTEMPTS at once. */
export const RESUME_EVERY_MS = 250;
export const RESUME_ATTEMPTS = 4;
/** Stalled this long (ms): the server's grace is long past; connect afresh. */
export const RESUME_GIVE_UP_MS = 10_000;

export interface RealtimeHandlers {
  state?: (s: RobotState) => void;
  /** `arm`: whose sensor (ARM's index). */
  forces?: (samples: ForceSample[], arm: number) => void;
  /** The server's arms, once every ARM after a WELCOME has come (each new session). */
  arms?: (arms: ArmAnnouncement[]) => void;
  /** An EVENT: its text and kind (EventKind). */
  event?: (text: string, kind: number) => void;
  error?: (text: string, seq: number, code: number) => void;
  connection?: (up: boolean, why: string) => void;
  /** A command's latency (ms): sent here → taken by the server's driver; and both times
   * on this client's clock (performance.now(), ms): the ACK's server time through the
   * clock sync (view/handeye.ts joins them to key presses). */
  ack?: (latencyMs: number, times: { sentAt: number; appliedAt: number }) => void;
  /** The server answered HELLO: the role it gave (operator: the token was accepted). */
  welcome?: (operator: boolean, clientId: string) => void;
}

export class RealtimeClient {
  private ws: WebSocket | null = null;
  private seq = 0;
  private pendingPing = new Map<number, number>();
  private sentAt = new Map<number, number>();
  // The server's clock, from PING/PONG: commands carry their send time on it (HELLO's
  // SYNCED_CLOCK), and the server drops one older than its max command age. Measured
  // afresh on each new session (connect): the server reached now may be another process
  // on another clock (a restart); a resumed session keeps it (the same server).
  private clock = new ClockSync();
  private pinger: ReturnType<typeof setInterval> | undefined;
  private watchdog: ReturnType<typeof setInterval> | undefined;
  private resumeKey = "";
  private lastHeard = 0; // ms, performance.now()
  private stalledSince: number | null = null;
  private lastAttempt = -Infinity;
  private attempts: WebSocket[] = [];
  private resuming: WebSocket | null = null; // the attempt whose HELLO asked to resume
  /** Sessions resumed on a new connection after a stall. */
  resumes = 0;
  operator = false;
  clientId = "";
  /** The arms the server drives (its ARM messages), and how many its WELCOME said. */
  arms: ArmAnnouncement[] = [];
  private armCount = 0;
  readonly stateInterval = new Rolling();
  readonly forceInterval = new Rolling(2000);
  readonly commandLatency = new Rolling();

  constructor(
    private readonly url: string,
    private readonly token: string,
    private readonly handlers: RealtimeHandlers,
  ) {}

  connect(): void {
    const ws = new WebSocket(this.url);
    ws.binaryType = "arraybuffer";
    this.ws = ws;
    this.resumeKey = "";
    this.clock = new ClockSync();
    this.stopResuming();
    ws.onopen = () => {
      const flags = M.HelloFlags.SYNCED_CLOCK | M.HelloFlags.RESUMABLE;
      ws.send(encode(M.HELLO, { version: M.PROTOCOL_VERSION, flags, token: new TextEncoder().encode(this.token) }));
      this.lastHeard = performance.now();
      for (let i = 0; i < 5; i++) setTimeout(() => this.ping(), 100 * i);
      clearInterval(this.pinger);
      this.pinger = setInterval(() => this.ping(), PING_EVERY_MS);
      clearInterval(this.watchdog);
      this.watchdog = setInterval(() => this.watch(performance.now()), 100);
      this.handlers.connection?.(true, "connected");
    };
    this.listen(ws);
  }

  /** `ws` is (now) this client's connection: its messages and its closing are ours. */
  private listen(ws: WebSocket): void {
    ws.onclose = (ev) => {
      if (ws !== this.ws) return; // a connection left behind by a resume
      // The server closes the old connection as it takes our resume, maybe before its
      // WELCOME reaches us: that WELCOME adopts the new one (or the attempt's failure
      // starts afresh).
      if (this.resuming) return;
      this.handlers.connection?.(false, ev.reason || "connection closed; reconnecting…");
      setTimeout(() => this.connect(), 1000);
    };
    ws.onmessage = (ev) => {
      this.lastHeard = performance.now();
      // The old connection's news got through first. That says nothing of what we send
      // on it: each end of a TCP connection waits out its own doubling retransmission
      // timer (0.2, 0.6, 1.4, 3 s), so ours may still be seconds from the server, past
      // the lease's grace. The attempts under way go on and the first to open resumes;
      // no new ones are made while the server is heard (watch), and the give-up clock
      // restarts at the next stall.
      this.stalledSince = null;
      this.receive(ev.data as ArrayBuffer);
    };
  }

  /** Every 100 ms: has the connection stalled? Then resume the session elsewhere. */
  private watch(now: number): void {
    if (!this.resumeKey || now - this.lastHeard < STALL_MS) return;
    if (!this.open && !this.resuming) return; // closed: its onclose reconnects
    this.stalledSince ??= now;
    if (now - this.stalledSince > RESUME_GIVE_UP_MS) return this.startAfresh("the link stalled too long");
    if (!this.resuming && now - this.lastAttempt >= RESUME_EVERY_MS) this.attemptResume(now);
  }

  private attemptResume(now: number): void {
    this.lastAttempt = now;
    const a = new WebSocket(this.url);
    a.binaryType = "arraybuffer";
    this.attempts.push(a);
    if (this.attempts.length > RESUME_ATTEMPTS) this.attempts.shift()?.close();
    const key = this.resumeKey;
    // Connections open in parallel (a SYN lost in the cut is resent only after 1 s), but
    // the session resumes on the first to open, alone: a second resume would take it
    // over again from the one adopted.
    a.onopen = () => {
      if (this.resuming) return a.close();
      this.resuming = a;
      for (const other of this.attempts) if (other !== a) other.close();
      this.attempts = [a];
      const flags = M.HelloFlags.SYNCED_CLOCK | M.HelloFlags.RESUMABLE | M.HelloFlags.RESUME;
      a.send(encode(M.HELLO, { version: M.PROTOCOL_VERSION, flags, token: new TextEncoder().encode(key) }));
    };
    a.onmessage = (ev) => {
      const msg = decode(ev.data as ArrayBuffer);
      if (msg.type === "WELCOME") {
        this.expectArms(msg.arms);
        this.adopt(a, performance.now(), msg.text);
      }
      else if (msg.type === "ERROR") this.startAfresh(msg.text); // the session has ended
    };
    a.onclose = () => {
      this.attempts = this.attempts.filter((x) => x !== a);
      if (this.resuming !== a) return;
      this.resuming = null; // closed before its WELCOME: try again…
      // …unless the old connection is gone too (the server may have taken the resume
      // and closed it, and the key with it): then only a fresh session is left.
      if (!this.open) this.startAfresh("the connection closed while resuming");
    };
  }

  /** A resume attempt was welcomed: it is the connection from now on, with the next
   * resume key from its WELCOME ("<client id> <key>"): a key resumes once. */
  private adopt(a: WebSocket, now: number, welcome: string): void {
    const old = this.ws;
    this.resumeKey = welcome.split(" ")[1] ?? "";
    const stalledMs = this.stalledSince === null ? 0 : now - this.stalledSince + STALL_MS;
    this.attempts = this.attempts.filter((x) => x !== a);
    this.stopResuming();
    this.ws = a;
    this.listen(a);
    this.lastHeard = now;
    this.resumes += 1;
    if (old) {
      old.onclose = old.onmessage = null;
      old.close(1000, "resumed on a new connection");
    }
    this.handlers.connection?.(true, `resumed on a new connection after ${Math.round(stalledMs)} ms without news`);
  }

  private stopResuming(): void {
    this.resuming = null;
    this.stalledSince = null;
    this.lastAttempt = -Infinity;
    for (const a of this.attempts) {
      a.onmessage = a.onclose = null;
      a.close();
    }
    this.attempts = [];
  }

  /** Give up the session: drop the connection (without waiting for its closing) and
   * connect afresh. */
  private startAfresh(why: string): void {
    const old = this.ws;
    this.stopResuming();
    if (old) {
      old.onclose = old.onmessage = null;
      old.close();
    }
    this.ws = null;
    this.handlers.connection?.(false, `${why}; reconnecting…`);
    setTimeout(() => this.connect(), 0);
  }

  get open(): boolean {
    return this.ws?.readyState === WebSocket.OPEN;
  }

  private now(): number {
    return performance.now() / 1000;
  }

  /** Server clock − page clock (s), from the recent ping with the least round trip. */
  get offset(): number {
    return this.clock.offset;
  }

  get bestRtt(): number {
    return this.clock.bestRtt;
  }

  /** The server's clock is known (a PING came back this session): `offset` holds. */
  get synced(): boolean {
    return this.clock.synced;
  }

  /** Now on the server's clock (what commands carry as client_time). */
  private serverNow(): number {
    return this.now() + this.clock.offset;
  }

  /** When the last message the server counts as a heartbeat went out (ms,
   * performance.now()): any but PING, which is the clock sync's and says nothing of the
   * operator being there (the server does not count it). Counting a PING here put off
   * the next heartbeat, and every 2 s the server saw 100 ms of silence instead of 50:
   * half the dead-man's margin gone, and a halt at the next hiccup. */
  lastSent = 0;

  private send(data: ArrayBuffer, heartbeat = true): void {
    if (this.ws?.readyState === WebSocket.OPEN) {
      this.ws.send(data);
      if (heartbeat) this.lastSent = performance.now();
    }
  }

  private nextSeq(): number {
    this.seq = (this.seq + 1) >>> 0;
    return this.seq;
  }

  ping(): void {
    if (!this.open) return;
    // An answer lost on the way must not leave its entry behind for good.
    if (this.pendingPing.size > 64) this.pendingPing.clear();
    const seq = this.nextSeq();
    this.pendingPing.set(seq, this.now());
    this.send(encode(M.PING, { seq, t0: this.now() }), false);
  }

  lease(action: number): void {
    this.send(encode(M.LEASE, { seq: this.nextSeq(), action }));
  }

  estop(): void {
    this.send(encode(M.ESTOP, { seq: this.nextSeq(), client_time: this.serverNow() }));
  }

  reset(): void {
    this.send(encode(M.RESET, { seq: this.nextSeq() }));
  }

  heartbeat(): void {
    this.send(encode(M.HEARTBEAT, { seq: this.nextSeq(), client_time: this.serverNow() }));
  }

  /** A WELCOME said how many arms: their ARM messages follow. */
  private expectArms(count: number): void {
    this.armCount = count;
    this.arms = [];
  }

  /** `arm`: the arm's index from its ARM message; 0 for the only arm of a one-arm server. */
  cartesian(dX: number[], rotvec: number[], frame: number, arm = 0): number {
    const seq = this.nextSeq();
    // Not before the first clock sync (the first ~RTT after connecting): the server
    // could not tell how old the command is.
    if (!this.clock.synced) return seq;
    const t = this.now();
    this.sentAt.set(seq, t);
    this.send(
      encode(M.CART_INC, {
        seq, client_time: t + this.clock.offset, frame,
        dx: dX[0] ?? 0, dy: dX[1] ?? 0, dz: dX[2] ?? 0,
        rx: rotvec[0] ?? 0, ry: rotvec[1] ?? 0, rz: rotvec[2] ?? 0, arm,
      }),
    );
    return seq;
  }

  private receive(data: ArrayBuffer): void {
    const msg = decode(data);
    switch (msg.type) {
      case "FORCE":
        this.forceInterval.tick(performance.now()); // per message: browsers get ~10 ms batches
        this.handlers.forces?.(msg.samples, msg.arm);
        break;
      case "ARM": {
        // One per arm right after WELCOME, in order: told once they have all come.
        this.arms = [...this.arms.filter((a) => a.index !== msg.index), { index: msg.index, joints: msg.joints, name: msg.text }].sort((a, b) => a.index - b.index);
        if (this.arms.length === this.armCount) this.handlers.arms?.(this.arms);
        break;
      }
      case "WELCOME": {
        // "<client id> <resume key>" (HELLO's RESUMABLE flag).
        const [id = "", key = ""] = msg.text.split(" ");
        this.operator = msg.role === 1;
        this.clientId = id;
        this.resumeKey = key;
        this.expectArms(msg.arms);
        this.handlers.welcome?.(this.operator, this.clientId);
        break;
      }
      case "STATE":
        this.stateInterval.tick(performance.now());
        this.handlers.state?.(robotState(msg));
        break;
      case "PONG": {
        const t3 = this.now();
        const t0 = this.pendingPing.get(msg.seq);
        if (t0 !== undefined) {
          this.pendingPing.delete(msg.seq);
          this.clock.add(t0, msg.t1, msg.t2, t3);
        }
        break;
      }
      case "ACK": {
        const sent = this.sentAt.get(msg.seq);
        if (sent !== undefined) {
          this.sentAt.delete(msg.seq);
          const applied = msg.server_time - this.offset;
          const latency = (applied - sent) * 1000;
          this.commandLatency.add(latency);
          this.handlers.ack?.(latency, { sentAt: sent * 1000, appliedAt: applied * 1000 });
        }
        break;
      }
      case "EVENT":
        this.handlers.event?.(msg.text, msg.kind);
        break;
      case "ERROR":
        this.handlers.error?.(msg.text, msg.seq, msg.code);
        break;
    }
  }
}

/** The page's view of a STATE message. */
export function robotState(msg: StateMessage): RobotState {
  return {
    status: M.ROBOT_STATUS[msg.status] ?? UNKNOWN_STATUS,
    joints: msg.joints,
    position: [msg.x, msg.y, msg.z],
    rotation: [
      [msg.r00, msg.r01, msg.r02],
      [msg.r10, msg.r11, msg.r12],
      [msg.r20, msg.r21, msg.r22],
    ],
    flags: msg.flags,
    serverTime: msg.server_time,
    arm: msg.arm,
  };
}
