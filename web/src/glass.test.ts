import { afterEach, describe, expect, it, vi } from "vitest";
import { measureGlass } from "./view/glass";
import { Rolling } from "./stats";

/** A MediaStreamTrackProcessor whose stream holds `queued` frames and ends when its
 * track is stopped (as Chromium's does), recording what happened to each frame. */
function fakeProcessor(queued: number) {
  const log: string[] = [];
  const frames = Array.from({ length: queued }, (_, i) => ({
    format: "I420",
    allocationSize: () => 1024,
    copyTo: async (buffer: Uint8Array) => [{ offset: 0, stride: buffer.length }],
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
    await vi.advanceTimersByTimeAsync(1000); // the late cancel finds nothing left
    expect(log.at(-1)).toBe("cancelled with 0 unread");
  });
});
