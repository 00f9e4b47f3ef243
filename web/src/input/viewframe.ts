// The view frame: keys and sticks move the gripper as the operator sees it in the
// left camera's image, whatever the camera's place. Computed from the camera's 3×4
// projection P (the calibration's, or the simulation's ground truth), and turned into
// base-frame increments here, on the page: the server only knows base/wrist/tool.
//
// Its axes follow the command's convention (the base frame's: x forward, y left, z up):
//   x: into the scene, away from the camera (W/S, stick forward)
//   y: left in the image (A/D)
//   z: up in the image (R/F)
// y is exactly the image's left (−x of the camera); z is as close to gravity's up
// (base +z) as is perpendicular to it; x = y × z is the rest, horizontal for a camera
// with no roll. So W is "into the scene" along the table, not the optical axis itself:
// a camera looking down on the work at 25° would send W down into the table along its
// optical axis, and the ball would barely move in the picture (only its size and
// disparity change); along the table it climbs the image as things further away do.
// A camera looking straight down keeps the same rule (W: up the image, across the
// table); only a camera rolled near 90° (the image's left near vertical) has no such
// frame, and there the camera's own axes are used (W exactly along the optical axis).
import type { Projection } from "../ar/projection";
import { type Mat3, type Vec3, column3, cross3, dot3, fromColumns, mulVec3, normalize3 } from "../robot/math";

/** The camera's axes in the base frame (rows of R in P = K[R|t]): right and down in
 * the image, and the optical axis (forward). A Gram–Schmidt RQ of P's left 3×3: its
 * third row is the optical axis times a scale, its second the image's down axis plus
 * some of the optical axis (K is upper triangular). P's overall sign is fixed so that
 * points in front of the camera have w > 0. */
export function cameraAxes(P: Projection): { right: Vec3; down: Vec3; forward: Vec3 } {
  const row = (i: number): Vec3 => [P[i]?.[0] ?? 0, P[i]?.[1] ?? 0, P[i]?.[2] ?? 0];
  const [m1, m2, m3] = [row(0), row(1), row(2)];
  const sign = Math.sign(dot3(m1, cross3(m2, m3))) || 1; // det of the 3×3
  const forward = normalize3(m3.map((v) => v * sign) as Vec3);
  const m2s = m2.map((v) => v * sign) as Vec3;
  const k = dot3(m2s, forward);
  const down = normalize3([m2s[0] - k * forward[0], m2s[1] - k * forward[1], m2s[2] - k * forward[2]]);
  return { right: cross3(down, forward), down, forward };
}

const UP: Vec3 = [0, 0, 1];
/** Below this, the image's left is too near vertical for an up perpendicular to it. */
const MIN_UP = 0.3;

/** The view frame's rotation in the base frame (columns: its x away, y left, z up). */
export function viewFrame(P: Projection): Mat3 {
  const { right, down, forward } = cameraAxes(P);
  const left: Vec3 = [-right[0], -right[1], -right[2]];
  const k = dot3(UP, left);
  const upPerp: Vec3 = [UP[0] - k * left[0], UP[1] - k * left[1], UP[2] - k * left[2]];
  if (Math.hypot(...upPerp) < MIN_UP) return fromColumns(forward, left, [-down[0], -down[1], -down[2]]);
  const up = normalize3(upPerp);
  return fromColumns(cross3(left, up), left, up);
}

/** A view-frame vector (a translation or a rotation vector) in the base frame. */
export function viewToBase(view: Mat3, v: Vec3): Vec3 {
  return mulVec3(view, v);
}

/** The view frame's axes in the base frame: x (away), y (left), z (up). */
export function viewAxes(view: Mat3): [Vec3, Vec3, Vec3] {
  return [column3(view, 0), column3(view, 1), column3(view, 2)];
}
