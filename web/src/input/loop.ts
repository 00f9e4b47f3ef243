// The input → command loop. Every animation frame the gamepad and the keyboard become
// Cartesian increments, sent only while the dead-man is held and this page holds the
// lease; in an XR session the controller's grip (the dead-man there) does the same.
// Also the lease requests (take, take over, release), the e-stop key and the frame.
// The view frame (the default) moves as the left camera's image shows: its increments
// are turned into the base frame's here, and sent (and predicted) as base ones.
// With two arms or more each command names its arm, and which input drives which is
// input/arms.ts's: the keys the selected arm, the gamepad each side's (or the selected
// one alone), the left XR controller or hand the left arm and the right the right.
import type { Mat3, Vec3 } from "../robot/math";
import type { FrameName } from "../robot/model";
import { Frame, LeaseAction, StateFlags } from "../transport/messages";
import { ARM_KEYS, type PadMode, armCommands, handArms, routingText, stepArm } from "./arms";
import type { GamepadState } from "./gamepad";
import type { MotionCommand } from "./motion";
import { viewToBase } from "./viewframe";
import { XRMaster, type XRControllerReading } from "./xr";

export const MAX_LINEAR = 0.1; // m/s at full deflection and speed 1
export const MAX_ANGULAR = 0.5; // rad/s
export const MAX_FRAME_S = 0.1; // a longer gap between frames moves no further than this
/** Heartbeats start the moment we ask for control, before a STATE confirms it; after
 * this long they go on only while we hold it. */
export const WANT_CONTROL_MS = 2000;
/** A correction taken over by holding the dead-man or the XR grip is handed back to the
 * policy when it has been let go this long: a re-clutch (let go, grip again) is quicker
 * and keeps control. */
export const HAND_BACK_MS = 600;
/** The frames the operator drives in: the view (W away from the camera, A left and R up
 * in the image) or one of the server's. */
export type DriveFrame = "view" | FrameName;
/** Keys that drive (KeyboardEvent.code): the dead-man and the motion keys. Pressed, they
 * drive at once (`key`), not at the next animation frame: on a page whose drawing takes
 * a software GPU's time that frame is tens of ms away (docs/hand-to-eye.md). */
export const DRIVE_KEYS = new Set(["Space", "KeyW", "KeyS", "KeyA", "KeyD", "KeyR", "KeyF", "KeyQ", "KeyE"]);
/** A key drives at once only while the animation frames tick (not in an XR session,
 * whose frames drive instead): the last tick this recent (ms). */
export const TICKING_MS = 250;
/** In the order the gamepad's Y cycles them. */
export const FRAMES: readonly DriveFrame[] = ["view", "base", "wrist", "tool"];
/** Keys that pick a frame (KeyboardEvent.code). */
export const FRAME_KEYS: Record<string, DriveFrame> = { Digit1: "base", Digit2: "wrist", Digit3: "tool", Digit4: "view" };
/** The frame each is sent in: the view's increments go as base ones. */
export const FRAME_IDS: Record<DriveFrame, number> = { view: Frame.BASE, base: Frame.BASE, wrist: Frame.WRIST, tool: Frame.TOOL };

/** The realtime channel, as far as the loop uses it. */
export interface CommandLink {
  /** `arm`: ARM's index (0: the only arm of a one-arm server). */
  cartesian(dX: number[], rotvec: number[], frame: number, arm?: number): void;
  lease(action: number): void;
  wantControl(on: boolean): void;
  estop(): void;
  /** The dead-man (a key, the gamepad's, an XR grip) was pressed or let go. */
  deadman?(held: boolean): void;
}
/** The local model that shows each command at once. */
export interface CommandPredictor {
  commandCartesian(dX: Vec3, rotvec: Vec3, frame: FrameName, now: number): void;
}

/** One arm as the loop drives it. */
export interface DriveArm {
  /** ARM's index, sent with each of its commands (0: the only arm of a one-arm server). */
  index: number;
  name: string;
  /** Its local model, told each command as it is sent. */
  predictor: CommandPredictor;
  /** The view frame's rotation in this arm's base frame (null: no camera). */
  view: Mat3 | null;
}

/** Each XR hand's reading in one frame (null: none). */
export interface XRHands {
  left: XRControllerReading | null;
  right: XRControllerReading | null;
}

export const hasControl = (flags: number): boolean => (flags & StateFlags.YOU_HAVE_CONTROL) !== 0;
/** Take control, or take it over when someone else has it. */
export const takeAction = (flags: number): number => ((flags & StateFlags.SOMEONE_HAS_CONTROL) !== 0 ? LeaseAction.TAKE_OVER : LeaseAction.TAKE);

