import { describe, expect, it } from "vitest";
import { readFrames, timecodeStrip } from "./view/glass";
import { type CommandTimes, type PresentedFrame, type Press, PARTS, joinMotions } from "./view/handeye";
import { type DecodedFrame, MARK, markStrip, movedPx, readMark } from "./view/motion-mark";

/** A copy of `markStrip(scale)`'s rect with the rulers at `lengths` (full-size px) drawn
 * as drivers/camera/motion_mark.py draws them, luma only. */
function markCopy(lengths: number[], scale: number): { buffer: Uint8Array; stride: number } {
  const { rect } = markStrip(scale);
  const buffer = new Uint8Array(rect.width * rect.height);
  const ruler = [
    [6, 12],
    [14, 20],
    [22, 28],
  ];
  for (let y = 0; y < rect.height; y++) {
    const full = (rect.y + y) / scale; // the full-size row this row shows
    const k = ruler.findIndex(([a, b]) => full >= a! && full < b!);
    if (k < 0) continue;
    for (let x = 0; x < rect.width; x++) buffer[y * rect.width + x] = x / scale < lengths[k]! ? 235 : 16;
  }
  return { buffer, stride: rect.width };
}

describe("the motion mark as the page reads it", () => {
  it("sits beside the timecode, in the rows the page crops, even for a 4:2:0 copy", () => {
    const { rect, rows } = markStrip(1);
    expect(rect).toEqual({ x: 528, y: 8, width: 96, height: 18 });
    expect(rows).toEqual([0, 8, 16]);
    const half = markStrip(0.5); // the server's low layer
    expect(half.rect).toEqual({ x: 264, y: 4, width: 48, height: 10 });
    expect(half.rows).toEqual([0, 4, 8]);
    const tc = timecodeStrip(1).rect;
    expect(rect.x).toBeGreaterThan(tc.x + tc.width); // clear of the timecode's blocks
    expect(rect.y + rect.height).toBeLessThanOrEqual(28); // view/stereo.ts TIMECODE_ROWS
  });

  it("reads each ruler's length back, at full and half size", () => {
    const lengths = [0, 37, 95];
    const full = markCopy(lengths, 1);
    expect(readMark(full.buffer, 0, full.stride, false, 1)).toEqual(lengths);
    const half = markCopy([10, 38, 94], 0.5);
    expect(readMark(half.buffer, 0, half.stride, false, 0.5)).toEqual([10, 38, 94]);
  });

  it("measures a move across the ruler's wrap", () => {
    expect(movedPx([95, 10, 3], [1, 10, 3])).toBe(2);
    expect(movedPx([5, 10, 3], [5, 7, 3])).toBe(3);
    expect(movedPx([5, 10, 3], [5, 10, 3])).toBe(0);
    expect(MARK.length * MARK.mPerPx).toBeCloseTo(0.0096, 9);
  });

  it("is read in the glass meter's frames while asked, with the exposure and decoded times", async () => {
    const code = 100_000 - 250; // exposed 25 ms before the server's now (10 s)
    const lengths = [12, 40, 80];
    // The picture's luma, 1280 × 40: the timecode's blocks and the mark's rulers drawn
    // as the camera draws them; a copy is of the rect asked for (one copy holds both).
    const W = 1280;
    const picture = new Uint8Array(W * 40);
    for (let i = 0; i < 32; i++) {
      if (!((code >>> (31 - i)) & 1)) continue;
      for (let y = 8; y < 24; y++) picture.fill(255, y * W + 8 + i * 16, y * W + 8 + (i + 1) * 16);
    }
    MARK.readRows.forEach((row, i) => {
      for (const y of [row, row + 1]) picture.fill(255, y * W + MARK.x0, y * W + MARK.x0 + lengths[i]!);
    });
    const copies: number[] = [];
    const frame = {
      format: "I420",
      displayWidth: W,
      allocationSize: ({ rect }: { rect: { width: number; height: number } }) => rect.width * rect.height,
      copyTo: async (buffer: Uint8Array, { rect }: { rect: { x: number; y: number; width: number; height: number } }) => {
        copies.push(rect.width * rect.height);
        for (let y = 0; y < rect.height; y++) buffer.set(picture.subarray((rect.y + y) * W + rect.x, (rect.y + y) * W + rect.x + rect.width), y * rect.width);
        return [{ offset: 0, stride: rect.width }];
      },
      close: () => undefined,
    };
    const got: DecodedFrame[] = [];
    for (const on of [true, false]) {
      const frames = [frame];
      const reader = {
        read: async () => (frames.length ? { value: frames.pop(), done: false } : { value: undefined, done: true }),
      } as unknown as ReadableStreamDefaultReader<VideoFrame>;
      await readFrames(reader, () => 10, { bestRtt: 0.001, offset: 0 }, () => undefined, () => 1280, { on: () => on, add: (f) => got.push(f) });
    }
    expect(copies).toHaveLength(2); // one copy a frame, with the mark or without
    expect(copies[0]).toBeGreaterThan(copies[1]!);
    expect(got).toHaveLength(1); // not read once no longer asked
    expect(got[0]!.code).toBe(code);
    expect(got[0]!.mark).toEqual(lengths);
    expect(got[0]!.decodedAt).toBe(10_000);
    expect(got[0]!.exposureAt).toBeCloseTo(9_975, 6);
  });
});

