import { describe, expect, it } from "vitest";
import { PINCH_CLOSE_M, PINCH_OPEN_M, Pinch, handReading, type HandJoints } from "./input/hands";
import { XRMaster, XRMasterInput } from "./input/xr";
import type { Vec3 } from "./robot/math";

/** A hand with its wrist at `wrist` and thumb and index tips `gap` metres apart. */
const hand = (wrist: Vec3, gap: number, emulated = false): HandJoints => ({
  wrist: { position: wrist, orientation: [0, 0, 0, 1], emulated },
  thumbTip: [wrist[0] + 0.1, wrist[1], wrist[2] - 0.05],
  indexTip: [wrist[0] + 0.1, wrist[1] + gap, wrist[2] - 0.05],
});

describe("pinch", () => {
  it("closes below 2 cm and opens only above 4 cm", () => {
    const p = new Pinch();
    const seen = [0.09, 0.03, 0.021, 0.019, 0.03, 0.039, 0.041, 0.03, 0.01].map((d) => p.update(d));
    expect(seen).toEqual([false, false, false, true, true, true, false, false, true]);
    expect(PINCH_CLOSE_M).toBe(0.02);
    expect(PINCH_OPEN_M).toBe(0.04);
  });

  it("opens when the hand is lost", () => {
    const p = new Pinch();
    p.update(0.005);
    expect(p.update(null)).toBe(false);
    expect(p.update(0.03)).toBe(false); // and stays open in the band until a new pinch
    expect(p.update(Number.NaN)).toBe(false);
  });
});

describe("a hand as the master", () => {
  it("reads the wrist's pose and the pinch as the clutch", () => {
    const pinch = new Pinch();
    const r = handReading(hand([0.1, 1.2, -0.3], 0.005), pinch);
    expect(r).toEqual({ gripping: true, position: [0.1, 1.2, -0.3], orientation: [0, 0, 0, 1], gamepad: null });
    expect(handReading(hand([0.1, 1.2, -0.3], 0.05), pinch).gripping).toBe(false);
    // An estimated wrist, or missing tips, is no clutch (and opens the pinch).
    expect(handReading(hand([0, 1, 0], 0.005, true), new Pinch()).gripping).toBe(false);
    expect(handReading({ ...hand([0, 1, 0], 0.005), indexTip: null }, new Pinch()).gripping).toBe(false);
  });

  it("moves the master as a controller does: right → base −y, up → +z, forward → +x", () => {
    const pinch = new Pinch();
    const master = new XRMaster();
    const step = (w: Vec3, gap: number, t: number) => {
      const r = handReading(hand(w, gap), pinch);
      return master.update(r.gripping, r.position, r.orientation, t);
    };
    expect(step([0, 1, 0], 0.08, 0)).toBeNull(); // open hand: nothing
    expect(step([0.01, 1, 0], 0.08, 0.02)).toBeNull();
    expect(step([0.01, 1, 0], 0.01, 0.04)).toBeNull(); // the pinch anchors
    const d = step([0.02, 1.005, -0.003], 0.03, 0.06)!; // held in the hysteresis band
    expect(d.dX[0]).toBeCloseTo(0.003);
    expect(d.dX[1]).toBeCloseTo(-0.01);
    expect(d.dX[2]).toBeCloseTo(0.005);
    expect(d.rotvec).toEqual([0, 0, 0]);
    expect(step([0.2, 1, 0], 0.01, 0.08)).toBeNull(); // an 18 cm jump in 20 ms: ignored
    expect(step([0.2, 1, 0], 0.05, 0.1)).toBeNull(); // released
    expect(step([0.3, 1, 0], 0.01, 0.12)).toBeNull(); // re-anchors, no step from the release
    expect(step([0.31, 1, 0], 0.01, 0.14)!.dX[1]).toBeCloseTo(-0.01);
  });
});

