// The PUMA 560 as GET /api/v1/robot/model describes it (its joint tree, a 0.1 m tool),
// for the unit tests of the page's local model. Generated from the server's model
// (telerobot.drivers.robot.models.load_model("puma560").chain()): the tree is its DH table.
import type { Schema } from "./api";

export const PUMA: Schema<"RobotModel"> = {
  model: "puma560",
  name: "PUMA 560",
  dof: 6,
  joint_names: ["joint1", "joint2", "joint3", "joint4", "joint5", "joint6"],
  joints: [
    { name: "joint1", parent: -1, origin: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]], axis: [0.0, 0.0, 1.0] },
    { name: "joint2", parent: 0, origin: [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.67183], [0.0, 0.0, 0.0, 1.0]], axis: [0.0, 0.0, 1.0] },
    { name: "joint3", parent: 1, origin: [[1.0, 0.0, 0.0, 0.4318], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]], axis: [0.0, 0.0, 1.0] },
    { name: "joint4", parent: 2, origin: [[1.0, 0.0, 0.0, 0.0203], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.15005], [0.0, 0.0, 0.0, 1.0]], axis: [0.0, 0.0, 1.0] },
    { name: "joint5", parent: 3, origin: [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.4318], [0.0, 0.0, 0.0, 1.0]], axis: [0.0, 0.0, 1.0] },
    { name: "joint6", parent: 4, origin: [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]], axis: [0.0, 0.0, 1.0] },
  ],
  flange: { parent: 5, origin: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]] },
  joint_limits_deg: [[-160.0, 160.0], [-45.0, 225.0], [-225.0, 45.0], [-110.0, 170.0], [-100.0, 100.0], [-266.0, 266.0]],
  named_poses: { qz: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0], qr: [0.0, 1.5707963267948966, -1.5707963267948966, 0.0, 0.0, 0.0], qs: [0.0, 0.0, -1.5707963267948966, 0.0, 0.0, 0.0], qn: [0.0, 0.7853981633974483, -3.141592653589793, 0.0, 0.7853981633974483, 0.0] },
  tool: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.1], [0.0, 0.0, 0.0, 1.0]],
  home_pose: "qn",
  urdf: "/api/v1/robot/model.urdf",
};
