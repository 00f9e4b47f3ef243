// The binary WebSocket channel (docs/protocol.md): hello, lease, commands,
// heartbeat, e-stop, clock sync; state, forces, events, errors and acks in.
import { decode, decodeForce, encode, type ForceSample } from "./codec";
import * as M from "./messages";
import { Rolling } from "../stats";

export interface RobotState {
  status: string;
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
    const type = new DataView(data).getUint8(0);
    if (type === M.FORCE.typeId) {
      const samples = decodeForce(data);
      this.forceInterval.tick(performance.now()); // per message: browsers get ~10 ms batches
      this.handlers.forces?.(samples);
      return;
    }
    const msg = decode(data);
    const f = msg.fields;
    switch (msg.spec.name) {
      case "WELCOME":
        this.operator = f.role === 1;
        this.clientId = msg.text;
        break;
      case "STATE":
        this.stateInterval.tick(performance.now());
        this.handlers.state?.({
          status: M.ROBOT_STATUS[f.status ?? 0] ?? "?",
          joints: [f.q1!, f.q2!, f.q3!, f.q4!, f.q5!, f.q6!],
          position: [f.x!, f.y!, f.z!],
          flags: f.flags ?? 0,
          serverTime: f.server_time ?? 0,
        });
        break;
      case "PONG": {
        const t3 = this.now();
        const t0 = this.pendingPing.get(f.seq ?? 0);
        if (t0 !== undefined) {
          this.pendingPing.delete(f.seq ?? 0);
          const rtt = t3 - t0 - ((f.t2 ?? 0) - (f.t1 ?? 0));
          if (rtt < this.bestRtt) {
            this.bestRtt = rtt;
            this.offset = ((f.t1 ?? 0) - t0 + ((f.t2 ?? 0) - t3)) / 2;
          }
        }
        break;
      }
      case "ACK": {
        const sent = this.sentAt.get(f.seq ?? 0);
        if (sent !== undefined) {
          this.sentAt.delete(f.seq ?? 0);
          const latency = ((f.server_time ?? 0) - this.offset - sent) * 1000;
          this.commandLatency.add(latency);
          this.handlers.ack?.(latency);
        }
        break;
      }
      case "EVENT":
        this.handlers.event?.(msg.text);
        break;
      case "ERROR":
        this.handlers.error?.(msg.text, f.seq ?? 0);
        break;
    }
  }
}