/** What `dt` seconds of `cmd` move at `speed` (0…1): null unless the dead-man is held
 * and some axis is deflected. */
export function increments(cmd: MotionCommand, speed: number, dt: number): { dX: Vec3; rotvec: Vec3 } | null {
  const moving = cmd.linear.some((v) => v !== 0) || cmd.angular.some((v) => v !== 0);
  if (!cmd.deadman || !moving) return null;
  return {
    dX: cmd.linear.map((v) => v * MAX_LINEAR * speed * dt) as Vec3,
    rotvec: cmd.angular.map((v) => v * MAX_ANGULAR * speed * dt) as Vec3,
  };
}

export interface InputLoopOptions {
  link: CommandLink;
  arm: CommandPredictor;
  /** The latest STATE's flags (0 before the first). */
  flags: () => number;
  /** The speed setting, 0…1. */
  speed: () => number;
  gamepad: { read(): GamepadState };
  keyboard: { read(): MotionCommand };
  /** The view frame's rotation in the base frame (viewframe.ts), from the left camera;
   * null: no camera, and the view frame drives as the base frame. */
  view: Mat3 | null;
  /** When the loop starts (ms, the clock `tick` is given). */
  now: number;
  /** A learned policy holds control (ui/autonomy.ts): pressing the dead-man or the XR
   * grip takes over from it, the one motion that starts a correction. */
  policyHolds?: () => boolean;
}

export class InputLoop {
  frame: DriveFrame = "view";
  /** A key or the gamepad picked another frame. */
  onFrameChange: ((frame: DriveFrame) => void) | null = null;
  /** The inputs' state changed (which devices, the dead-man): for the page to show. */
  onInputState: ((text: string) => void) | null = null;
  /** This page gives control up on purpose (not a loss to alarm about). */
  onRelease: (() => void) | null = null;
  /** Another arm was selected, the gamepad swapped between both arms and one, or the
   * arms are others (a restarted server). */
  onArmChange: ((why: "select" | "swap" | "arms") => void) | null = null;
  /** The arm the keys drive (and the gamepad in "one"): an index into `arms`. */
  selected = 0;
  /** Two arms or more: the gamepad drives both (a side each) or the selected one. */
  padMode: PadMode = "both";
  /** A driving key drives at its keydown (DRIVE_KEYS); false: at the next frame only, as
   * before (bench.hand_to_eye --send-on-frame measures both). */
  driveOnKey = true;
  private arms: DriveArm[];
  private last: number;
  private inputState = "";
  private readonly xr = new XRMaster();
  private readonly hands = { left: new XRMaster(), right: new XRMaster() };
  private deadmanWas = false;
  private gripWas = false;
  // Each arm's dead-man, as the last frame's inputs held it (keys, gamepad, XR grips).
  private deadmen: boolean[] = [false];
  private xrHeld: boolean[] = [false];
  private heldTakeover = false; // this correction began by holding the dead-man or the grip
  private letGoAt: number | null = null;
  // A take is on its way (take(), WANT_CONTROL_MS): a dead-man pressed meanwhile (T, then
  // Space to drive, before the STATE says control came: seconds on a loaded machine)
  // drives that correction; it does not make it one that letting go hands back.
  private asking = false;
  private asks = 0; // takes so far: the latest one's WANT_CONTROL_MS counts
  private deadmanSaid = false; // what the link was told of the dead-man
  private lastPad: GamepadState | null = null; // the last tick's gamepad
  private tickedAt = -Infinity;

  constructor(private readonly o: InputLoopOptions) {
    this.last = o.now;
    this.arms = [{ index: 0, name: "arm", predictor: o.arm, view: o.view }];
  }

  /** The view frame's rotation in the selected arm's base frame (null: no camera). */
  get view(): Mat3 | null {
    return this.arms[this.selected]?.view ?? null;
  }

  /** Another left camera (a restarted server): the first arm's. */
  set view(view: Mat3 | null) {
    this.o.view = view;
    if (this.arms[0]) this.arms[0].view = view;
  }

  /** The arms to drive (the server's, in order); the selection stays if it still can. */
  setArms(arms: readonly DriveArm[]): void {
    this.arms = arms.slice();
    this.selected = Math.min(this.selected, Math.max(0, arms.length - 1));
    this.deadmen = arms.map(() => false);
    this.xrHeld = arms.map(() => false);
    this.onArmChange?.("arms");
  }

  get armCount(): number {
    return this.arms.length;
  }

