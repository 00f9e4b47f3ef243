// The glass-to-glass meter's frames, read off the page's main thread (view/glass.ts).
import { type FromGlassWorker, type ServerClock, type ToGlassWorker, readFrames, stopReading, trackProcessor } from "./glass";

const port = self as unknown as {
  onmessage: ((e: MessageEvent<ToGlassWorker>) => void) | null;
  postMessage(message: FromGlassWorker): void;
};
const clock: ServerClock = { bestRtt: Infinity, offset: 0 };
let stop: (() => void) | null = null;
let pending: number[] = [];
let fullWidth: number | null = null;

port.onmessage = (e) => {
  const m = e.data;
  if (m.op === "clock") {
    clock.offset = m.offset;
    clock.bestRtt = m.bestRtt;
    fullWidth = m.fullWidth;
  } else if (m.op === "track") {
    const Processor = trackProcessor(self);
    if (!Processor) {
      m.track.stop();
      port.postMessage({ op: "unsupported" });
      return;
    }
    const reader = new Processor({ track: m.track }).readable.getReader();
    // The page's clock: this worker's own started elsewhere.
    const now = () => (performance.now() + performance.timeOrigin - m.pageOrigin) / 1000;
    stop = () => stopReading(m.track, reader);
    const flush = setInterval(() => {
      if (pending.length) port.postMessage({ op: "ms", ms: pending });
      pending = [];
    }, 250);
    void readFrames(reader, now, clock, (ms) => pending.push(ms), () => fullWidth).then(() => {
      clearInterval(flush);
      port.postMessage({ op: "ms", ms: pending });
      port.postMessage({ op: "stopped" });
    });
  } else if (m.op === "stop") {
    stop?.();
  }
};
