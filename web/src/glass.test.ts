import { afterEach, describe, expect, it, vi } from "vitest";
import { STUCK_MS, measureGlass, readFrames, timecodeStrip } from "./view/glass";
import { Rolling } from "./stats";

/** A MediaStreamTrackProcessor whose stream holds `queued` frames and ends when its
 * track is stopped (as Chromium's does), recording what happened to each frame. */
function fakeProcessor(queued: number, copyMs = 0) {
  const log: string[] = [];
  const frames = Array.from({ length: queued }, (_, i) => ({
    format: "I420",
    allocationSize: () => 1024,
    copyTo: async (buffer: Uint8Array) => {
      if (copyMs) await new Promise((r) => setTimeout(r, copyMs));
      return [{ offset: 0, stride: buffer.length }];
    },
    close: () => log.push(`closed ${i}`),
  }));
  let ended = false;
  let wake: (() => void) | null = null;
  const track = {
    stop: () => {
      log.push("track stopped");
      ended = true;
      wake?.();
    },
  } as unknown as MediaStreamTrack;
  const reader = {
    async read() {
      const frame = frames.shift();
      if (frame) return { value: frame, done: false };
      if (!ended) await new Promise<void>((r) => (wake = r));
      return { value: undefined, done: true };
    },
    async cancel() {
      log.push(`cancelled with ${frames.length} unread`);
    },
  };
  (globalThis as Record<string, unknown>).MediaStreamTrackProcessor = class {
    readable = { getReader: () => reader };
  };
  return { track, log };
}

afterEach(() => {
  delete (globalThis as Record<string, unknown>).MediaStreamTrackProcessor;
  vi.useRealTimers();
});

describe("the glass-to-glass meter (on the page's thread: no Worker here)", () => {
  it("closes every frame it was given, those still queued when it stops too, and cancels nothing it had", async () => {
    vi.useFakeTimers();
    const { track, log } = fakeProcessor(3);
    const meter = measureGlass(track, { bestRtt: Infinity, offset: 0 }, new Rolling(10));
    meter.stop();
    await vi.advanceTimersByTimeAsync(0);
    expect(log).toEqual(["track stopped", "closed 0", "closed 1", "closed 2"]);
    await vi.advanceTimersByTimeAsync(STUCK_MS); // the late cancel finds nothing left
    expect(log.at(-1)).toBe("cancelled with 0 unread");
  });

  it("gives a reader slowed by a busy machine the time to close its queue before cancelling", async () => {
    vi.useFakeTimers();
    const { track, log } = fakeProcessor(4, 600); // 2.4 s to read what is queued
    const meter = measureGlass(track, { bestRtt: Infinity, offset: 0 }, new Rolling(10));
    meter.stop();
    await vi.advanceTimersByTimeAsync(3000);
    expect(log).toEqual(["track stopped", "closed 0", "closed 1", "closed 2", "closed 3"]);
    await vi.advanceTimersByTimeAsync(STUCK_MS);
    expect(log.at(-1)).toBe("cancelled with 0 unread");
  });
});

describe("the timecode on a smaller layer", () => {
  it("is read where the blocks are at the picture's own scale", () => {
    expect(timecodeStrip(1)).toEqual({
      rect: { x: 8, y: 16, width: 512, height: 2 },
      xs: Array.from({ length: 32 }, (_, i) => 8 + 16 * i),
    });
    const half = timecodeStrip(0.5); // the server's low layer
    expect(half.rect).toEqual({ x: 4, y: 8, width: 256, height: 2 });
    expect(half.xs.slice(0, 3)).toEqual([4, 12, 20]);
  });

  it("gives the low layer's frames their latency (they were dropped as unreadable)", async () => {
    const code = 100_000 - 250; // drawn 25 ms before the server's now (10 s)
    const frame = {
      format: "I420",
      displayWidth: 1280, // both eyes at half of 2560
      allocationSize: ({ rect }: { rect: { width: number; height: number } }) => rect.width * rect.height,
      copyTo: async (buffer: Uint8Array, { rect }: { rect: { width: number } }) => {
        const { xs } = timecodeStrip(rect.width / 512);
        xs.forEach((x, i) => (buffer[x] = (code >>> (31 - i)) & 1 ? 255 : 0));
        return [{ offset: 0, stride: rect.width }];
      },
      close: () => undefined,
    };
    const frames = [frame];
    const reader = {
      read: async () => (frames.length ? { value: frames.pop(), done: false } : { value: undefined, done: true }),
    } as unknown as ReadableStreamDefaultReader<VideoFrame>;
    const got: number[] = [];
    await readFrames(reader, () => 10, { bestRtt: 0.001, offset: 0 }, (ms) => got.push(ms), () => 2560);
    expect(got).toHaveLength(1);
    expect(got[0]).toBeCloseTo(25, 6);
  });
});