  /** The arms' names, in order. */
  get armNames(): string[] {
    return this.arms.map((a) => a.name);
  }

  /** Select the arm the keys (and the gamepad alone) drive. */
  selectArm(i: number): void {
    const next = stepArm(i, 0, this.arms.length);
    if (next === this.selected) return;
    this.selected = next;
    this.onArmChange?.("select");
  }

  /** The arms whose dead-man (or XR grip) is held now. Indices into the arms. */
  get held(): number[] {
    return this.arms.map((_, i) => i).filter((i) => this.deadmen[i] || this.xrHeld[i]);
  }

  /** The arms driven now: those held; when none is, the selected one (what the keys
   * would drive). Indices into the arms. */
  get driven(): number[] {
    const on = this.held;
    return on.length ? on : [this.selected];
  }

  private get routing() {
    return { count: this.arms.length, selected: this.selected, padMode: this.padMode, hands: handArms(this.armNames) };
  }

  get hasControl(): boolean {
    return hasControl(this.o.flags());
  }

  take(): void {
    this.o.link.lease(takeAction(this.o.flags()));
    this.o.link.wantControl(true);
    this.asking = true;
    const ask = ++this.asks;
    setTimeout(() => {
      if (ask !== this.asks) return; // asked again since: that one's time counts
      this.asking = false;
      this.o.link.wantControl(false); // from then on: only while we hold it
    }, WANT_CONTROL_MS);
  }

  release(): void {
    this.asking = false;
    this.onRelease?.();
    this.o.link.wantControl(false);
    this.o.link.lease(LeaseAction.RELEASE);
  }

  estop(): void {
    this.o.link.estop();
  }

  /** A key went down (KeyboardEvent.code) at `now` (ms, the clock `tick` is given):
   * Escape is the e-stop, 1/2/3/4 pick the base/wrist/tool/view frame, [ and ] the arm
   * (two arms or more); a driving key drives at once (DRIVE_KEYS). */
  key(code: string, now: number = performance.now()): void {
    if (code === "Escape") this.estop();
    const frame = FRAME_KEYS[code];
    if (frame) this.pickFrame(frame);
    const step = ARM_KEYS[code];
    if (step && this.arms.length > 1) this.selectArm(this.selected + step);
    if (this.driveOnKey && DRIVE_KEYS.has(code) && this.lastPad && now - this.tickedAt < TICKING_MS && now > this.last) {
      // The same as a frame's inputs, the gamepad as the last frame read it (its
      // buttons' edges were taken then); the next frame goes on from here.
      this.drive(now, { ...this.lastPad, cycleFrame: false, swapArms: false, pickArm: 0 });
    }
  }

  private pickFrame(frame: DriveFrame): void {
    this.frame = frame;
    this.onFrameChange?.(frame);
  }

  /** One animation frame at `now` (ms); gives the gamepad's state (for its rumble). */
  tick(now: number): GamepadState {
    const pad = this.o.gamepad.read();
    this.lastPad = pad;
    this.tickedAt = now;
    if (pad.cycleFrame) this.pickFrame(FRAMES[(FRAMES.indexOf(this.frame) + 1) % FRAMES.length]!);
    if (this.arms.length > 1) {
      if (pad.swapArms) {
        this.padMode = this.padMode === "both" ? "one" : "both";
        this.onArmChange?.("swap");
      }
      if (pad.pickArm) this.selectArm(this.selected + pad.pickArm);
    }
    this.drive(now, pad);
    return pad;
  }

  /** The inputs at `now` (the keys as held now, the gamepad's `pad`) to commands: the
   * increments of the time since the last frame or key. */
  private drive(now: number, pad: GamepadState): void {
    const dt = Math.min(MAX_FRAME_S, Math.max(0, now - this.last) / 1000);
    this.last = now;
    const cmds = armCommands(this.routing, pad, this.o.keyboard.read());
    this.deadmen = cmds.map((c) => c.deadman);
    const deadman = this.deadmen.some(Boolean);
    if (deadman && !this.deadmanWas) this.takeOverFromPolicy();
    this.deadmanWas = deadman;
    this.afterFrame(now);
    const routing = routingText(this.armNames, this.routing);
    const inputState = `${pad.pad ? "gamepad" : "no gamepad"} · dead-man ${deadman ? "held" : "released"}${routing ? ` · ${routing}` : ""}`;
    if (inputState !== this.inputState) this.onInputState?.((this.inputState = inputState));
    const speed = this.o.speed();
    cmds.forEach((cmd, i) => {
      const step = increments(cmd, speed, dt);
      if (step && this.hasControl) this.send(step.dX, step.rotvec, this.frame, now, i);
    });
  }

