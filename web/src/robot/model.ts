// The local robot model (the thesis's RobotModel, §5.5.1): the same DH parameters as
// the server (read from /api/v1/robot/model), forward kinematics, and a predicted
// tool pose that integrates every command the moment it is sent and is corrected
// when the server reports where the arm actually is.
import type { Schema } from "../api";
import { type Mat4, type Vec3, identity4, inverseRigid, matrixToRotvec, mul3, mul4, pose, position, rotation, rotvecToMatrix, solveLinear } from "./math";

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

/** Every link frame by forward kinematics: the base (identity), then each joint's DH
 * frame in turn, and last the tool (forwardKinematics's pose). */
export function linkFrames(model: RobotModelInfo, q: number[]): Mat4[] {
  const frames: Mat4[] = [identity4()];
  model.dh.forEach((row, i) => frames.push(mul4(frames[frames.length - 1]!, dhTransform(q[i] ?? 0, row))));
  frames.push(mul4(frames[frames.length - 1]!, model.tool.flat()));
  return frames;
}

/** The arm as a chain of points in the base frame: the origin of every link frame, base
 * to tool (the ghost arm's skeleton). */
export function jointOrigins(model: RobotModelInfo, q: number[]): Vec3[] {
  return linkFrames(model, q).map(position);
}

/** Joints that put the tool at `target`, found from `seed` by damped least squares (a
 * numerical inverse kinematics for any DH chain: the predicted pose moves a little
 * from the reported joints, so a few steps from there converge to the nearby solution). */
export function solveIK(model: RobotModelInfo, target: Mat4, seed: number[], iterations = 20, tolerance = 1e-7): number[] {
  const q = model.dh.map((_, i) => seed[i] ?? 0);
  const error = (t: Mat4): number[] => {
    const p = position(t);
    const goal = position(target);
    const rt = rotation(t);
    const transposed = [rt[0]!, rt[3]!, rt[6]!, rt[1]!, rt[4]!, rt[7]!, rt[2]!, rt[5]!, rt[8]!];
    return [goal[0] - p[0], goal[1] - p[1], goal[2] - p[2], ...matrixToRotvec(mul3(rotation(target), transposed))];
  };
  const lambda2 = 1e-4; // damping: bounded steps near a singularity
  for (let it = 0; it < iterations; it++) {
    const e = error(forwardKinematics(model, q));
    if (Math.hypot(...e) < tolerance) break;
    // The Jacobian by finite differences (6 × n).
    const h = 1e-6;
    const J = e.map(() => q.map(() => 0));
    q.forEach((_, j) => {
      const dq = q.slice();
      dq[j]! += h;
      const ej = error(forwardKinematics(model, dq));
      ej.forEach((v, i) => (J[i]![j] = (e[i]! - v) / h));
    });
    // dq = Jᵀ (J Jᵀ + λ² I)⁻¹ e
    const JJt = J.map((ri, i) => J.map((rk, k) => ri.reduce((s, v, j) => s + v * rk[j]!, 0) + (i === k ? lambda2 : 0)));
    const y = solveLinear(JJt, e);
    if (!y) break;
    q.forEach((_, j) => (q[j]! += J.reduce((s, row, i) => s + row[j]! * y[i]!, 0)));
  }
  return q;
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
  private predictedJoints: number[] | null = null;
  private jointsStale = false;

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
      this.predictedJoints = joints.slice();
      this.jointsStale = false;
    }
  }

  /** A Cartesian increment that was just sent. */
  commandCartesian(dX: Vec3, rotvec: Vec3, frame: FrameName, now: number): void {
    if (this.predicted === null) return;
    this.predicted = applyIncrement(this.model, this.predicted, dX, rotvec, frame);
    this.lastCommandAt = now;
    this.jointsStale = true;
  }

  /** The joints of the predicted pose: the reported ones until a command moves the
   * prediction, then solved from the last ones (at most once per change). */
  get joints(): number[] | null {
    if (this.jointsStale && this.predicted && this.predictedJoints) {
      this.predictedJoints = solveIK(this.model, this.predicted, this.predictedJoints);
      this.jointsStale = false;
    }
    return this.predictedJoints;
  }
}
