// The PUMA 560 as GET /api/v1/robot/model describes it (DH rows, a 0.1 m tool), for the
// unit tests of the page's local model.
import type { RobotModelInfo } from "./robot/model";

export const PUMA: RobotModelInfo = {
  dh: [
    { d: 0.67183, a: 0, alpha: Math.PI / 2 },
    { d: 0, a: 0.4318, alpha: 0 },
    { d: 0.15005, a: 0.0203, alpha: -Math.PI / 2 },
    { d: 0.4318, a: 0, alpha: Math.PI / 2 },
    { d: 0, a: 0, alpha: -Math.PI / 2 },
    { d: 0, a: 0, alpha: 0 },
  ],
  tool: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.1], [0, 0, 0, 1]],
};
