// A tracked hand (WebXR Hand Input) as the 6-DoF master: a pinch (thumb tip to index
// tip) is the clutch, and the wrist's pose is the master's pose, read into the same
// reading a controller gives so that one XRMaster (scaling, clutch, jump guard) serves both.
import type { Vec3 } from "../robot/math";
import type { Quat, XRControllerReading } from "./xr";

/** A pinch closes below this thumb-to-index distance and opens above PINCH_OPEN_M:
 * between the two it stays as it was, so a hand at the threshold does not flicker. */
export const PINCH_CLOSE_M = 0.02;
export const PINCH_OPEN_M = 0.04;

/** Pinch detection with hysteresis. */
export class Pinch {
  closed = false;

  /** Feed the thumb-to-index distance (null: the hand is not tracked, which opens it). */
  update(distance: number | null): boolean {
    if (distance === null || !Number.isFinite(distance)) this.closed = false;
    else this.closed = this.closed ? distance < PINCH_OPEN_M : distance < PINCH_CLOSE_M;
    return this.closed;
  }
}

/** What the master needs of a hand in one frame (XR space, metres); null joints: not tracked. */
export interface HandJoints {
  wrist: { position: Vec3; orientation: Quat; emulated: boolean } | null;
  thumbTip: Vec3 | null;
  indexTip: Vec3 | null;
}

/** The wrist and both tips are tracked, not estimated. */
export function isTracked(j: HandJoints): boolean {
  return !!j.wrist && !j.wrist.emulated && !!j.thumbTip && !!j.indexTip;
}

/** The hand as a master reading: pinched (with hysteresis, in `pinch`) and tracked is
 * the clutch held; the wrist is the pose. An untracked hand opens its pinch. */
export function handReading(joints: HandJoints, pinch: Pinch): XRControllerReading {
  const { wrist, thumbTip, indexTip } = joints;
  const distance = isTracked(joints) && thumbTip && indexTip ? Math.hypot(thumbTip[0] - indexTip[0], thumbTip[1] - indexTip[1], thumbTip[2] - indexTip[2]) : null;
  const gripping = pinch.update(distance);
  return { gripping, position: wrist?.position ?? [0, 0, 0], orientation: wrist?.orientation ?? [0, 0, 0, 1], gamepad: null };
}

/** Read a hand's joints from an XR frame (poses in `space`). */
export function readHandJoints(frame: XRFrame, hand: XRHand, space: XRReferenceSpace): HandJoints {
  const jointPose = (name: XRHandJoint): XRJointPose | null | undefined => {
    const joint = hand.get(name);
    return joint ? frame.getJointPose?.(joint, space) : null;
  };
  const at = (p: XRJointPose | null | undefined): Vec3 | null => (p ? [p.transform.position.x, p.transform.position.y, p.transform.position.z] : null);
  const w = jointPose("wrist");
  const o = w?.transform.orientation;
  return {
    wrist: w && o ? { position: at(w)!, orientation: [o.x, o.y, o.z, o.w], emulated: w.emulatedPosition } : null,
    thumbTip: at(jointPose("thumb-tip")),
    indexTip: at(jointPose("index-finger-tip")),
  };
}