// Fake WebXR objects: enough of XRFrame / XRInputSource / XRHand for XRMasterInput. The
// sources are the same objects from frame to frame, as a session's are.
type FakeHand = { handedness: "left" | "right"; wrist: Vec3 | null; gap: number };
const sourceCache = new Map<string, { handedness: string; hand?: Map<string, { pose: Vec3 | null }>; gripSpace: { pose?: Vec3 }; gamepad: object }>();
function frameOf(hands: FakeHand[], controller?: { squeeze: boolean; position: Vec3 }): XRFrame {
  const sources: object[] = hands.map((h) => {
    const key = `hand-${h.handedness}`;
    const s = sourceCache.get(key) ?? { handedness: h.handedness, hand: new Map(), gripSpace: {}, gamepad: { buttons: [{ pressed: false }] } };
    sourceCache.set(key, s);
    const j = hand(h.wrist ?? [0, 0, 0], h.gap);
    s.hand!.set("wrist", { pose: h.wrist ? j.wrist!.position : null });
    s.hand!.set("thumb-tip", { pose: h.wrist ? j.thumbTip : null });
    s.hand!.set("index-finger-tip", { pose: h.wrist ? j.indexTip : null });
    return s;
  });
  if (controller) {
    const s = sourceCache.get("controller") ?? { handedness: "right", gripSpace: {}, gamepad: { buttons: [{ pressed: false }, { pressed: false }] } };
    sourceCache.set("controller", s);
    s.gripSpace.pose = controller.position;
    (s.gamepad as { buttons: { pressed: boolean }[] }).buttons[1]!.pressed = controller.squeeze;
    sources.push(s);
  }
  const poseOf = (p: Vec3 | null | undefined) => (p ? { emulatedPosition: false, transform: { position: { x: p[0], y: p[1], z: p[2] }, orientation: { x: 0, y: 0, z: 0, w: 1 } } } : null);
  return {
    session: { inputSources: sources },
    getPose: (space: { pose?: Vec3 }) => poseOf(space.pose),
    getJointPose: (joint: { pose: Vec3 | null }) => poseOf(joint.pose),
  } as unknown as XRFrame;
}
const space = {} as XRReferenceSpace;

describe("XRMasterInput", () => {
  it("takes a tracked hand, the right first, and lets go for a frame when the hand changes", () => {
    const input = new XRMasterInput();
    const both = (rightWrist: Vec3 | null) => frameOf([{ handedness: "left", wrist: [-0.2, 1, 0], gap: 0.01 }, { handedness: "right", wrist: rightWrist, gap: 0.01 }]);
    expect(input.read(both([0.2, 1, 0]), space)).toMatchObject({ position: [0.2, 1, 0], gripping: false }); // a new source: not yet
    expect(input.read(both([0.2, 1, 0]), space)).toMatchObject({ position: [0.2, 1, 0], gripping: true, gamepad: null });
    expect(input.read(both(null), space)).toMatchObject({ position: [-0.2, 1, 0], gripping: false }); // right lost → left, re-anchored
    expect(input.read(both(null), space)).toMatchObject({ position: [-0.2, 1, 0], gripping: true });
    expect(input.read(frameOf([]), space)).toBeNull();
  });

  it("prefers a controller to a hand, and re-anchors when it takes over", () => {
    const input = new XRMasterInput();
    const onlyHand = () => frameOf([{ handedness: "right", wrist: [0.2, 1, 0], gap: 0.01 }]);
    const withController = () => frameOf([{ handedness: "right", wrist: [0.2, 1, 0], gap: 0.01 }], { squeeze: true, position: [0.5, 1, 0] });
    input.read(onlyHand(), space);
    expect(input.read(onlyHand(), space)).toMatchObject({ gripping: true, position: [0.2, 1, 0] });
    expect(input.read(withController(), space)).toMatchObject({ gripping: false, position: [0.5, 1, 0] });
    const r = input.read(withController(), space)!;
    expect(r.position).toEqual([0.5, 1, 0]);
    expect(r.gripping).toBe(true);
    expect(r.gamepad).not.toBeNull();
  });
});
