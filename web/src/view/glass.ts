// Glass-to-glass latency, measured in the page for every frame.
import type { Rolling } from "../stats";

/** The clock sync the measurement needs: server − page clock (s), valid once bestRtt is finite. */
export interface ServerClock {
  bestRtt: number;
  offset: number;
}

/** Capture → decoded frame in this page, for every frame: each decoded frame carries its
 * capture time as a timecode (32 blocks of 16 px at (8, 8) in the left image), read from
 * the decoder's own frame (a 512×2 luma copy; no GPU read-back), on the server's clock
 * through the ping offset. Reads `track` (a copy: it is stopped) until `stop()`. */
export function measureGlass(track: MediaStreamTrack, clock: ServerClock, glass: Rolling): { stop(): void } {
  const Processor = (window as unknown as { MediaStreamTrackProcessor?: new (i: { track: MediaStreamTrack }) => { readable: ReadableStream<VideoFrame> } })
    .MediaStreamTrackProcessor;
  if (!Processor) return { stop: () => track.stop() }; // not Chromium: the panel shows no glass-to-glass figure
  const reader = new Processor({ track }).readable.getReader();
  void readFrames(reader, clock, glass);
  return {
    stop() {
      // Stopping the track ends the stream after the frames already queued, which the
      // reader still takes and closes. Cancelling the stream instead would drop them
      // unclosed, to the garbage collector, which Chromium reports on the console as an
      // error ("A VideoFrame was garbage collected without being closed": seen when a
      // peer was re-negotiated). A reader still not done a second later is cancelled.
      track.stop();
      setTimeout(() => void reader.cancel().catch(() => undefined), 1000);
    },
  };
}

async function readFrames(reader: ReadableStreamDefaultReader<VideoFrame>, clock: ServerClock, glass: Rolling): Promise<void> {
  const rect = { x: 8, y: 16, width: 512, height: 2 };
  for (;;) {
    const { value: frame, done } = await reader.read().catch(() => ({ value: undefined, done: true }));
    if (done || !frame) return;
    const now = performance.now() / 1000;
    try {
      const buffer = new Uint8Array(frame.allocationSize({ rect }));
      const layout = await frame.copyTo(buffer, { rect });
      const rgb = (frame.format ?? "").startsWith("RGB") || (frame.format ?? "").startsWith("BGR");
      let code = 0;
      for (let i = 0; i < 32; i++) {
        const x = i * 16 + 8;
        code = code * 2 + ((buffer[(layout[0]?.offset ?? 0) + (rgb ? x * 4 + 1 : x)] ?? 0) > 128 ? 1 : 0);
      }
      if (clock.bestRtt < Infinity) {
        const wrap = 2 ** 32;
        const server = now + clock.offset;
        const behind = ((((Math.round(server / 1e-4) - code) % wrap) + wrap) % wrap) / 10; // ms
        if (behind < 5000) glass.add(behind);
      }
    } finally {
      frame.close();
    }
  }
}
