import { describe, expect, it } from "vitest";
import { PUMA } from "./puma.fixture";
import { project } from "./ar/projection";
import { deadzone } from "./input/motion";
import { XRMaster } from "./input/xr";
import { type Mat4, identity4, mul4, position } from "./robot/math";
import { PredictedArm, applyIncrement, forwardKinematics, jointOrigins } from "./robot/model";
import { Rolling } from "./stats";

const near = (a: number[], b: number[], tol = 1e-4) => a.forEach((v, i) => expect(Math.abs(v - (b[i] ?? NaN))).toBeLessThan(tol));

describe("robot model", () => {
  it("matches the server's reference poses", () => {
    const noTool = { ...PUMA, tool: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]] };
    near(position(forwardKinematics(noTool, [0, 0, 0, 0, 0, 0])), [0.4521, -0.15005, 1.1036]);
    near(position(forwardKinematics(noTool, [0, Math.PI / 4, -Math.PI, 0, Math.PI / 4, 0])), [0.5963, -0.15005, 0.6575]);
    near(position(forwardKinematics(PUMA, [0, 0, 0, 0, 0, 0])), [0.4521, -0.15005, 1.2036]);
  });

  it("is the PUMA's DH table as a joint tree", () => {
    // The standard DH rows (d, a, α) the page used before the server sent the tree.
    const dh = [
      [0.67183, 0, Math.PI / 2],
      [0, 0.4318, 0],
      [0.15005, 0.0203, -Math.PI / 2],
      [0.4318, 0, Math.PI / 2],
      [0, 0, -Math.PI / 2],
      [0, 0, 0],
    ];
    const row = (q: number, [d, a, alpha]: number[]): Mat4 => {
      const [ct, st, ca, sa] = [Math.cos(q), Math.sin(q), Math.cos(alpha!), Math.sin(alpha!)];
      return [ct, -st * ca, st * sa, a! * ct, st, ct * ca, -ct * sa, a! * st, 0, sa, ca, d!, 0, 0, 0, 1];
    };
    for (const q of [[0, 0, 0, 0, 0, 0], [0.3, -1.2, 2.1, -0.4, 0.9, 2.8], [-2, 0.5, -3, 1.7, -1.1, -0.6]]) {
      const frames: Mat4[] = [identity4()];
      dh.forEach((r, i) => frames.push(mul4(frames.at(-1)!, row(q[i]!, r))));
      near(forwardKinematics(PUMA, q), mul4(frames.at(-1)!, PUMA.tool.flat()), 1e-12);
      // The skeleton: each joint sits where the DH frame before it has its origin.
      near(jointOrigins(PUMA, q).slice(1, 7).flat(), frames.slice(0, 6).map(position).flat(), 1e-12);
    }
  });

  it("applies increments in the base, tool and wrist frames", () => {
    const T = forwardKinematics(PUMA, [0, Math.PI / 4, -Math.PI, 0, Math.PI / 4, 0]);
    const p = position(T);
    near(position(applyIncrement(PUMA, T, [0.01, 0, 0], [0, 0, 0], "base")), [p[0] + 0.01, p[1], p[2]], 1e-12);
    // A rotation about the tool axis keeps the tool point, but swings it about the wrist.
    near(position(applyIncrement(PUMA, T, [0, 0, 0], [0.3, 0, 0], "tool")), p, 1e-12);
    const swung = position(applyIncrement(PUMA, T, [0, 0, 0], [0.3, 0, 0], "wrist"));
    expect(Math.hypot(swung[0] - p[0], swung[1] - p[1], swung[2] - p[2])).toBeCloseTo(2 * 0.1 * Math.sin(0.15), 6);
  });

  it("predicts from commands and snaps back to the reported arm when idle", () => {
    const arm = new PredictedArm(PUMA, 300);
    const q = [0, Math.PI / 4, -Math.PI, 0, Math.PI / 4, 0];
    arm.report(q, false, 0);
    const p0 = position(arm.pose!);
    arm.commandCartesian([0.02, 0, 0], [0, 0, 0], "base", 1000);
    near(position(arm.pose!), [p0[0] + 0.02, p0[1], p0[2]], 1e-12);
    arm.report(q, true, 1100); // still moving: keep the prediction
    near(position(arm.pose!), [p0[0] + 0.02, p0[1], p0[2]], 1e-12);
    arm.report(q, false, 1500); // settled: trust the robot
    near(position(arm.pose!), p0, 1e-12);
  });
});

describe("inputs and projection", () => {
  it("projects with a 3×4 matrix and refuses points behind the camera", () => {
    const P = [[100, 0, 50, 0], [0, 100, 40, 0], [0, 0, 1, 0]];
    expect(project(P, [0.1, 0.2, 1])).toEqual([60, 60]);
    expect(project(P, [0, 0, -1])).toBeNull();
    expect(position(identity4())).toEqual([0, 0, 0]);
  });

  it("applies a dead-zone and rescales beyond it", () => {
    expect(deadzone(0.1, 0.15)).toBe(0);
    expect(deadzone(1, 0.15)).toBe(1);
    expect(deadzone(-0.575, 0.15)).toBeCloseTo(-0.5);
  });

  it("XR clutch re-anchors and ignores tracking jumps", () => {
    const xr = new XRMaster();
    const q: [number, number, number, number] = [0, 0, 0, 1];
    expect(xr.update(true, [0, 1, 0], q, 0)).toBeNull(); // anchor
    near(xr.update(true, [0, 1, -0.01], q, 0.011)!.dX, [0.01, 0, 0], 1e-12); // forward in XR is +x for the robot
    expect(xr.update(true, [0, 2, 0], q, 0.022)).toBeNull(); // a 1 m jump in one 90 Hz frame
    expect(xr.update(true, [0, 2, -0.06], q, 0.033)).toBeNull(); // 6 cm in 11 ms: a jump too
    expect(xr.update(false, [0, 2, 0], q, 0.044)).toBeNull();
    expect(xr.update(true, [0, 2, 0], q, 0.055)).toBeNull(); // gripped again: a new anchor, no step
  });

  it("XR clutch keeps a slow page's hand motion: the jump guard is a speed, not a step", () => {
    const xr = new XRMaster();
    const q: [number, number, number, number] = [0, 0, 0, 1];
    xr.update(true, [0, 1, 0], q, 0);
    // Frames 0.5 s apart: a 10 cm step is 0.2 m/s, a hand's pace, and it is sent.
    near(xr.update(true, [0, 1, -0.1], q, 0.5)!.dX, [0.1, 0, 0], 1e-12);
    // 1.5 m in 0.5 s (3 m/s) is not a hand.
    expect(xr.update(true, [0, 1, -1.6], q, 1.0)).toBeNull();
  });

  it("keeps rolling percentiles", () => {
    const r = new Rolling(5);
    [5, 1, 4, 2, 3, 100].forEach((v) => r.add(v));
    expect(r.count).toBe(5);
    expect(r.percentile(50)).toBe(3); // the oldest (5) fell out: 1 2 3 4 100
  });
});
