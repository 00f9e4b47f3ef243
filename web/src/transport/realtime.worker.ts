// The realtime channel in its own thread: the WebSocket, the clock sync, the arrival
// times of state and forces, and the dead-man heartbeat run here, where the page's
// rendering cannot stall them. The page talks to it through RealtimeLink (link.ts).
import { type BeatSkip, BeatRecord, HEARTBEAT_PERIOD_MS, PageSilence, TimerLateness } from "./heartbeat";
import type { FromWorker, ToWorker } from "./link";
import { StateFlags } from "./messages";
import { RealtimeClient } from "./realtime";

// An ACK also carries its command's times on the page's clock (ms): sent from here,
// taken by the server's driver (RealtimeLink.onAck: the hand-to-eye recorder's).
const port = self as unknown as {
  onmessage: ((e: MessageEvent<ToWorker>) => void) | null;
  postMessage(message: FromWorker): void;
};
let client: RealtimeClient | null = null;
let mainOrigin = 0; // the page's performance.timeOrigin: times go back on its clock
let wantControl = false;
let hasControl = false;
let visible = true;
// The main thread's last check-in, its dead-man, and whether the server stopped the arm since.
const page = new PageSilence(performance.now());
const lateness = new TimerLateness();
const beats = new BeatRecord();
const pageGaps = new TimerLateness(); // between the main thread's messages

const pageNow = () => performance.now() + performance.timeOrigin - mainOrigin;

function meta(c: RealtimeClient) {
  return {
    operator: c.operator,
    clientId: c.clientId,
    open: c.open,
    bestRtt: c.bestRtt,
    // server − page clock (s): the worker's offset moved onto the page's clock
    offset: c.offset + (mainOrigin - performance.timeOrigin) / 1000,
    timerLateMs: lateness.recent(performance.now(), HEARTBEAT_PERIOD_MS),
    pageStallMs: pageGaps.recent(performance.now(), 0),
    beatGapMs: beats.worstGap(performance.now()),
    beatSkips: { ...beats.skips },
    resumes: c.resumes,
  };
}

/** The heartbeat timer fired: a heartbeat if one is due (what it did is recorded). */
function tick(): void {
  lateness.fired(performance.now(), HEARTBEAT_PERIOD_MS);
  if (!client) return;
  beats.fired(beat(client), client.lastSent);
}

/** A heartbeat if one is due; why not otherwise. */
function beat(c: RealtimeClient): BeatSkip | null {
  const skip = page.skip(performance.now(), visible && (wantControl || hasControl), hasControl, c.lastSent);
  if (skip === null) c.heartbeat();
  return skip;
}

port.onmessage = (e) => {
  const m = e.data;
  page.checkIn(performance.now());
  pageGaps.fired(page.seen, 0);
  if (m.op === "connect") {
    if (client) return;
    mainOrigin = m.timeOrigin;
    const c = (client = new RealtimeClient(m.url, m.token, {
      state: (state) => {
        hasControl = (state.flags & StateFlags.YOU_HAVE_CONTROL) !== 0;
        // The server's news that it stopped the arm of a page silent past PAGE_SILENCE_MS:
        // the heartbeats keep the lease from now (heartbeat.ts), the first one at once.
        const at = c.synced ? (state.serverTime - c.offset) * 1000 : null; // this worker's clock
        if (page.state(state.flags, at)) beat(c);
        port.postMessage({ kind: "state", state, at: pageNow(), meta: meta(c) });
      },
      forces: (samples, arm) => port.postMessage({ kind: "forces", samples, arm, at: pageNow() }),
      arms: (arms) => port.postMessage({ kind: "arms", arms }),
      event: (text, eventKind) => port.postMessage({ kind: "event", text, eventKind }),
      error: (text, seq, code) => port.postMessage({ kind: "error", text, seq, code }),
      connection: (up, why) => port.postMessage({ kind: "connection", up, why, meta: meta(c) }),
      ack: (latencyMs, t) => {
        const toPage = performance.timeOrigin - mainOrigin; // this worker's clock → the page's
        port.postMessage({ kind: "ack", latencyMs, meta: meta(c), sentAt: t.sentAt + toPage, appliedAt: t.appliedAt + toPage });
      },
      welcome: () => port.postMessage({ kind: "welcome", meta: meta(c) }),
    }));
    c.connect();
    setInterval(tick, HEARTBEAT_PERIOD_MS);
    return;
  }
  if (!client) return;
  switch (m.op) {
    case "alive":
      break;
    case "want-control":
      wantControl = m.on;
      if (m.on) client.heartbeat();
      break;
    case "deadman":
      page.deadman = m.held;
      break;
    case "visible":
      visible = m.on;
      break;
    case "lease":
      client.lease(m.action);
      break;
    case "estop":
      client.estop();
      break;
    case "reset":
      client.reset();
      break;
    case "cartesian":
      client.cartesian(m.dX, m.rotvec, m.frame, m.arm);
      break;
  }
};
