import { describe, expect, it } from "vitest";
import { AxisMarker, type OverlayHost, frameAxes, projectMarker } from "./ar/axes";
import type { OverlayPainter } from "./view/overlay";
import { project } from "./ar/projection";
import { cameraAxes, viewAxes, viewFrame, viewToBase } from "./input/viewframe";
import { type Mat3, type Mat4, type Vec3, cross3, fromColumns, identity4, mulVec3, pose, rotvecToMatrix } from "./robot/math";

const sub = (a: Vec3, b: Vec3): Vec3 => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const unit = (v: Vec3): Vec3 => {
  const n = Math.hypot(...v);
  return [v[0] / n, v[1] / n, v[2] / n];
};
const near = (a: number[], b: number[], tol = 1e-9) => a.forEach((v, i) => expect(Math.abs(v - (b[i] ?? NaN))).toBeLessThan(tol));

/** P = s·K[R|t] of a camera at `at` looking at `target` (as drivers/sim/workcell.py's
 * PinholeCamera.look_at: x right, y down, z forward), `s` any non-zero scale. */
function lookAt(at: Vec3, target: Vec3, { up = [0, 0, 1] as Vec3, width = 1280, height = 720, skew = 0, s = 1 } = {}): number[][] {
  const z = unit(sub(target, at));
  const x = unit(cross3(z, up));
  const y = cross3(z, x);
  const f = width / 2 / Math.tan(Math.PI / 6);
  const K = [[f, skew, width / 2], [0, f, height / 2], [0, 0, 1]];
  const R = [x, y, z];
  const t = R.map((r) => -(r[0] * at[0] + r[1] * at[1] + r[2] * at[2]));
  return K.map((k) => [0, 1, 2, 3].map((j) => s * (j < 3 ? k[0]! * R[0]![j]! + k[1]! * R[1]![j]! + k[2]! * R[2]![j]! : k[0]! * t[0]! + k[1]! * t[1]! + k[2]! * t[2]!)));
}
/** Depth of `p` in the camera's frame (along its optical axis). */
const depth = (P: number[][], p: Vec3) => {
  const f = cameraAxes(P).forward;
  return f[0] * p[0] + f[1] * p[1] + f[2] * p[2];
};

// The simulated workcell's left camera (drivers/sim/workcell.py default_workcell):
// 1.8 m from the work centre, 20° to the side of +x, 25° above.
const CENTRE: Vec3 = [0.65, -0.15, 0.55];
const [AZ, EL] = [(20 * Math.PI) / 180, (25 * Math.PI) / 180];
const DIRECTION: Vec3 = [Math.cos(EL) * Math.cos(AZ), Math.cos(EL) * Math.sin(AZ), Math.sin(EL)];
const EYE: Vec3 = [CENTRE[0] + 1.8 * DIRECTION[0], CENTRE[1] + 1.8 * DIRECTION[1], CENTRE[2] + 1.8 * DIRECTION[2]];
const LEFT_HALF = unit(cross3([-DIRECTION[0], -DIRECTION[1], -DIRECTION[2]], [0, 0, 1])).map((v) => -0.06 * v) as Vec3;
const SIM_LEFT = lookAt([EYE[0] + LEFT_HALF[0], EYE[1] + LEFT_HALF[1], EYE[2] + LEFT_HALF[2]], [CENTRE[0] + LEFT_HALF[0], CENTRE[1] + LEFT_HALF[1], CENTRE[2] + LEFT_HALF[2]]);

const W: Vec3 = [1, 0, 0]; // the keyboard's command axes: W/S, A/D, R/F
const A: Vec3 = [0, 1, 0];
const R: Vec3 = [0, 0, 1];

