// Glass-to-glass latency, measured in the page for every frame.
import type { Rolling } from "../stats";
import { type DecodedFrame, decodedFrames, markStrip, readMark } from "./motion-mark";

/** The clock sync the measurement needs: server − page clock (s), valid once bestRtt is finite. */
export interface ServerClock {
  bestRtt: number;
  offset: number;
}

/** Page → glass worker. */
export type ToGlassWorker =
  | { op: "track"; track: MediaStreamTrack; pageOrigin: number }
  | { op: "clock"; offset: number; bestRtt: number; fullWidth: number | null; mark: boolean }
  | { op: "stop" };
/** Glass worker → page: latencies (ms) since the last message (and the frames read with
 * their motion mark, while asked: `mark`); whether it can read; that it has stopped
 * (every frame it was given closed). */
export type FromGlassWorker = { op: "ms"; ms: number[]; frames: DecodedFrame[] } | { op: "unsupported" } | { op: "stopped" };

/** What the reader does with each frame's motion mark: whether to read it now, and where
 * each frame read with it goes. */
export interface MarkSink {
  on(): boolean;
  add(frame: DecodedFrame): void;
}

type Processor = new (i: { track: MediaStreamTrack }) => { readable: ReadableStream<VideoFrame> };

export function trackProcessor(scope: unknown): Processor | undefined {
  return (scope as { MediaStreamTrackProcessor?: Processor }).MediaStreamTrackProcessor;
}

/** Capture → decoded frame in this page, for every frame: each decoded frame carries its
 * capture time as a timecode (32 blocks of 16 px at (8, 8) in the left image), read from
 * the decoder's own frame (a 512×2 luma copy; no GPU read-back), on the server's clock
 * through the ping offset. Reads `track` (a copy: it is stopped) until `stop()`.
 *
 * In a worker of its own where the browser lets a track move there (Chromium): a frame
 * read on the main thread waited behind rendering, and on a busy machine frames were
 * held there long enough to be reported as leaked. Else on the main thread. */
export function measureGlass(
  track: MediaStreamTrack,
  clock: ServerClock,
  glass: Rolling,
  fullWidth: () => number | null = () => null,
): { stop(): void } {
  if (typeof Worker !== "undefined") {
    const worker = new Worker(new URL("./glass.worker.ts", import.meta.url), { type: "module" });
    try {
      const msg: ToGlassWorker = { op: "track", track, pageOrigin: performance.timeOrigin };
      worker.postMessage(msg, [track as unknown as Transferable]);
    } catch {
      worker.terminate(); // tracks cannot move to workers here: read on this thread
      return measureHere(track, clock, glass, fullWidth);
    }
    return measureInWorker(worker, clock, glass, fullWidth);
  }
  return measureHere(track, clock, glass, fullWidth);
}

function measureInWorker(worker: Worker, clock: ServerClock, glass: Rolling, fullWidth: () => number | null): { stop(): void } {
  const tell = (msg: ToGlassWorker) => worker.postMessage(msg);
  const sendClock = () =>
    tell({ op: "clock", offset: clock.offset, bestRtt: clock.bestRtt, fullWidth: fullWidth(), mark: decodedFrames.on });
  sendClock();
  const timer = setInterval(sendClock, 500);
  worker.onmessage = (e: MessageEvent<FromGlassWorker>) => {
    if (e.data.op === "ms") {
      for (const v of e.data.ms) glass.add(v);
      for (const f of e.data.frames) decodedFrames.log.push(f);
    }
    if (e.data.op === "stopped" || e.data.op === "unsupported") {
      clearInterval(timer);
      worker.terminate();
    }
  };
  return {
    stop() {
      clearInterval(timer);
      tell({ op: "stop" }); // it stops the track, closes what is queued, then says so
      // (and is terminated then); terminated here only if it never does, after its
      // reader's own deadline: ending a worker drops the frames it still holds.
      setTimeout(() => worker.terminate(), STUCK_MS + 2000);
    },
  };
}

function measureHere(track: MediaStreamTrack, clock: ServerClock, glass: Rolling, fullWidth: () => number | null): { stop(): void } {
  const Processor = trackProcessor(globalThis);
  if (!Processor) return { stop: () => track.stop() }; // not Chromium: the panel shows no glass-to-glass figure
  const reader = new Processor({ track }).readable.getReader();
  const marks: MarkSink = { on: () => decodedFrames.on, add: (f) => decodedFrames.log.push(f) };
  void readFrames(reader, () => performance.now() / 1000, clock, (ms) => glass.add(ms), fullWidth, marks);
  return { stop: () => stopReading(track, reader) };
}

