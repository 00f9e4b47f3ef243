// The local robot model (the thesis's RobotModel, §5.5.1): the server's arm as its joint
// tree (read from /api/v1/robot/model, whichever arm that is), forward kinematics, and
// a predicted tool pose that integrates every command the moment it is sent and is
// corrected when the server reports where the arm actually is.
import type { Schema } from "../api";
import { type Mat3, type Mat4, type Vec3, identity4, inverseRigid, matrixToRotvec, mul3, mul4, pose, position, rotation, rotvecToMatrix, solveLinear } from "./math";

// As GET /api/v1/robot/model gives them (the server's OpenAPI schema).
export type ModelJoint = Schema<"ModelJoint">;
export type RobotModelInfo = Pick<Schema<"RobotModel">, "joints" | "flange" | "tool">;
/** The frame Cartesian increments are expressed in (the server's WorkingFrame). */
export type FrameName = Schema<"WorkingFrame">;

/** Rodrigues: the rotation by `q` (radians) about `axis` (any length but zero), as a
 * 4×4 transform. */
export function axisRotation(axis: readonly number[], q: number): Mat4 {
  const n = Math.hypot(axis[0] ?? 0, axis[1] ?? 0, axis[2] ?? 0);
  if (!(n > 0)) throw new Error(`a joint axis of length ${n}`);
  const [x, y, z] = [(axis[0] ?? 0) / n, (axis[1] ?? 0) / n, (axis[2] ?? 0) / n];
  const c = Math.cos(q);
  const s = Math.sin(q);
  const t = 1 - c;
  const r: Mat3 = [
    t * x * x + c, t * x * y - s * z, t * x * z + s * y,
    t * x * y + s * z, t * y * y + c, t * y * z - s * x,
    t * x * z - s * y, t * y * z + s * x, t * z * z + c,
  ];
  return pose(r, [0, 0, 0]);
}

/** A joint's frame from its parent's: parent · origin · Rot(axis, q). */
export function jointTransform(parent: Mat4, joint: ModelJoint, q: number): Mat4 {
  return mul4(mul4(parent, joint.origin.flat()), axisRotation(joint.axis, q));
}

// The chain of each model (cached: the model read once is used for every frame).
const chains = new WeakMap<RobotModelInfo["joints"], number[]>();

/** The joints that move the tool, base first: `flange.parent` and its ancestors. The
 * others (a gripper's jaw, a branch) do not move the tool. */
export function toolChain(model: RobotModelInfo): number[] {
  const cached = chains.get(model.joints);
  if (cached && cached.at(-1) === model.flange.parent) return cached;
  const chain: number[] = [];
  for (let i = model.flange.parent; i !== -1; i = model.joints[i]!.parent) {
    if (!Number.isInteger(i) || i < -1 || i >= model.joints.length) throw new Error(`the arm model has no joint ${i}`);
    if (chain.length >= model.joints.length) throw new Error("the arm model's joints form a loop");
    chain.push(i);
  }
  chain.reverse();
  chains.set(model.joints, chain);
  return chain;
}

/** Every joint's frame in the base frame at joints `q` (index as `model.joints`). */
export function jointFrames(model: RobotModelInfo, q: readonly number[]): Mat4[] {
  const frames: (Mat4 | undefined)[] = [];
  const frameOf = (i: number, depth: number): Mat4 => {
    const known = frames[i];
    if (known) return known;
    const joint = model.joints[i];
    if (!joint || depth > model.joints.length) throw new Error(`the arm model's joint ${i} is missing or in a loop`);
    const parent = joint.parent === -1 ? identity4() : frameOf(joint.parent, depth + 1);
    return (frames[i] = jointTransform(parent, joint, q[i] ?? 0));
  };
  return model.joints.map((_, i) => frameOf(i, 0));
}

/** Every link frame on the way to the tool: the base (identity), then the frame of each
 * joint of the tool's chain (toolChain), and last the tool (forwardKinematics's pose). */
export function linkFrames(model: RobotModelInfo, q: readonly number[]): Mat4[] {
  const frames: Mat4[] = [identity4()];
  for (const i of toolChain(model)) frames.push(jointTransform(frames[frames.length - 1]!, model.joints[i]!, q[i] ?? 0));
  frames.push(mul4(mul4(frames[frames.length - 1]!, model.flange.origin.flat()), model.tool.flat()));
  return frames;
}

/** The tool pose: frame[flange.parent] · flange.origin · tool. */
export function forwardKinematics(model: RobotModelInfo, q: readonly number[]): Mat4 {
  return linkFrames(model, q).at(-1)!;
}

/** The arm as a chain of points in the base frame: the base, each joint of the tool's
 * chain, the tool (the ghost arm's skeleton; a branch such as a gripper's jaw is not
 * in it). */
export function jointOrigins(model: RobotModelInfo, q: readonly number[]): Vec3[] {
  return linkFrames(model, q).map(position);
}

/** Joints that put the tool at `target`, found from `seed` by damped least squares (a
 * numerical inverse kinematics for any joint tree: the predicted pose moves a little
 * from the reported joints, so a few steps from there converge to the nearby solution).
 * One angle per joint of the model; a joint off the tool's chain (its Jacobian column
 * is zero) keeps its seed. */
export function solveIK(model: RobotModelInfo, target: Mat4, seed: readonly number[], iterations = 20, tolerance = 1e-7): number[] {
  const q = model.joints.map((_, i) => seed[i] ?? 0);
  const moving = new Set(toolChain(model));
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
    // The Jacobian by finite differences (6 × n; zero for a joint that does not move the tool).
    const h = 1e-6;
    const J = e.map(() => q.map(() => 0));
    q.forEach((_, j) => {
      if (!moving.has(j)) return;
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
 * the server's kinematics compute it (`apply_increment`, for any arm). */
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
    private arm: RobotModelInfo,
    private readonly settleMs = 300,
  ) {}

  get model(): RobotModelInfo {
    return this.arm;
  }

  /** Another arm (the server restarted with another model): the prediction starts again
   * from the next reported state. */
  setModel(model: RobotModelInfo): void {
    this.arm = model;
    this.predicted = null;
    this.predictedJoints = null;
    this.jointsStale = false;
  }

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
