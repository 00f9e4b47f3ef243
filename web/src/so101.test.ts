// The local model on any arm the server describes: the SO-101 (whose gripper joint is a
// branch off the wrist roll, not on the way to the tool), and a small tree whose axes
// are not all z and whose joints are not listed as one chain.
import { describe, expect, it } from "vitest";
import { SO101 } from "./so101.fixture";
import { GhostArm } from "./ar/ghost";
import { type Mat4, position, rotation } from "./robot/math";
import { PredictedArm, type RobotModelInfo, forwardKinematics, jointFrames, jointOrigins, linkFrames, solveIK, toolChain } from "./robot/model";
import { jointTable } from "./ui/readouts";

const near = (a: readonly number[], b: readonly number[], tol = 1e-9) => {
  expect(a.length).toBe(b.length);
  a.forEach((v, i) => expect(Math.abs(v - (b[i] ?? NaN))).toBeLessThan(tol));
};
const translation = (x: number, y: number, z: number) => [
  [1, 0, 0, x],
  [0, 1, 0, y],
  [0, 0, 1, z],
  [0, 0, 0, 1],
];

// The server's figures (telerobot.drivers.robot.models.load_model("so101").kinematics(): fk(q)
// and link_origins(q), Pinocchio on the URDF), pasted.
const ZERO = [0, 0, 0, 0, 0, 0];
const TOOL_AT_ZERO: Mat4 = [
  2.3489894930786288e-17, 2.15755121277023e-16, 1.0, 0.39136190000000004,
  0.04866027636027259, 0.9988153870984076, -2.1656139264183496e-16, -1.1246427803199326e-5,
  -0.9988153870984076, 0.04866027636027259, 1.1297304212403243e-17, 0.22646874461378258,
  0, 0, 0, 1,
];
// base, shoulder_pan, shoulder_lift, elbow_flex, wrist_flex, wrist_roll, gripper, tool
const ORIGINS_AT_ZERO = [
  [0.0, 0.0, 0.0],
  [0.0388353, 0.0, 0.0624],
  [0.0692345, -0.018277800000000004, 0.1166],
  [0.09723450000000003, -0.01827780000000002, 0.22916999999999998],
  [0.23213450000000002, -0.018277800000000035, 0.23437],
  [0.2932345, -0.00017780000000004043, 0.23437],
  [0.31663450000000004, 0.017616991694972512, 0.2554608840149609],
  [0.39136190000000004, -1.1246427803199326e-5, 0.22646874461378258],
];
const Q = [0.3, -0.5, 0.7, 0.9, -1.1, 0.8];
const TOOL_AT_Q: Mat4 = [
  -0.07923274526413604, 0.8977423241306877, 0.43333692612370295, 0.23521082786223935,
  0.9793812178789449, 0.1511419208425204, -0.13404681954446881, -0.053482235997876645,
  -0.18583487870650822, 0.4137811489525161, -0.8912073600614354, 0.06364625685021935,
  0, 0, 0, 1,
];
const GRIPPER_AT_Q = [0.22212849833808382, -0.0681114425786922, 0.14333516577842512];

describe("the SO-101 (a gripper joint off the tool's chain)", () => {
  it("puts the tool where the server does", () => {
    near(forwardKinematics(SO101, ZERO), TOOL_AT_ZERO);
    near(position(forwardKinematics(SO101, ZERO)), [0.3914, 0, 0.2265], 1e-4);
    near(forwardKinematics(SO101, Q), TOOL_AT_Q);
    near(linkFrames(SO101, Q).at(-1)!, TOOL_AT_Q);
  });

  it("does not move the tool with the gripper", () => {
    expect(toolChain(SO101)).toEqual([0, 1, 2, 3, 4]);
    const open = Q.slice();
    open[5] = -0.2;
    near(forwardKinematics(SO101, open), TOOL_AT_Q);
    // …whose own frame hangs off the wrist roll, as the server has it.
    near(position(jointFrames(SO101, Q)[5]!), GRIPPER_AT_Q);
    near(position(jointFrames(SO101, ZERO)[5]!), ORIGINS_AT_ZERO[6]!);
  });

  it("draws the ghost from the base along the tool's chain, not through the gripper", () => {
    const pts = jointOrigins(SO101, ZERO);
    expect(pts).toHaveLength(7); // base, the five joints that move the tool, the tool
    const expected = ORIGINS_AT_ZERO.filter((_, i) => i !== 6);
    pts.forEach((p, i) => near(p, expected[i]!));
    // The gripper's angle changes nothing in it.
    const skeleton = jointOrigins(SO101, Q);
    near(jointOrigins(SO101, [...Q.slice(0, 5), 0]).flat(), skeleton.flat(), 1e-15);
    expect(skeleton.some((p) => Math.hypot(p[0] - GRIPPER_AT_Q[0]!, p[1] - GRIPPER_AT_Q[1]!, p[2] - GRIPPER_AT_Q[2]!) < 1e-6)).toBe(false);
    const side = [
      [100, 0, 0, 320],
      [0, 0, -100, 240],
      [0, 0, 0, 1],
    ];
    const ghost = new GhostArm(SO101, [
      { name: "left", P: side },
      { name: "right", P: side },
    ]);
    expect(ghost.update(Q)).toBe(true);
    expect(ghost.pixels[0]).toHaveLength(7);
  });

  it("solves the joints of a pose and keeps the gripper at its seed", () => {
    const goal = [0.1, -0.4, 0.5, 1.0, -0.9, 0.9];
    const seed = [0.05, -0.45, 0.55, 1.05, -0.95, 0.3];
    const q = solveIK(SO101, forwardKinematics(SO101, goal), seed);
    expect(q).toHaveLength(6);
    expect(q[5]).toBe(0.3); // off the tool's chain: a zero Jacobian column, never moved
    near(q.slice(0, 5), goal.slice(0, 5), 1e-6);
    near(forwardKinematics(SO101, q), forwardKinematics(SO101, goal), 1e-7);
  });

  it("predicts on the SO-101 too: a move along the tool's own z is within its five joints", () => {
    const arm = new PredictedArm(SO101);
    const ready = SO101.named_poses["ready"]!;
    arm.report(ready, false, 0);
    arm.commandCartesian([0, 0, 0.01], [0, 0, 0], "tool", 10);
    const q = arm.joints!;
    expect(q[5]).toBe(ready[5]);
    near(forwardKinematics(SO101, q), arm.pose!, 1e-6);
  });

  it("labels the joints table with the arm's joint names", () => {
    const html = jointTable(SO101.joint_names, [0, Math.PI / 2, -Math.PI / 4, 0, 0, 0.5]);
    expect(html).toBe(
      "<tr><th>shoulder_pan</th><td>0.0°</td></tr><tr><th>shoulder_lift</th><td>90.0°</td></tr>" +
        "<tr><th>elbow_flex</th><td>-45.0°</td></tr><tr><th>wrist_flex</th><td>0.0°</td></tr>" +
        "<tr><th>wrist_roll</th><td>0.0°</td></tr><tr><th>gripper</th><td>28.6°</td></tr>",
    );
    expect(jointTable(["a<b", "c"], [0])).toBe("<tr><th>a&lt;b</th><td>0.0°</td></tr><tr><th>c</th><td>—</td></tr>");
  });
});