/** Stopping the track ends the stream after the frames already queued, which the reader
 * still takes and closes. Cancelling the stream instead would drop them unclosed, to the
 * garbage collector, which Chromium reports on the console as an error ("A VideoFrame
 * was garbage collected without being closed": seen when a peer was re-negotiated). Only
 * a reader still not done after STUCK_MS is cancelled: on a busy machine a reader a second
 * behind is slow, not stuck, and cancelling it at 1 s still dropped its queue (seen in a
 * WebXR test with other work on both cores). */
export function stopReading(track: MediaStreamTrack, reader: ReadableStreamDefaultReader<VideoFrame>): void {
  track.stop();
  setTimeout(() => void reader.cancel().catch(() => undefined), STUCK_MS);
}

/** How long a stopped meter may take to read and close the frames it still holds. */
export const STUCK_MS = 10_000;

/** Where the timecode's blocks are read in a picture `scale` times the size it was drawn
 * at (drivers/camera/timecode.py: 32 blocks of 16 px at (8, 8); the server's low video
 * layer is half size): a strip through the blocks' middle row, its corner and size
 * even (a 4:2:0 frame copies whole chroma samples), and each block's centre in it. */
export function timecodeStrip(scale: number): { rect: { x: number; y: number; width: number; height: number }; xs: number[] } {
  const even = (v: number) => 2 * Math.max(0, Math.round(v / 2));
  const x = even(8 * scale);
  const rect = { x, y: even(16 * scale), width: Math.max(2, even(512 * scale)), height: 2 };
  const xs = Array.from({ length: 32 }, (_, i) => Math.min(rect.width - 1, Math.max(0, Math.round((8 + i * 16 + 8) * scale) - x)));
  return { rect, xs };
}

/** The smallest rect holding both `a` and `b` (their corners even: so is its). */
export function spanning(
  a: { x: number; y: number; width: number; height: number },
  b: { x: number; y: number; width: number; height: number },
): { x: number; y: number; width: number; height: number } {
  const x = Math.min(a.x, b.x);
  const y = Math.min(a.y, b.y);
  const right = Math.max(a.x + a.width, b.x + b.width);
  const bottom = Math.max(a.y + a.height, b.y + b.height);
  return { x, y, width: right - x, height: bottom - y };
}

/** Read every frame until the stream ends, each closed once read; `now`: the page's
 * clock (s), `add`: one frame's capture → decoded age (ms); `fullWidth`: the full
 * picture's width (both eyes), when known, so a smaller layer is read at its scale;
 * `marks`: while it says so, each frame's motion mark is read too (view/handeye.ts). */
export async function readFrames(
  reader: ReadableStreamDefaultReader<VideoFrame>,
  now: () => number,
  clock: ServerClock,
  add: (ms: number) => void,
  fullWidth: () => number | null = () => null,
  marks: MarkSink | null = null,
): Promise<void> {
  for (;;) {
    const { value: frame, done } = await reader.read().catch(() => ({ value: undefined, done: true }));
    if (done || !frame) return;
    const at = now();
    try {
      const full = fullWidth();
      const scale = full ? frame.displayWidth / full : 1;
      const { rect, xs } = timecodeStrip(scale);
      // With the mark wanted, one copy holds both (a second copyTo a frame cut this
      // worker's reads from 30 to 6 a second on a software GPU): the rect from the
      // timecode's strip over the mark's rulers.
      const m = marks?.on() ? markStrip(scale) : null;
      const whole = m ? spanning(rect, m.rect) : rect;
      const buffer = new Uint8Array(frame.allocationSize({ rect: whole }));
      const layout = await frame.copyTo(buffer, { rect: whole });
      const rgb = (frame.format ?? "").startsWith("RGB") || (frame.format ?? "").startsWith("BGR");
      const stride = layout[0]?.stride ?? whole.width * (rgb ? 4 : 1);
      const codeAt = (layout[0]?.offset ?? 0) + (rect.y - whole.y) * stride + (rect.x - whole.x) * (rgb ? 4 : 1);
      let code = 0;
      for (const x of xs) {
        code = code * 2 + ((buffer[codeAt + (rgb ? x * 4 + 1 : x)] ?? 0) > 128 ? 1 : 0);
      }
      if (clock.bestRtt < Infinity) {
        const wrap = 2 ** 32;
        const server = at + clock.offset;
        const behind = ((((Math.round(server / 1e-4) - code) % wrap) + wrap) % wrap) / 10; // ms
        if (behind < 5000) add(behind);
        if (behind < 5000 && m && marks) {
          const markAt = (layout[0]?.offset ?? 0) + (m.rect.y - whole.y) * stride + (m.rect.x - whole.x) * (rgb ? 4 : 1);
          const mark = readMark(buffer, markAt, stride, rgb, scale);
          marks.add({ code, mediaUs: frame.timestamp, exposureAt: at * 1000 - behind, decodedAt: at * 1000, mark });
        }
      }
    } finally {
      frame.close();
    }
  }
}