describe("the view frame", () => {
  it("recovers the camera's axes from any P = s·K[R|t], skew and negative scale included", () => {
    for (const s of [1, -0.003, 42]) {
      const { right, down, forward } = cameraAxes(lookAt([3, 0, 0.5], [0, 0, 0.5], { skew: 3, s }));
      near(forward, [-1, 0, 0]);
      near(right, [0, 1, 0]); // looking back at the robot, its +y is to the right
      near(down, [0, 0, -1]);
    }
  });

  it("for a camera looking along base −x: W is −x, A is −y (image left), R is +z", () => {
    const view = viewFrame(lookAt([3, 0, 0.5], [0, 0, 0.5]));
    near(viewToBase(view, W), [-1, 0, 0]);
    near(viewToBase(view, A), [0, -1, 0]);
    near(viewToBase(view, R), [0, 0, 1]);
    near(viewToBase(view, [0, 0, 1]), [0, 0, 1]); // Q (yaw): about the image's up, base +z here
  });

  it("moves the projected gripper as the simulated left camera shows it", () => {
    const view = viewFrame(SIM_LEFT);
    const p: Vec3 = [0.6, -0.15, 0.7];
    const at = project(SIM_LEFT, p)!;
    const step = (v: Vec3) => {
      const d = viewToBase(view, v).map((x) => 0.02 * x) as Vec3;
      const q: Vec3 = [p[0] + d[0], p[1] + d[1], p[2] + d[2]];
      const uv = project(SIM_LEFT, q)!;
      return { du: uv[0] - at[0], dv: uv[1] - at[1], depth: depth(SIM_LEFT, q) - depth(SIM_LEFT, p) };
    };
    const w = step(W); // away from the camera: deeper, and up the image more than sideways
    expect(w.depth).toBeGreaterThan(0.015);
    expect(w.dv).toBeLessThan(-3);
    expect(Math.abs(w.du)).toBeLessThan(Math.abs(w.dv) / 2);
    const s = step([-1, 0, 0]);
    expect(s.depth).toBeLessThan(-0.015);
    const a = step(A); // left in the image, hardly up or down
    expect(a.du).toBeLessThan(-10);
    expect(Math.abs(a.dv)).toBeLessThan(Math.abs(a.du) / 5);
    expect(Math.abs(a.depth)).toBeLessThan(1e-9); // the image's left keeps the depth
    const r = step(R); // up in the image
    expect(r.dv).toBeLessThan(-10);
    expect(Math.abs(r.du)).toBeLessThan(Math.abs(r.dv) / 5);
    // The frame is a rotation: orthonormal and right-handed.
    const [x, y, z] = viewAxes(view);
    near(cross3(x, y), z);
    near([Math.hypot(...x), Math.hypot(...y), Math.hypot(...z)], [1, 1, 1]);
  });

  it("for a camera looking straight down: W goes up the image, R towards the camera", () => {
    const P = lookAt([0.6, 0, 2], [0.6, 0, 0], { up: [1, 0, 0] }); // the image's up is base +x
    const view = viewFrame(P);
    near(viewToBase(view, W), [1, 0, 0]);
    near(viewToBase(view, R), [0, 0, 1]);
    expect(project(P, [0.62, 0, 0.5])![1]).toBeLessThan(project(P, [0.6, 0, 0.5])![1]);
  });

  it("for a camera rolled a quarter turn uses the camera's own axes: W along the optical axis", () => {
    const P = lookAt([3, 0, 0.5], [0, 0, 0.5], { up: [0, 1, 0] }); // image left is vertical
    const view = viewFrame(P);
    const { right, down, forward } = cameraAxes(P);
    near(viewToBase(view, W), forward);
    near(viewToBase(view, A), right.map((v) => -v));
    near(viewToBase(view, R), down.map((v) => -v));
  });
});