  /** One XR frame at `now` (ms): the controller that drives (null: none). While its grip
   * is held, its motion since the last frame, scaled by the speed, moves the gripper. */
  xrFrame(controller: XRControllerReading | null, now: number): void {
    if (!controller) {
      this.xr.update(false, [0, 0, 0], [0, 0, 0, 1], 0);
      this.gripWas = false;
      this.xrHeld = this.arms.map(() => false);
      this.afterFrame(now);
      return;
    }
    if (controller.gripping && !this.gripWas) this.takeOverFromPolicy();
    this.gripWas = controller.gripping;
    this.afterFrame(now);
    this.xrHeld = this.arms.map((_, i) => i === this.selected && controller.gripping);
    const delta = this.xr.update(controller.gripping, controller.position, controller.orientation, now / 1000);
    if (!delta || !this.hasControl) return;
    const speed = this.o.speed();
    this.send(delta.dX.map((v) => v * speed) as Vec3, delta.rotvec.map((v) => v * speed) as Vec3, "base", now, this.selected);
  }

  /** One XR frame at `now` (ms) with two arms or more: the left hand (controller or
   * tracked hand) drives the left arm and the right hand the right one (handArms), each
   * with its own clutch. A hand's motion is taken in the view frame (forward: into the
   * picture, right and up as it shows them: what the headset shows), each arm's own. */
  xrHands(hands: XRHands, now: number): void {
    const { left, right } = handArms(this.armNames);
    const gripping = !!hands.left?.gripping || !!hands.right?.gripping;
    if (gripping && !this.gripWas) this.takeOverFromPolicy();
    this.gripWas = gripping;
    this.afterFrame(now);
    this.xrHeld = this.arms.map((_, i) => (i === left && !!hands.left?.gripping) || (i === right && !!hands.right?.gripping));
    for (const hand of ["left", "right"] as const) {
      const r = hands[hand];
      const arm = hand === "left" ? left : right;
      const delta = this.hands[hand].update(r?.gripping ?? false, r?.position ?? [0, 0, 0], r?.orientation ?? [0, 0, 0, 1], now / 1000);
      if (!delta || !this.hasControl || !this.arms[arm]) continue;
      const view = this.arms[arm].view;
      const speed = this.o.speed();
      const [dX, rotvec] = [delta.dX, delta.rotvec].map((v) => (view ? viewToBase(view, v) : v).map((x) => x * speed) as Vec3) as [Vec3, Vec3];
      this.send(dX, rotvec, "base", now, arm);
    }
  }

  /** The dead-man or the grip went down while a policy holds control: take over. The
   * server stops the arm where it is; the increments drive from there once the STATE
   * says this page has control (none is sent before). */
  private takeOverFromPolicy(): void {
    if (this.o.policyHolds?.() && !this.hasControl && !this.asking) {
      this.take();
      this.heldTakeover = true;
    }
  }

  /** After each frame's inputs: a take is answered once control came; the link is told
   * when the dead-man (or the grip) is pressed or let go (its worker keeps a stalled
   * page's lease only while it is held); and a correction begun by holding hands back
   * once the dead-man and the grip have both been let go for HAND_BACK_MS (the server
   * then gives control to the policy). */
  private afterFrame(now: number): void {
    if (this.hasControl) this.asking = false;
    const held = this.deadmanWas || this.gripWas;
    if (held !== this.deadmanSaid) this.o.link.deadman?.((this.deadmanSaid = held));
    if (!this.heldTakeover) return;
    if (this.deadmanWas || this.gripWas) {
      this.letGoAt = null;
      return;
    }
    this.letGoAt ??= now;
    if (now - this.letGoAt < HAND_BACK_MS) return;
    this.heldTakeover = false;
    this.letGoAt = null;
    if (this.hasControl) this.release();
  }

  /** Send an increment in `frame` to arm `i` (of `arms`), and give its local model the
   * very same one. */
  private send(dX: Vec3, rotvec: Vec3, frame: DriveFrame, now: number, i = 0): void {
    const arm = this.arms[i];
    if (!arm) return;
    if (frame === "view") {
      const view = arm.view;
      if (view) [dX, rotvec] = [viewToBase(view, dX), viewToBase(view, rotvec)];
      frame = "base";
    }
    this.o.link.cartesian(dX, rotvec, FRAME_IDS[frame], arm.index);
    arm.predictor.commandCartesian(dX, rotvec, frame, now);
  }
}
