import { describe, expect, it } from "vitest";
import { PUMA } from "./puma.fixture";
import { GhostArm, REDRAW_PX, ghostChain, largestShift } from "./ar/ghost";
import { matrixToRotvec, position, rotation, rotvecToMatrix } from "./robot/math";
import { PredictedArm, forwardKinematics, jointOrigins, linkFrames, solveIK } from "./robot/model";

const QN = [0, Math.PI / 4, -Math.PI, 0, Math.PI / 4, 0];
const near = (a: number[], b: number[], tol = 1e-4) => {
  expect(a.length).toBe(b.length);
  a.forEach((v, i) => expect(Math.abs(v - (b[i] ?? NaN))).toBeLessThan(tol));
};
// A camera looking along base +y at the arm from its side: u = 320 + 100 x, v = 240 − 100 z.
const SIDE = [
  [100, 0, 0, 320],
  [0, 0, -100, 240],
  [0, 0, 0, 1],
];
// A camera 3 m in front of the arm (at x = 3, looking along −x), focal length 500 px.
const FRONT = [
  [0, -500, -320, 960],
  [-240, 0, -500, 240 * 3 + 500 * 0.8],
  [-1, 0, 0, 3],
];

describe("the arm's link frames", () => {
  it("runs from the base through every joint to the tool", () => {
    const pts = jointOrigins(PUMA, [0, 0, 0, 0, 0, 0]);
    expect(pts).toHaveLength(8); // base, six joints, tool
    near(pts[0]!, [0, 0, 0]);
    near(pts[1]!, [0, 0, 0]); // the waist joint, on the base
    near(pts[2]!, [0, 0, 0.67183]); // the shoulder
    near(pts[3]!, [0.4318, 0, 0.67183]); // the elbow (upper arm along x at q = 0)
    near(pts[7]!, [0.4521, -0.15005, 1.2036]); // the tool, as forwardKinematics gives it
    near(linkFrames(PUMA, QN).at(-1)!, forwardKinematics(PUMA, QN), 1e-12);
  });
});

describe("the ghost's projection", () => {
  it("projects the chain into each camera's pixels", () => {
    const chain = ghostChain(PUMA, [0, 0, 0, 0, 0, 0], SIDE);
    expect(chain).toHaveLength(8);
    near(chain[0]!, [320, 240]);
    near(chain[1]!, [320, 240]); // the waist joint, on the base
    near(chain[2]!, [320, 240 - 67.183]);
    near(chain[3]!, [320 + 43.18, 240 - 67.183]);
    near(chain[7]!, [320 + 45.21, 240 - 120.36], 0.01); // (the tool to 0.1 mm)
    // Perspective: the base's origin lands at the principal point's column.
    const front = ghostChain(PUMA, QN, FRONT);
    near(front[0]!, [320, 240 + 500 * 0.8 / 3]);
    // Behind the camera: no pixel.
    expect(ghostChain(PUMA, [0, 0, 0, 0, 0, 0], [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0]]).every((p) => p === null)).toBe(true);
  });

  it("measures how far the chain moved", () => {
    expect(largestShift([[0, 0], [10, 10]], [[0, 0.3], [10, 12]])).toBeCloseTo(2);
    expect(largestShift([[0, 0]], [null])).toBe(Infinity);
    expect(largestShift([], [[1, 1]])).toBe(Infinity);
    expect(largestShift([null], [null])).toBe(0);
  });

  it("asks for a redraw only when it moved half a pixel, or was switched", () => {
    const ghost = new GhostArm(PUMA, [
      { name: "left", P: SIDE },
      { name: "right", P: FRONT },
    ]);
    expect(ghost.update(null)).toBe(false);
    expect(ghost.update(QN)).toBe(true); // the first pose
    near(ghost.pixels[0][7]!, ghostChain(PUMA, QN, SIDE)[7]!);
    near(ghost.pixels[1][7]!, ghostChain(PUMA, QN, FRONT)[7]!);
    // 1e-4 rad at the waist swings the tool ~0.06 mm: far under half a pixel.
    expect(ghost.update([1e-4, ...QN.slice(1)])).toBe(false);
    // 0.01 rad at the shoulder: several pixels.
    const moved = [0, QN[1]! + 0.01, ...QN.slice(2)];
    expect(REDRAW_PX).toBe(0.5);
    expect(ghost.update(moved)).toBe(true);
    expect(ghost.setEnabled(false)).toBe(true);
    expect(ghost.setEnabled(false)).toBe(false);
    expect(ghost.update(QN)).toBe(false); // hidden: moves are kept, nothing to redraw
    near(ghost.pixels[0][7]!, ghostChain(PUMA, QN, SIDE)[7]!);
    expect(ghost.setEnabled(true)).toBe(true);
  });

  it("paints the links and a dot on every joint in the eye asked for, nothing when off", () => {
    const ghost = new GhostArm(PUMA, [
      { name: "left", P: SIDE },
      { name: "right", P: FRONT },
    ]);
    ghost.update(QN);
    const dots: [number, number][] = [];
    let strokes = 0;
    const ctx = {
      beginPath() {},
      moveTo() {},
      lineTo() {},
      stroke: () => (strokes += 1),
      fill() {},
      arc: (x: number, y: number) => dots.push([x, y]),
    } as unknown as CanvasRenderingContext2D;
    ghost.paint(ctx, 1, { width: 640, height: 360 });
    expect(strokes).toBe(1);
    expect(dots).toEqual(ghostChain(PUMA, QN, FRONT));
    ghost.setEnabled(false);
    dots.length = 0;
    ghost.paint(ctx, 0, { width: 640, height: 360 });
    expect(dots).toEqual([]);
  });
});

describe("the predicted arm's joints", () => {
  it("inverse kinematics finds the nearby joints of a pose", () => {
    const q = [0.1, Math.PI / 4 + 0.05, -Math.PI + 0.1, 0.2, Math.PI / 4 - 0.1, 0.3];
    near(solveIK(PUMA, forwardKinematics(PUMA, q), QN), q, 1e-6);
    const R = rotvecToMatrix([0.1, -0.2, 0.3]);
    near(matrixToRotvec(R), [0.1, -0.2, 0.3], 1e-9);
    near(matrixToRotvec(rotvecToMatrix([Math.PI, 0, 0])), [Math.PI, 0, 0], 1e-6);
  });

  it("are the reported joints until a command moves the prediction, then follow it", () => {
    const arm = new PredictedArm(PUMA);
    expect(arm.joints).toBeNull();
    arm.report(QN, false, 0);
    expect(arm.joints).toEqual(QN);
    arm.commandCartesian([0.02, -0.01, 0.01], [0, 0, 0.05], "base", 10);
    const q = arm.joints!;
    near(position(forwardKinematics(PUMA, q)), position(arm.pose!), 1e-6);
    near(rotation(forwardKinematics(PUMA, q)), rotation(arm.pose!), 1e-6);
    near(q, QN, 0.2); // the same configuration, a little moved
  });
});