// A tree worked out by hand: joint 0 about z on a 1 m post; joint 1 a branch (about x,
// 5 m along joint 0's x); joint 2 about y, 1 m along joint 0's x (its parent is joint 0,
// not joint 1 before it); joint 3 about −z (the axis [0, 0, −2]: any length), 1 m up
// joint 2's z; the flange 1 m along joint 3's x.
const TREE: RobotModelInfo = {
  joints: [
    { name: "a", parent: -1, origin: translation(0, 0, 1), axis: [0, 0, 1] },
    { name: "branch", parent: 0, origin: translation(5, 0, 0), axis: [1, 0, 0] },
    { name: "b", parent: 0, origin: translation(1, 0, 0), axis: [0, 1, 0] },
    { name: "c", parent: 2, origin: translation(0, 0, 1), axis: [0, 0, -2] },
  ],
  flange: { parent: 3, origin: translation(1, 0, 0) },
  tool: translation(0, 0, 0),
};
const TREE_Q = [Math.PI / 2, 0.7, Math.PI / 2, Math.PI / 2];

describe("a joint tree: each joint's parent and axis", () => {
  it("follows each joint's parent and turns about its axis", () => {
    // Rz(90°) at the post's top; Ry(90°) 1 m along the turned x (0, 1, 1); then 1 m up
    // joint b's z, which Ry(90°) laid along x and Rz(90°) turned to y: (0, 2, 1); then
    // Rz(−90°) turns c's x back to the base's x: the tool at (1, 2, 1), turned Rx(−90°).
    near(jointOrigins(TREE, TREE_Q).flat(), [0, 0, 0, 0, 0, 1, 0, 1, 1, 0, 2, 1, 1, 2, 1], 1e-12);
    const T = forwardKinematics(TREE, TREE_Q);
    near(position(T), [1, 2, 1], 1e-12);
    near(rotation(T), [1, 0, 0, 0, 0, 1, 0, -1, 0], 1e-12);
    // (Turning c about +z instead would put the tool at (−1, 2, 1); every axis taken as z
    // would put c at (0, 1, 2); b under the branch joint would put it past x = 5.)
  });

  it("computes the branch but leaves it out of the tool's chain", () => {
    expect(toolChain(TREE)).toEqual([0, 2, 3]);
    near(position(jointFrames(TREE, TREE_Q)[1]!), [0, 5, 1], 1e-12);
    expect(forwardKinematics(TREE, [TREE_Q[0]!, -1.3, ...TREE_Q.slice(2)])).toEqual(forwardKinematics(TREE, TREE_Q));
    const q = solveIK(TREE, forwardKinematics(TREE, [1.4, 0, 1.5, 1.6]), [1.5, 0.7, 1.6, 1.5]);
    expect(q[1]).toBe(0.7);
    near(forwardKinematics(TREE, q), forwardKinematics(TREE, [1.4, 0, 1.5, 1.6]), 1e-7);
  });

  it("refuses a parent that is not there, and a loop", () => {
    expect(() => forwardKinematics({ ...TREE, flange: { parent: 7, origin: translation(0, 0, 0) } }, TREE_Q)).toThrow(/no joint 7/);
    const loop = TREE.joints.map((j, i) => (i === 0 ? { ...j, parent: 3 } : j));
    expect(() => forwardKinematics({ ...TREE, joints: loop }, TREE_Q)).toThrow(/loop/);
    expect(() => jointFrames({ ...TREE, joints: loop }, TREE_Q)).toThrow(/loop/);
  });
});
