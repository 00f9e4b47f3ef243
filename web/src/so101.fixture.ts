// The SO-101 as GET /api/v1/robot/model describes it (its joint tree, no tool), for the
// unit tests of the page's local model. Generated from the server's model
// (telerobot.drivers.robot.models.load_model("so101").chain()). Joint 6, the gripper, is a
// branch: its parent is the wrist roll, the flange's too, so it does not move the tool.
import type { Schema } from "./api";

export const SO101: Schema<"RobotModel"> = {
  model: "so101",
  name: "SO-101",
  dof: 6,
  joint_names: ["shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper"],
  joints: [
    { name: "shoulder_pan", parent: -1, origin: [[-1.0, -0.0, -0.0, 0.0388353], [-0.0, 1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0624], [0.0, 0.0, 0.0, 1.0]], axis: [0.0, 0.0, 1.0] },
    { name: "shoulder_lift", parent: 0, origin: [[0.0, 1.0, -0.0, -0.0303992], [0.0, 0.0, 1.0, -0.0182778], [1.0, -0.0, 0.0, -0.0542], [0.0, 0.0, 0.0, 1.0]], axis: [0.0, 0.0, 1.0] },
    { name: "elbow_flex", parent: 1, origin: [[0.0, -1.0, 0.0, -0.11257], [1.0, 0.0, 0.0, -0.028], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]], axis: [0.0, 0.0, 1.0] },
    { name: "wrist_flex", parent: 2, origin: [[0.0, 1.0, 0.0, -0.1349], [-1.0, 0.0, 0.0, 0.0052], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]], axis: [0.0, 0.0, 1.0] },
    { name: "wrist_roll", parent: 3, origin: [[-0.998815387098, -0.04866027636, 0.0, 0.0], [0.0, -0.0, 1.0, -0.0611], [-0.04866027636, 0.998815387098, 0.0, 0.0181], [0.0, 0.0, 0.0, 1.0]], axis: [0.0, 0.0, 1.0] },
    { name: "gripper", parent: 4, origin: [[1.0, 0.0, 0.0, 0.0202], [0.0, 0.0, -1.0, 0.0188], [0.0, 1.0, 0.0, -0.0234], [0.0, 0.0, 0.0, 1.0]], axis: [0.0, 0.0, 1.0] },
  ],
  flange: { parent: 4, origin: [[-1.0, 0.0, 0.0, -0.0079], [0.0, 1.0, 0.0, -0.000218121], [-0.0, 0.0, -1.0, -0.0981274], [0.0, 0.0, 0.0, 1.0]] },
  joint_limits_deg: [[-109.99987525598623, 109.99987525598623], [-100.00004285756798, 100.00004285756798], [-96.82986737710912, 96.82986737710912], [-94.99984017946129, 94.99984017946129], [-157.21102461697095, 162.78934171036462], [-10.000004285756797, 100.00004285756798]],
  named_poses: { zero: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0], ready: [0.0, -0.6, 0.6, 1.2, 0.0, 0.5], rest: [0.0, -1.74, 1.66, 0.75, 0.0, 0.0] },
  tool: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
  home_pose: "ready",
  urdf: "/api/v1/robot/model.urdf",
};