describe("the axis marker", () => {
  const TOOL: Mat4 = pose([1, 0, 0, 0, 1, 0, 0, 0, 1], [0, 0, 0.1]);
  const turned: Mat3 = rotvecToMatrix([0, 0, Math.PI / 2]);
  const T = pose(turned, [0.6, -0.15, 0.7]);

  it("shows the active frame's axes: base, the view's, the tool's", () => {
    const view = viewFrame(SIM_LEFT);
    expect(frameAxes("base", T, view, TOOL)).toEqual([1, 0, 0, 0, 1, 0, 0, 0, 1]);
    expect(frameAxes("view", T, view, TOOL)).toBe(view);
    near(frameAxes("tool", T, view, TOOL), turned);
    near(frameAxes("wrist", T, view, TOOL), turned); // this tool is a pure offset
    const px = projectMarker(SIM_LEFT, [0.6, -0.15, 0.7], view);
    expect(px[1]![1]).toBeLessThan(px[0]![1]); // x (away) points up the image,
    expect(px[2]![0]).toBeLessThan(px[0]![0]); // y left,
    expect(px[3]![1]).toBeLessThan(px[0]![1]); // z up
  });

  it("asks for a redraw only when it moved half a pixel or more, or the frame changed", () => {
    let changes = 0;
    const painters: OverlayPainter[] = [];
    const host: OverlayHost = { addOverlay: (p) => void painters.push(p), overlayChanged: () => void (changes += 1) };
    const marker = new AxisMarker([{ name: "left", P: SIM_LEFT }, { name: "right", P: SIM_LEFT }], identity4(), host);
    expect(painters).toEqual([marker]);
    const at = (dx: number) => pose([1, 0, 0, 0, 1, 0, 0, 0, 1], [0.6, -0.15 + dx, 0.7]);
    marker.update("view", null, null);
    const none = changes; // nothing to draw yet
    marker.update("view", at(0), viewFrame(SIM_LEFT));
    expect(changes).toBe(none + 1);
    marker.update("view", at(0.00001), viewFrame(SIM_LEFT)); // ~0.01 px
    expect(changes).toBe(none + 1);
    marker.update("view", at(0.002), viewFrame(SIM_LEFT)); // ~1 px
    expect(changes).toBe(none + 2);
    marker.update("base", at(0.002), viewFrame(SIM_LEFT));
    expect(changes).toBe(none + 3);
    marker.update("base", at(0.002), viewFrame(SIM_LEFT), false); // hidden with the AR ball
    expect(changes).toBe(none + 4);
    expect(marker.pixels).toEqual([null, null]);
  });

  it("paints three coloured axes with their letters, and ⊗ for the view's x (along the line of sight)", () => {
    const marker = new AxisMarker([{ name: "left", P: SIM_LEFT }, { name: "right", P: SIM_LEFT }], identity4(), null);
    marker.update("view", pose([1, 0, 0, 0, 1, 0, 0, 0, 1], [0.6, -0.15, 0.7]), viewFrame(SIM_LEFT));
    const drawn: string[] = [];
    const ctx = new Proxy({} as Record<string, unknown>, {
      get: (target, key: string) => target[key] ?? ((...args: unknown[]) => void drawn.push(`${key}${key === "fillText" ? ` ${String(args[0])}` : ""}`)),
      set: (target, key: string, value) => ((target[key] = value), true),
    }) as unknown as CanvasRenderingContext2D;
    marker.paint(ctx, 1, { width: 1280, height: 720 });
    expect(drawn.filter((d) => d === "stroke")).toHaveLength(5); // 3 lines, ⊗'s circle and its cross
    expect(drawn.filter((d) => d === "arc")).toHaveLength(1);
    expect(drawn.filter((d) => d.startsWith("fillText"))).toEqual(["fillText x", "fillText y", "fillText z"]);
  });
});

// (mulVec3 and fromColumns agree: a view matrix's columns are its axes.)
it("fromColumns puts the axes in the columns", () => {
  near(mulVec3(fromColumns([1, 2, 3], [4, 5, 6], [7, 8, 9]), [0, 1, 0]), [4, 5, 6]);
});
