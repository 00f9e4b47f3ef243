import { describe, expect, it } from "vitest";
import { PathOverlay, endDirection, pathLength, projectPath, thin } from "./ar/path";
import type { Vec3 } from "./robot/math";

// A camera looking along base +y at the arm from its side: u = 320 + 100 x, v = 240 − 100 z.
const SIDE = [
  [100, 0, 0, 320],
  [0, 0, -100, 240],
  [0, 0, 0, 1],
];
// The same, 1 m further along y with a 500 px focal length: perspective (w = y + 1).
const PERSPECTIVE = [
  [500, 320, 0, 320],
  [0, 240, -500, 240],
  [0, 1, 0, 1],
];
const BEHIND = [
  [1, 0, 0, 0],
  [0, 1, 0, 0],
  [0, 0, -1, 0],
];

describe("a task's path projected", () => {
  it("lands each base-frame point in the camera's pixels", () => {
    const px = projectPath(SIDE, [
      [0, 0, 0],
      [0.1, 0, 0.2],
    ]);
    expect(px[0]).toEqual([320, 240]);
    expect(px[1]![0]).toBeCloseTo(330);
    expect(px[1]![1]).toBeCloseTo(220);
    // Perspective: twice as far, half the offset from the principal point.
    const far = projectPath(PERSPECTIVE, [
      [0.1, 0, 0],
      [0.1, 1, 0],
    ]);
    expect(far[0]![0]).toBeCloseTo(370);
    expect(far[1]![0]).toBeCloseTo(345);
    expect(far[1]![1]).toBeCloseTo(240);
    expect(projectPath(BEHIND, [[0, 0, 1]])).toEqual([null]);
  });

  it("points its arrowhead along the last segment that moved", () => {
    const [dx, dy] = endDirection([[0, 0], [10, 0], [10, 0.2]])!; // (10, 0) is under 1 px from the end: from (0, 0)
    expect(dx).toBeCloseTo(1, 3);
    expect(dy).toBeCloseTo(0.02, 3);
    const dir = endDirection([[0, 0], [0, 10], [0, 10]])!; // the repeated end point skipped
    expect(dir[0]).toBeCloseTo(0);
    expect(dir[1]).toBeCloseTo(1);
    expect(endDirection([[5, 5]])).toBeNull();
    expect(endDirection([null, null])).toBeNull();
  });
});

describe("the path's points", () => {

  it("thins evenly, keeping both ends", () => {
    expect(thin([1, 2, 3], 5)).toEqual([1, 2, 3]);
    expect(thin([0, 1, 2, 3, 4, 5, 6, 7, 8], 3)).toEqual([0, 4, 8]);
  });

  it("measures its length", () => {
    expect(
      pathLength([
        [0, 0, 0],
        [0.03, 0.04, 0],
        [0.03, 0.04, 0.1],
      ]),
    ).toBeCloseTo(0.15);
  });
});

describe("the path overlay", () => {
  const host = () => {
    const h = { added: 0, changed: 0, addOverlay: () => (h.added += 1), overlayChanged: () => (h.changed += 1) };
    return h;
  };
  const cams = [
    { name: "left", P: SIDE },
    { name: "right", P: PERSPECTIVE },
  ];
  const A: Vec3[] = [
    [0, 0, 0],
    [0.02, 0, 0],
  ];

  it("asks for a redraw only when the path changes or is cleared", () => {
    const h = host();
    const path = new PathOverlay(cams, h);
    expect(h.added).toBe(1);
    expect(path.shown).toBe(false);
    path.clear(); // nothing shown: nothing to redraw
    expect(h.changed).toBe(0);
    path.show(A);
    expect(h.changed).toBe(1);
    expect(path.shown).toBe(true);
    expect(path.pixels[0][1]![0]).toBeCloseTo(322);
    expect(path.pixels[1][1]![0]).toBeCloseTo(330);
    path.show(A.map((p) => [...p] as Vec3)); // the same points again
    expect(h.changed).toBe(1);
    path.show([...A, [0.02, 0, 0.01]]);
    expect(h.changed).toBe(2);
    path.clear();
    expect(h.changed).toBe(3);
    expect(path.shown).toBe(false);
    expect(path.pixels).toEqual([[], []]);
  });

  it("draws nothing when cleared, a line, a start dot and an arrowhead when shown", () => {
    const calls: string[] = [];
    const ctx = new Proxy(
      {},
      {
        get: (_t, name: string) => (name === "save" || name === "restore" || typeof name !== "string" ? () => undefined : (..._args: unknown[]) => calls.push(name)),
        set: () => true,
      },
    ) as unknown as CanvasRenderingContext2D;
    const path = new PathOverlay(cams, null);
    path.paint(ctx, 0, { width: 640, height: 480 });
    expect(calls).toEqual([]);
    path.show(A);
    path.paint(ctx, 0, { width: 640, height: 480 });
    expect(calls.filter((c) => c === "stroke")).toHaveLength(2); // outline and line
    expect(calls.filter((c) => c === "arc")).toHaveLength(1); // the start dot
    expect(calls.filter((c) => c === "closePath")).toHaveLength(1); // the arrowhead
    expect(calls.filter((c) => c === "fill")).toHaveLength(2);
  });

  it("leads in with the approach, dashed, from the tool to the path's start", () => {
    const calls: string[] = [];
    const ctx = new Proxy(
      {},
      {
        get: (_t, name: string) => (name === "save" || name === "restore" || typeof name !== "string" ? () => undefined : (..._args: unknown[]) => calls.push(name)),
        set: () => true,
      },
    ) as unknown as CanvasRenderingContext2D;
    const h = host();
    const path = new PathOverlay(cams, h);
    const lead: Vec3[] = [
      [0.05, 0, 0.01],
      [0.02, 0, 0.005],
      [0, 0, 0],
    ];
    path.show(A, lead);
    expect(path.approach).toEqual(lead);
    expect(path.approachPixels[0]).toHaveLength(3);
    expect(path.approachPixels[0][0]![0]).toBeCloseTo(325);
    path.paint(ctx, 0, { width: 640, height: 480 });
    expect(calls.filter((c) => c === "stroke")).toHaveLength(4); // the approach's two, the path's two
    expect(calls.filter((c) => c === "setLineDash")).toHaveLength(2); // dashed, then solid again
    path.show(A, lead); // the same: no redraw
    expect(h.changed).toBe(1);
    path.show(A); // the same path from its start: the approach goes
    expect(h.changed).toBe(2);
    expect(path.approachPixels).toEqual([[], []]);
    path.show(A, lead);
    path.clear();
    expect(path.approach).toEqual([]);
    expect(path.approachPixels).toEqual([[], []]);
  });
});
