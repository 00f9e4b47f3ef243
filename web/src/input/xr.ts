// A WebXR controller or a tracked hand as a 6-DoF master: while the grip is held (a
// hand: pinched), the motion since the last frame moves the gripper (a clutch: releasing
// and gripping again re-anchors). Jumps in tracking are ignored rather than sent.
import type { Vec3 } from "../robot/math";
import { Pinch, handReading, isTracked, readHandJoints } from "./hands";

export type Quat = [number, number, number, number]; // x y z w

/** The driving controller (or hand) in one XR frame. */
export interface XRControllerReading {
  /** The grip (squeeze; a hand: the pinch) is held and the position is tracked, not estimated. */
  gripping: boolean;
  position: Vec3; // XR space, metres
  orientation: Quat;
  /** The controller's gamepad (its haptics); null for a hand. */
  gamepad: Gamepad | null;
}

/** The right-hand controller (else the first with a grip and buttons), or null. Hands
 * (which may carry a gamepad for their pinch) are not controllers. */
export function readController(frame: XRFrame, space: XRReferenceSpace): XRControllerReading | null {
  const sources = Array.from(frame.session.inputSources).filter(isController);
  const source = sources.find((s) => s.handedness === "right") ?? sources[0];
  return source ? controllerReading(frame, space, source) : null;
}

/** A controller: a grip and buttons, and no hand (a hand may carry a gamepad for its pinch). */
const isController = (s: XRInputSource): boolean => !!s.gripSpace && !!s.gamepad && !s.hand;

/** One controller's reading (null: it has no grip or no gamepad). */
function controllerReading(frame: XRFrame, space: XRReferenceSpace, source: XRInputSource): XRControllerReading | null {
  if (!source.gripSpace || !source.gamepad) return null;
  const pose = frame.getPose(source.gripSpace, space);
  // xr-standard mapping: button 1 is the squeeze. An emulated (lost) position is no grip.
  const gripping = (source.gamepad.buttons[1]?.pressed ?? false) && !!pose && !pose.emulatedPosition;
  const p = pose?.transform.position ?? { x: 0, y: 0, z: 0 };
  const o = pose?.transform.orientation ?? { x: 0, y: 0, z: 0, w: 1 };
  return { gripping, position: [p.x, p.y, p.z], orientation: [o.x, o.y, o.z, o.w], gamepad: source.gamepad };
}

/** The master in each XR frame: a controller when there is one, else a tracked hand
 * (the right first). Whenever the driving input changes (another hand, a controller
 * picked up) the reading lets go for one frame, so the clutch re-anchors on the new one
 * instead of taking the step between the two for a motion. */
export class XRMasterInput {
  private readonly pinches = new Map<XRHandedness, Pinch>();
  private last: XRInputSource | null = null;
  private readonly lastOf = new Map<XRHandedness, XRInputSource | null>();

  /** Each hand's master, for two arms: its controller, else its tracked hand (null:
   * neither). As `read`, a hand whose input changes lets go for one frame. */
  readHands(frame: XRFrame, space: XRReferenceSpace): { left: XRControllerReading | null; right: XRControllerReading | null } {
    const sources = Array.from(frame.session.inputSources);
    const readOne = (handedness: "left" | "right"): XRControllerReading | null => {
      const controller = sources.find((s) => s.handedness === handedness && isController(s));
      const hand = controller ? undefined : sources.find((s) => s.hand && s.handedness === handedness);
      const source = controller ?? hand ?? null;
      let reading: XRControllerReading | null = null;
      if (controller) reading = controllerReading(frame, space, controller);
      else if (hand?.hand) reading = handReading(readHandJoints(frame, hand.hand, space), this.pinch(handedness));
      if (source !== (this.lastOf.get(handedness) ?? null)) {
        this.lastOf.set(handedness, source);
        if (reading) reading = { ...reading, gripping: false };
      }
      return reading;
    };
    return { left: readOne("left"), right: readOne("right") };
  }

  read(frame: XRFrame, space: XRReferenceSpace): XRControllerReading | null {
    const controller = readController(frame, space);
    const sources = Array.from(frame.session.inputSources);
    let source: XRInputSource | null = null;
    let reading: XRControllerReading | null = null;
    if (controller) {
      source = sources.find((s) => s.gamepad === controller.gamepad) ?? null;
      reading = controller;
    } else {
      const hands = sources.filter((s) => s.hand && (s.handedness === "right" || s.handedness === "left"));
      hands.sort((a, b) => (a.handedness === "right" ? 0 : 1) - (b.handedness === "right" ? 0 : 1));
      // Every hand's pinch is followed each frame (its hysteresis needs every distance).
      const joints = hands.map((s) => readHandJoints(frame, s.hand!, space));
      const readings = joints.map((j, k) => handReading(j, this.pinch(hands[k]!.handedness)));
      const i = Math.max(0, joints.findIndex(isTracked));
      source = hands[i] ?? null;
      reading = readings[i] ?? null;
    }
    if (source !== this.last) {
      this.last = source;
      if (reading) reading = { ...reading, gripping: false };
    }
    return reading;
  }

  private pinch(handedness: XRHandedness): Pinch {
    let p = this.pinches.get(handedness);
    if (!p) this.pinches.set(handedness, (p = new Pinch()));
    return p;
  }
}

export interface XRDelta {
  dX: Vec3; // robot base frame, metres
  rotvec: Vec3;
}

// A tracking jump is a step faster than a hand: more than MAX_SPEED over the time since
// the last frame (at least MAX_STEP, for tracking noise at a headset's 72–120 Hz). Per
// frame alone would drop every step of a page whose frames come slowly (a busy or
// software-rendered page: 1–9 XR frames/s), and the hand's motion would be lost.
const MAX_STEP = 0.05; // m
const MAX_SPEED = 2; // m/s

export class XRMaster {
  private last: { p: Vec3; q: [number, number, number, number]; t: number } | null = null;

  /** Feed the grip state and the controller pose (XR space: y up, −z forward) at time
   * `t` (seconds, the XR frame's time). */
  update(gripping: boolean, position: Vec3, orientation: [number, number, number, number], t: number): XRDelta | null {
    if (!gripping) {
      this.last = null;
      return null;
    }
    const prev = this.last;
    this.last = { p: position, q: orientation, t };
    if (!prev) return null; // the clutch re-anchors on each press
    const d: Vec3 = [position[0] - prev.p[0], position[1] - prev.p[1], position[2] - prev.p[2]];
    if (Math.hypot(...d) > Math.max(MAX_STEP, MAX_SPEED * (t - prev.t))) return null;
    // XR (x right, y up, z back) → robot base (x forward, y left, z up).
    const dX: Vec3 = [-d[2], -d[0], d[1]];
    const rel = quatMul(orientation, quatConj(prev.q));
    const angle = 2 * Math.acos(Math.max(-1, Math.min(1, rel[3])));
    const s = Math.sqrt(Math.max(1e-12, 1 - rel[3] * rel[3]));
    const axis: Vec3 = [rel[0] / s, rel[1] / s, rel[2] / s];
    const rv: Vec3 = [-axis[2] * angle, -axis[0] * angle, axis[1] * angle];
    return { dX, rotvec: angle > 1e-6 ? rv : [0, 0, 0] };
  }
}

function quatConj(q: [number, number, number, number]): [number, number, number, number] {
  return [-q[0], -q[1], -q[2], q[3]];
}

function quatMul(a: [number, number, number, number], b: [number, number, number, number]): [number, number, number, number] {
  return [
    a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1],
    a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0],
    a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3],
    a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2],
  ];
}