describe("one motion from its records", () => {
  // Frames every 20 ms from t = 0 (page ms; code: the exposure in 0.1 ms), decoded 15 ms
  // after their exposure; the mark moves from 1030 ms's exposure on.
  const decoded: DecodedFrame[] = Array.from({ length: 100 }, (_, i) => {
    const t = 20 * i;
    return { code: t * 10, mediaUs: 1000 * t + 7, exposureAt: t, decodedAt: t + 15, mark: [50, 20, 70 + (t >= 1030 ? 4 : 0)] };
  });
  const presented: PresentedFrame[] = decoded.map((f) => ({ mediaUs: f.mediaUs, submittedAt: f.decodedAt + 2, presentedAt: f.decodedAt + 9 }));
  const press: Press = { key: "KeyW", at: 1000.5 };
  const commands: CommandTimes[] = [
    { sentAt: 990, appliedAt: 991 }, // an earlier motion's
    { sentAt: 1008, appliedAt: 1009 },
    { sentAt: 1024, appliedAt: 1025 },
  ];

  it("is the first command after the press, the first frame its mark moved in, and that frame shown", () => {
    const { motions, missed } = joinMotions([press], commands, decoded, presented);
    expect(missed).toEqual({});
    expect(motions).toHaveLength(1);
    const m = motions[0]!;
    expect(m.code).toBe(10_400); // the frame exposed at 1040 ms
    expect(m.parts).toEqual({
      input_to_sent: 7.5,
      sent_to_applied: 1,
      applied_to_exposure: 31,
      exposure_to_decoded: 15,
      decoded_to_presented: 9,
    });
    const sum = PARTS.reduce((s, p) => s + m.parts[p], 0);
    expect(sum).toBeCloseTo(m.wholeMs, 9);
    expect(m.wholeMs).toBeCloseTo(1064 - 1000.5, 9);
    expect(m.movedPx).toBe(4);
  });

  it("was decoded when the <video> had it, if the glass meter read it later", () => {
    const early = presented.map((p) => ({ ...p, submittedAt: p.submittedAt - 10 }));
    const [m] = joinMotions([press], commands, decoded, early).motions;
    expect(m!.parts.exposure_to_decoded).toBe(15 + 2 - 10);
    expect(m!.parts.decoded_to_presented).toBe(9 - 2 + 10);
  });

  it("is shown by the next frame presented when its own one was skipped", () => {
    const skipped = presented.filter((p) => p.mediaUs !== 1_040_007);
    const [m] = joinMotions([press], commands, decoded, skipped).motions;
    expect(m!.parts.decoded_to_presented).toBe(20 + 9);
  });

  it("is left out, and why, when a part is missing", () => {
    const still = decoded.map((f) => ({ ...f, mark: [50, 20, 70] }));
    expect(joinMotions([press], commands, still, presented).missed).toEqual({ "no motion seen": 1 });
    expect(joinMotions([press], commands.slice(0, 1), decoded, presented).missed).toEqual({ "no command": 1 });
    expect(joinMotions([press], commands, decoded, presented.slice(0, 40)).missed).toEqual({ "not presented": 1 });
    expect(joinMotions([{ key: "KeyW", at: 1500 }], commands, decoded, presented).missed).toEqual({ "no command": 1 });
    const noMark = decoded.map((f) => ({ ...f, mark: null }));
    expect(joinMotions([press], commands, noMark, presented).missed).toEqual({ "no frame before": 1 });
  });

  it("looks no further than the next press", () => {
    const next: Press = { key: "KeyS", at: 1020 };
    const { motions, missed } = joinMotions([press, next], commands, decoded, presented);
    expect(missed).toEqual({ "no motion seen": 1 }); // the first: its frames end at the next press
    expect(motions.map((m) => m.key)).toEqual(["KeyS"]);
  });
});
