import { describe, expect, it } from "vitest";
import { project } from "./ar/projection";
import { forceBand, jointsLine, modelArm, mountedProjection, recordedArms, severalArms } from "./review/arms";

const ACROSS = [
  [-1, 0, 0, 1.2],
  [0, -1, 0, 0],
  [0, 0, 1, 0],
  [0, 0, 0, 1],
]; // the second arm: 1.2 m along x, turned 180°

describe("a multi-arm recording in the review", () => {
  it("reads its arms from /arms, with their models and mounts", () => {
    const arms = recordedArms({
      "/arms": [{ time: 0, arms: [{ name: "left", model: "so101", joint_names: ["a", "b"], mount: ACROSS.map((r, i) => (i === 0 ? [1, 0, 0, 0] : r)) }, { name: "right", model: "so101", joint_names: ["a", "b"], mount: ACROSS }] }],
      "/arms/left/state": [],
      "/arms/right/state": [],
    });
    expect(arms.map((a) => [a.name, a.model, a.stateTopic, a.forceTopic])).toEqual([
      ["left", "so101", "/arms/left/state", "/arms/left/force"],
      ["right", "so101", "/arms/right/state", "/arms/right/force"],
    ]);
    expect(arms[1]?.mount).toEqual(ACROSS);
    expect(arms[0]?.jointNames).toEqual(["a", "b"]);
    expect(severalArms(arms)).toBe(true);
  });
  it("without /arms, names the arms by their channels (at the workcell's origin)", () => {
    const arms = recordedArms({ "/arms/a/state": [], "/arms/b/force": [], "/commands": [] });
    expect(arms.map((a) => a.name)).toEqual(["a", "b"]);
    expect(arms[0]?.mount[0]).toEqual([1, 0, 0, 0]);
  });
  it("a one-arm recording is its one arm on /robot/state and /force, as before", () => {
    const arms = recordedArms({ "/robot/state": [], "/force": [] });
    expect(arms).toHaveLength(1);
    expect(arms[0]?.stateTopic).toBe("/robot/state");
    expect(arms[0]?.forceTopic).toBe("/force");
    expect(severalArms(arms)).toBe(false);
  });
  it("projects an arm's base-frame point through P · its mount", () => {
    const P = [
      [500, 0, 320, 0],
      [0, 500, 240, 0],
      [0, 0, 1, 2],
    ];
    const inBase: [number, number, number] = [0.2, 0.1, 0.3];
    const inScene: [number, number, number] = [1.2 - 0.2, -0.1, 0.3]; // the mount applied
    const a = project(mountedProjection(P, ACROSS), inBase);
    const b = project(P, inScene);
    expect(a?.[0]).toBeCloseTo(b?.[0] ?? NaN, 9);
    expect(a?.[1]).toBeCloseTo(b?.[1] ?? NaN, 9);
  });
  it("asks the server for each arm's model by its name, else its first arm's", () => {
    expect(modelArm("right", ["left", "right"])).toBe("right");
    expect(modelArm("arm", ["left", "right"])).toBe("left");
    expect(modelArm("left", ["arm"])).toBeNull(); // a one-arm server: its model, no ?arm=
  });
  it("says each arm's joints at the cursor, and gives each its band of the force plot", () => {
    expect(jointsLine("left", [0, Math.PI / 2], ["pan", "lift"])).toBe("left: pan 0.0°  lift 90.0°");
    expect(jointsLine("right", [0.1], [])).toBe("right: j1 5.7°");
    expect(jointsLine("right", undefined, [])).toBe("right: —");
    expect(forceBand(1, 2, 320)).toEqual({ top: 160, height: 160 });
    expect(forceBand(0, 1, 160)).toEqual({ top: 0, height: 160 });
  });
});
