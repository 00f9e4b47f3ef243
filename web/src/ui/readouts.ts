// The Robot and Force panels' figures, as plain functions of the numbers: joint
// angles in degrees under the arm's joint names, the tool's orientation as
// roll/pitch/yaw, and each force axis's row (name, value with its unit, bar length
// against the limit).
// The orientation reads as a rotation vector first: the arm's home pose (qn) sits at
// pitch 90°, where roll and yaw are not defined apart.

export const FORCE_AXES = ["Fx", "Fy", "Fz", "Tx", "Ty", "Tz"] as const;

const DEG = 180 / Math.PI;

export const degrees = (rad: number): number => rad * DEG;
/** One decimal, and never "-0.0". */
const oneDecimal = (v: number): string => (Math.abs(v) < 0.05 ? 0 : v).toFixed(1);

/** Roll, pitch, yaw (radians) of a rotation matrix R = Rz(yaw)·Ry(pitch)·Rx(roll)
 * (fixed X-Y-Z axes, as the ROS and URDF "rpy"). At pitch ±90° roll is taken as 0. */
export function rpyFromMatrix(r: readonly (readonly number[])[]): [number, number, number] {
  const at = (i: number, j: number) => r[i]?.[j] ?? 0;
  const sinPitch = Math.max(-1, Math.min(1, -at(2, 0)));
  const pitch = Math.asin(sinPitch);
  if (Math.abs(sinPitch) > 1 - 1e-9) {
    // gimbal lock: only roll ∓ yaw is defined
    return [0, pitch, Math.atan2(-at(0, 1), at(1, 1))];
  }
  return [Math.atan2(at(2, 1), at(2, 2)), pitch, Math.atan2(at(1, 0), at(0, 0))];
}

/** The rotation vector (axis × angle, radians) of a rotation matrix: smooth
 * everywhere but at 180°, where either sign of the axis is right. */
export function rotvecFromMatrix(r: readonly (readonly number[])[]): [number, number, number] {
  const at = (i: number, j: number) => r[i]?.[j] ?? 0;
  const angle = Math.acos(Math.max(-1, Math.min(1, (at(0, 0) + at(1, 1) + at(2, 2) - 1) / 2)));
  const v: [number, number, number] = [at(2, 1) - at(1, 2), at(0, 2) - at(2, 0), at(1, 0) - at(0, 1)]; // 2 sin(angle) axis
  if (angle < 1e-6) return [v[0] / 2, v[1] / 2, v[2] / 2];
  if (Math.PI - angle > 1e-3) {
    const k = angle / (2 * Math.sin(angle));
    return [v[0] * k, v[1] * k, v[2] * k];
  }
  // Near 180°: the axis from (R + I)/2 ≈ a aᵀ, its largest diagonal first.
  const i = [0, 1, 2].reduce((best, j) => (at(j, j) > at(best, best) ? j : best), 0);
  const ai = Math.sqrt(Math.max(0, (at(i, i) + 1) / 2));
  const axis = [0, 1, 2].map((j) => (j === i ? ai : (at(i, j) + at(j, i)) / (4 * ai)));
  const sign = axis[0]! * v[0] + axis[1]! * v[1] + axis[2]! * v[2] < 0 ? -1 : 1;
  return axis.map((a) => a * sign * angle) as [number, number, number];
}

/** "rotation vector 0.0, 90.0, 0.0° · roll 0.0° pitch 90.0° yaw 0.0°" */
export function orientationText(r: readonly (readonly number[])[]): string {
  const rv = rotvecFromMatrix(r).map((a) => oneDecimal(degrees(a)));
  const [roll, pitch, yaw] = rpyFromMatrix(r).map((a) => oneDecimal(degrees(a)));
  return `rotation vector ${rv.join(", ")}° · roll ${roll}° pitch ${pitch}° yaw ${yaw}°`;
}

export interface ForceRow {
  axis: string;
  /** "12.34 N", "0.56 N·m" */
  text: string;
  /** Bar length, 0…100 (% of the limit). */
  percent: number;
  /** The force's magnitude is over the limit on this axis. */
  over: boolean;
}

/** One row per axis: forces against the force limit (N); torques are shown against
 * the same number in N·m (the server states no torque limit). */
export function forceRows(values: readonly number[], limitN: number): ForceRow[] {
  return FORCE_AXES.map((axis, i) => {
    const v = values[i] ?? 0;
    const unit = i < 3 ? "N" : "N·m";
    const share = limitN > 0 ? Math.abs(v) / limitN : 0;
    return { axis, text: `${(Math.abs(v) < 0.005 ? 0 : v).toFixed(2)} ${unit}`, percent: Math.min(100, share * 100), over: i < 3 && share >= 1 };
  });
}

const escapeHtml = (text: string): string =>
  text.replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c] ?? c);

/** The joints table's rows (HTML): one per joint, its name (GET /robot/model's
 * joint_names) and its angle in degrees, one decimal ("—" for one the state does not
 * have). A row each, not a column each: six columns of names such as "shoulder_lift"
 * do not fit the panel's width (the SO-101's were cut after the third). */
export function jointTable(names: readonly string[], joints: readonly number[]): string {
  const angle = (q: number | undefined) => (q === undefined || !Number.isFinite(q) ? "—" : `${degrees(q).toFixed(1)}°`);
  return names.map((n, i) => `<tr><th>${escapeHtml(n)}</th><td>${angle(joints[i])}</td></tr>`).join("");
}

/** The speed setting as shown beside its slider: "0.50". */
export const speedText = (value: number): string => (Number.isFinite(value) ? value.toFixed(2) : "—");
