// The local robot model (the thesis's RobotModel, §5.5.1): the same DH parameters as
// the server (read from /api/v1/robot/model), forward kinematics, and a predicted
// tool pose that integrates every command the moment it is sent and is corrected
// when the server reports where the arm actually is.
import type { Schema } from "../api";
import { type Mat4, type Vec3, identity4, inverseRigid, mul3, mul4, pose, position, rotation, rotvecToMatrix } from "./math";

// As GET /api/v1/robot/model gives them (the server's OpenAPI schema).
export type DHRow = Schema<"DHRow">;
export type RobotModelInfo = Pick<Schema<"RobotModel">, "dh" | "tool">;
/** The frame Cartesian increments are expressed in (the server's WorkingFrame). */
export type FrameName = Schema<"WorkingFrame">;

export function dhTransform(q: number, row: DHRow): Mat4 {
  const ct = Math.cos(q);
  const st = Math.sin(q);
  const ca = Math.cos(row.alpha);
  const sa = Math.sin(row.alpha);
  return [ct, -st * ca, st * sa, row.a * ct, st, ct * ca, -ct * sa, row.a * st, 0, sa, ca, row.d, 0, 0, 0, 1];
}

export function forwardKinematics(model: RobotModelInfo, q: number[]): Mat4 {
  let t = identity4();
  model.dh.forEach((row, i) => {
    t = mul4(t, dhTransform(q[i] ?? 0, row));
  });
  return mul4(t, model.tool.flat());
}

/** The tool pose after the increment (dX, rotation vector) expressed in `frame`, as
 * the server's `Puma560Kinematics.apply_increment` computes it. */
export function applyIncrement(model: RobotModelInfo, t: Mat4, dX: Vec3, rotvec: Vec3, frame: FrameName): Mat4 {
  const dM = rotvecToMatrix(rotvec);
  const delta = pose(dM, dX);
  if (frame === "base") {
    const p = position(t);
    return pose(mul3(dM, rotation(t)), [p[0] + dX[0], p[1] + dX[1], p[2] + dX[2]]);
  }
  if (frame === "tool") return mul4(t, delta);
  const tool = model.tool.flat();
  return mul4(mul4(mul4(t, inverseRigid(tool)), delta), tool);
}

export class PredictedArm {
  private predicted: Mat4 | null = null;
  private lastCommandAt = -Infinity;

  constructor(
    readonly model: RobotModelInfo,
    private readonly settleMs = 300,
  ) {}

  get pose(): Mat4 | null {
    return this.predicted;
  }

  /** A state from the server: while no command has been sent for a moment and the arm
   * is at rest, the prediction snaps to what the robot reports. */
  report(joints: number[], moving: boolean, now: number): void {
    if (this.predicted === null || (!moving && now - this.lastCommandAt > this.settleMs)) {
      this.predicted = forwardKinematics(this.model, joints);
    }
  }

  /** A Cartesian increment that was just sent. */
  commandCartesian(dX: Vec3, rotvec: Vec3, frame: FrameName, now: number): void {
    if (this.predicted === null) return;
    this.predicted = applyIncrement(this.model, this.predicted, dX, rotvec, frame);
    this.lastCommandAt = now;
  }
}
