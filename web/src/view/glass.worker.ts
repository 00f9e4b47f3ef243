// The glass-to-glass meter's frames, read off the page's main thread (view/glass.ts).
import { type FromGlassWorker, type MarkSink, type ServerClock, type ToGlassWorker, readFrames, stopReading, trackProcessor } from "./glass";
import type { DecodedFrame } from "./motion-mark";

const port = self as unknown as {
  onmessage: ((e: MessageEvent<ToGlassWorker>) => void) | null;
  postMessage(message: FromGlassWorker): void;
};
const clock: ServerClock = { bestRtt: Infinity, offset: 0 };
let stop: (() => void) | null = null;
let pending: number[] = [];
let frames: DecodedFrame[] = []; // read with their motion mark, while the page asks
let fullWidth: number | null = null;
let mark = false;
const marks: MarkSink = {
  on: () => mark,
  add: (f) => {
    if (frames.length < 1000) frames.push(f); // 250 ms of frames: bounded all the same
  },
};

port.onmessage = (e) => {
  const m = e.data;
  if (m.op === "clock") {
    clock.offset = m.offset;
    clock.bestRtt = m.bestRtt;
    fullWidth = m.fullWidth;
    mark = m.mark;
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
      if (pending.length || frames.length) port.postMessage({ op: "ms", ms: pending, frames });
      pending = [];
      frames = [];
    }, 250);
    void readFrames(reader, now, clock, (ms) => pending.push(ms), () => fullWidth, marks).then(() => {
      clearInterval(flush);
      port.postMessage({ op: "ms", ms: pending, frames });
      port.postMessage({ op: "stopped" });
    });
  } else if (m.op === "stop") {
    stop?.();
  }
};
