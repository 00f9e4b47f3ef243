// The motion mark the simulated camera draws beside the timecode
// (drivers/camera/motion_mark.py), as the page reads it from a decoded frame, and the
// decoded frames read with it for the hand-to-eye measurement (view/handeye.ts).

/** drivers/camera/motion_mark.py's layout (full size). */
export const MARK = { x0: 528, length: 96, readRows: [8, 16, 24], mPerPx: 1e-4 } as const;
/** A ruler that changed by this many pixels (0.3 mm of the tool) has moved: a decoded
 * bar's end is off by a pixel at most (tests/test_motion_mark.py). */
export const MOVED_PX = 3;
/** Records kept of each kind: at 60 fps five minutes of frames. */
export const KEPT = 20_000;

/** The rect that holds the mark's rulers in a picture `scale` times the size drawn at,
 * its corner and size even (4:2:0), and each ruler's row in it. */
export function markStrip(scale: number): { rect: { x: number; y: number; width: number; height: number }; rows: number[] } {
  const even = (v: number) => 2 * Math.max(0, Math.round(v / 2));
  const y = even(MARK.readRows[0] * scale);
  const rows = MARK.readRows.map((r) => Math.round(r * scale) - y);
  const height = Math.max(2, even(Math.max(...rows) + 2));
  return { rect: { x: even(MARK.x0 * scale), y, width: Math.max(2, even(MARK.length * scale)), height }, rows };
}

/** Each ruler's length (pixels at full size) from a copy of `markStrip(scale)`'s rect:
 * its pixels brighter than mid-grey on its row. `rgb`: 4 bytes a pixel (else luma). */
export function readMark(buffer: Uint8Array, offset: number, stride: number, rgb: boolean, scale: number): number[] {
  const { rect, rows } = markStrip(scale);
  return rows.map((row) => {
    let n = 0;
    for (let x = 0; x < rect.width; x++) if ((buffer[offset + row * stride + (rgb ? x * 4 + 1 : x)] ?? 0) > 128) n++;
    return n / scale;
  });
}

/** The largest change of a ruler between two readings (pixels), wrap-aware. */
export function movedPx(before: readonly number[], after: readonly number[]): number {
  let most = 0;
  before.forEach((a, i) => {
    const d = ((((after[i] ?? a) - a) % MARK.length) + MARK.length) % MARK.length;
    most = Math.max(most, Math.min(d, MARK.length - d));
  });
  return most;
}

/** One decoded frame, read in the glass meter: its timecode, its media timestamp (the
 * VideoFrame's, µs: the <video>'s requestVideoFrameCallback says the same of the frame
 * it presents as mediaTime), when it was exposed and decoded (page clock, ms) and its
 * mark (null: not read). */
export interface DecodedFrame {
  code: number;
  mediaUs: number;
  exposureAt: number;
  decodedAt: number;
  mark: number[] | null;
}
/** A list that keeps its newest `limit` entries. */
export class Kept<T> {
  readonly items: T[] = [];
  dropped = 0;
  constructor(private readonly limit = KEPT) {}
  push(item: T): void {
    this.items.push(item);
    if (this.items.length > this.limit) {
      this.items.splice(0, this.items.length - this.limit);
      this.dropped += 1;
    }
  }
}

/** The decoded frames the glass meter read with their mark: `on` while a recorder wants
 * them (the meter reads the mark only then: a second copy per frame). One per page. */
export const decodedFrames = { on: false, log: new Kept<DecodedFrame>() };

