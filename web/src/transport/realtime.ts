// The binary WebSocket channel (docs/protocol.md): hello, lease, commands,
// heartbeat, e-stop, clock sync; state, forces, events, errors and acks in.
import { decode, encode, type ForceSample } from "./codec";
import * as M from "./messages";
import type { RobotStatusName, StateMessage } from "./messages";
import { Rolling } from "../stats";

/** Shown for a status index the generated list does not have. */
export const UNKNOWN_STATUS = "?";

export interface RobotState {
  status: RobotStatusName | typeof UNKNOWN_STATUS;
  joints: number[];
  position: [number, number, number];
  flags: number;
  serverTime: number;
}

export interface RealtimeHandlers {
  state?: (s: RobotState) => void;
  forces?: (samples: ForceSample[]) => void;
  event?: (text: string) => void;
  error?: (text: string, seq: number) => void;
  connection?: (up: boolean, why: string) => void;
  /** A command's latency (ms): sent here → taken by the server's driver. */
  ack?: (latencyMs: number) => void;
}

export class RealtimeClient {
  private ws: WebSocket | null = null;
  private seq = 0;
  private pendingPing = new Map<number, number>();
  private sentAt = new Map<number, number>();
  offset = 0; // server clock − client clock (s), from ping sync
  bestRtt = Infinity;
  operator = false;
  clientId = "";
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
    ws.onopen = () => {
      ws.send(encode(M.HELLO, { version: M.PROTOCOL_VERSION, flags: 0, token: new TextEncoder().encode(this.token) }));
      for (let i = 0; i < 5; i++) setTimeout(() => this.ping(), 100 * i);
      this.handlers.connection?.(true, "connected");
    };
    ws.onclose = (ev) => {
      this.handlers.connection?.(false, ev.reason || "connection closed; reconnecting…");
      setTimeout(() => this.connect(), 1000);
    };
    ws.onmessage = (ev) => this.receive(ev.data as ArrayBuffer);
  }

  get open(): boolean {
    return this.ws?.readyState === WebSocket.OPEN;
  }

  private now(): number {
    return performance.now() / 1000;
  }

  /** When the last message went out (ms, performance.now()). */
  lastSent = 0;

  private send(data: ArrayBuffer): void {
    if (this.ws?.readyState === WebSocket.OPEN) {
      this.ws.send(data);
      this.lastSent = performance.now();
    }
  }

  private nextSeq(): number {
    this.seq = (this.seq + 1) >>> 0;
    return this.seq;
  }

  ping(): void {
    const seq = this.nextSeq();
    this.pendingPing.set(seq, this.now());
    this.send(encode(M.PING, { seq, t0: this.now() }));
  }

  lease(action: number): void {
    this.send(encode(M.LEASE, { seq: this.nextSeq(), action }));
  }

  estop(): void {
    this.send(encode(M.ESTOP, { seq: this.nextSeq(), client_time: this.now() }));
  }

  reset(): void {
    this.send(encode(M.RESET, { seq: this.nextSeq() }));
  }

  heartbeat(): void {
    this.send(encode(M.HEARTBEAT, { seq: this.nextSeq(), client_time: this.now() }));
  }

  cartesian(dX: number[], rotvec: number[], frame: number): number {
    const seq = this.nextSeq();
    const t = this.now();
    this.sentAt.set(seq, t);
    this.send(
      encode(M.CART_INC, {
        seq, client_time: t, frame,
        dx: dX[0] ?? 0, dy: dX[1] ?? 0, dz: dX[2] ?? 0,
        rx: rotvec[0] ?? 0, ry: rotvec[1] ?? 0, rz: rotvec[2] ?? 0,
      }),
    );
    return seq;
  }

  private receive(data: ArrayBuffer): void {
    const msg = decode(data);
    switch (msg.type) {
      case "FORCE":
        this.forceInterval.tick(performance.now()); // per message: browsers get ~10 ms batches
        this.handlers.forces?.(msg.samples);
        break;
      case "WELCOME":
        this.operator = msg.role === 1;
        this.clientId = msg.text;
        break;
      case "STATE":
        this.stateInterval.tick(performance.now());
        this.handlers.state?.(robotState(msg));
        break;
      case "PONG": {
        const t3 = this.now();
        const t0 = this.pendingPing.get(msg.seq);
        if (t0 !== undefined) {
          this.pendingPing.delete(msg.seq);
          const rtt = t3 - t0 - (msg.t2 - msg.t1);
          if (rtt < this.bestRtt) {
            this.bestRtt = rtt;
            this.offset = (msg.t1 - t0 + (msg.t2 - t3)) / 2;
          }
        }
        break;
      }
      case "ACK": {
        const sent = this.sentAt.get(msg.seq);
        if (sent !== undefined) {
          this.sentAt.delete(msg.seq);
          const latency = (msg.server_time - this.offset - sent) * 1000;
          this.commandLatency.add(latency);
          this.handlers.ack?.(latency);
        }
        break;
      }
      case "EVENT":
        this.handlers.event?.(msg.text);
        break;
      case "ERROR":
        this.handlers.error?.(msg.text, msg.seq);
        break;
    }
  }
}

/** The page's view of a STATE message. */
export function robotState(msg: StateMessage): RobotState {
  return {
    status: M.ROBOT_STATUS[msg.status] ?? UNKNOWN_STATUS,
    joints: [msg.q1, msg.q2, msg.q3, msg.q4, msg.q5, msg.q6],
    position: [msg.x, msg.y, msg.z],
    flags: msg.flags,
    serverTime: msg.server_time,
  };
}
