// The page's side of the realtime channel: the same calls as RealtimeClient, carried
// out by the realtime worker (realtime.worker.ts), with the figures the panels show
// mirrored here on the page's clock.
import type { ForceSample } from "./codec";
import { type BeatSkip, PAGE_CHECK_IN_MS } from "./heartbeat";
import type { ArmAnnouncement, RealtimeHandlers, RobotState } from "./realtime";
import { Rolling } from "../stats";

export type ToWorker =
  | { op: "connect"; url: string; token: string; timeOrigin: number }
  | { op: "alive" }
  | { op: "want-control"; on: boolean }
  | { op: "deadman"; held: boolean }
  | { op: "visible"; on: boolean }
  | { op: "lease"; action: number }
  | { op: "estop" }
  | { op: "reset" }
  | { op: "cartesian"; dX: number[]; rotvec: number[]; frame: number; arm: number };

export interface LinkMeta {
  operator: boolean;
  clientId: string;
  open: boolean;
  bestRtt: number;
  offset: number;
  /** How late the worker's heartbeat timer fired lately (ms; heartbeat.ts TimerLateness). */
  timerLateMs: number;
  /** The page's main thread's longest silence to the worker lately (ms): past
   * PAGE_SILENCE_MS the worker stopped beating (heartbeat.ts). */
  pageStallMs: number;
  /** The worst gap between the worker's messages that count as heartbeats, lately (ms;
   * heartbeat.ts BeatRecord), and its timer's firings that sent nothing, by reason. */
  beatGapMs: number;
  beatSkips: Record<BeatSkip, number>;
  /** Sessions resumed on a new connection after a stall. */
  resumes: number;
}

export type FromWorker =
  | { kind: "state"; state: RobotState; at: number; meta: LinkMeta }
  | { kind: "forces"; samples: ForceSample[]; arm: number; at: number }
  | { kind: "arms"; arms: ArmAnnouncement[] }
  | { kind: "event"; text: string; eventKind: number }
  | { kind: "error"; text: string; seq: number; code: number }
  | { kind: "connection"; up: boolean; why: string; meta: LinkMeta }
  | { kind: "ack"; latencyMs: number; sentAt?: number; appliedAt?: number; meta: LinkMeta }
  | { kind: "welcome"; meta: LinkMeta };

export class RealtimeLink implements LinkMeta {
  operator = false;
  clientId = "";
  open = false;
  bestRtt = Infinity;
  offset = 0; // server − page clock (s)
  timerLateMs = 0;
  pageStallMs = 0;
  beatGapMs = 0;
  beatSkips: Record<BeatSkip, number> = { unwanted: 0, pageSilent: 0, recent: 0 };
  resumes = 0;
  /** The arms the server drives, from its ARM messages (this session's). */
  arms: ArmAnnouncement[] = [];
  readonly stateInterval = new Rolling();
  readonly forceInterval = new Rolling(2000);
  readonly commandLatency = new Rolling();
  /** Each ACKed command's send and the server's applying of it, on this page's clock
   * (ms): the hand-to-eye measurement's (view/handeye.ts). */
  onAck: ((sentAt: number, appliedAt: number) => void) | null = null;
  private readonly worker: Worker;

  constructor(
    private readonly url: string,
    private readonly token: string,
    private readonly handlers: RealtimeHandlers,
  ) {
    this.worker = new Worker(new URL("./realtime.worker.ts", import.meta.url), { type: "module" });
    this.worker.onmessage = (e: MessageEvent<FromWorker>) => this.receive(e.data);
    this.worker.onerror = (e) => handlers.error?.(`the realtime worker failed: ${e.message}`, 0, 0);
  }

  connect(): void {
    this.post({ op: "connect", url: this.url, token: this.token, timeOrigin: performance.timeOrigin });
    setInterval(() => this.post({ op: "alive" }), PAGE_CHECK_IN_MS);
    // A hidden page (another tab in front, a minimised window) lets its lease lapse.
    const visible = () => this.post({ op: "visible", on: document.visibilityState === "visible" });
    document.addEventListener("visibilitychange", visible);
    visible();
  }

  /** Ask for heartbeats while we want control (the worker also beats while we hold it). */
  wantControl(on: boolean): void {
    this.post({ op: "want-control", on });
  }

  /** The dead-man is held (or let go): while it is, a page that stands still keeps its
   * lease once the server has stopped the arm (heartbeat.ts). */
  deadman(held: boolean): void {
    this.post({ op: "deadman", held });
  }

  lease(action: number): void {
    this.post({ op: "lease", action });
  }

  estop(): void {
    this.post({ op: "estop" });
  }

  reset(): void {
    this.post({ op: "reset" });
  }

  /** `arm`: ARM's index (0: the only arm of a one-arm server). */
  cartesian(dX: number[], rotvec: number[], frame: number, arm = 0): void {
    this.post({ op: "cartesian", dX, rotvec, frame, arm });
  }

  private post(m: ToWorker): void {
    this.worker.postMessage(m);
  }

  private receive(m: FromWorker): void {
    if ("meta" in m) Object.assign(this, m.meta);
    switch (m.kind) {
      case "state":
        this.stateInterval.tick(m.at);
        this.handlers.state?.(m.state);
        break;
      case "forces":
        this.forceInterval.tick(m.at); // per message, timed where it arrived
        this.handlers.forces?.(m.samples, m.arm);
        break;
      case "arms":
        this.arms = m.arms;
        this.handlers.arms?.(m.arms);
        break;
      case "event":
        this.handlers.event?.(m.text, m.eventKind);
        break;
      case "error":
        this.handlers.error?.(m.text, m.seq, m.code);
        break;
      case "connection":
        this.handlers.connection?.(m.up, m.why);
        break;
      case "ack":
        this.commandLatency.add(m.latencyMs);
        if (m.sentAt !== undefined && m.appliedAt !== undefined) this.onAck?.(m.sentAt, m.appliedAt);
        break;
      case "welcome":
        this.handlers.welcome?.(m.meta.operator, m.meta.clientId);
        break;
    }
  }
}
