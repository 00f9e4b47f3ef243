// The input → command loop. Every animation frame the gamepad and the keyboard become
// Cartesian increments, sent only while the dead-man is held and this page holds the
// lease; in an XR session the controller's grip (the dead-man there) does the same.
// Also the lease requests (take, take over, release), the e-stop key and the frame.
// The view frame (the default) moves as the left camera's image shows: its increments
// are turned into the base frame's here, and sent (and predicted) as base ones.
import type { Mat3, Vec3 } from "../robot/math";
import type { FrameName } from "../robot/model";
import { Frame, LeaseAction, StateFlags } from "../transport/messages";
import type { GamepadState } from "./gamepad";
import { combine, type MotionCommand } from "./motion";
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
/** In the order the gamepad's Y cycles them. */
export const FRAMES: readonly DriveFrame[] = ["view", "base", "wrist", "tool"];
/** Keys that pick a frame (KeyboardEvent.code). */
export const FRAME_KEYS: Record<string, DriveFrame> = { Digit1: "base", Digit2: "wrist", Digit3: "tool", Digit4: "view" };
/** The frame each is sent in: the view's increments go as base ones. */
export const FRAME_IDS: Record<DriveFrame, number> = { view: Frame.BASE, base: Frame.BASE, wrist: Frame.WRIST, tool: Frame.TOOL };

/** The realtime channel, as far as the loop uses it. */
export interface CommandLink {
  cartesian(dX: number[], rotvec: number[], frame: number): void;
  lease(action: number): void;
  wantControl(on: boolean): void;
  estop(): void;
}
/** The local model that shows each command at once. */
export interface CommandPredictor {
  commandCartesian(dX: Vec3, rotvec: Vec3, frame: FrameName, now: number): void;
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
  private last: number;
  private inputState = "";
  private readonly xr = new XRMaster();
  private deadmanWas = false;
  private gripWas = false;
  private heldTakeover = false; // this correction began by holding the dead-man or the grip
  private letGoAt: number | null = null;

  constructor(private readonly o: InputLoopOptions) {
    this.last = o.now;
  }

  /** The view frame's rotation in the base frame (null: no camera). */
  get view(): Mat3 | null {
    return this.o.view;
  }

  /** Another left camera (a restarted server). */
  set view(view: Mat3 | null) {
    this.o.view = view;
  }

  get hasControl(): boolean {
    return hasControl(this.o.flags());
  }

  take(): void {
    this.o.link.lease(takeAction(this.o.flags()));
    this.o.link.wantControl(true);
    setTimeout(() => this.o.link.wantControl(false), WANT_CONTROL_MS); // from then on: only while we hold it
  }

  release(): void {
    this.onRelease?.();
    this.o.link.wantControl(false);
    this.o.link.lease(LeaseAction.RELEASE);
  }

  estop(): void {
    this.o.link.estop();
  }

  /** A key went down (KeyboardEvent.code): Escape is the e-stop, 1/2/3/4 pick the
   * base/wrist/tool/view frame. */
  key(code: string): void {
    if (code === "Escape") this.estop();
    const frame = FRAME_KEYS[code];
    if (frame) this.pickFrame(frame);
  }

  private pickFrame(frame: DriveFrame): void {
    this.frame = frame;
    this.onFrameChange?.(frame);
  }

  /** One animation frame at `now` (ms); gives the gamepad's state (for its rumble). */
  tick(now: number): GamepadState {
    const dt = Math.min(MAX_FRAME_S, (now - this.last) / 1000);
    this.last = now;
    const pad = this.o.gamepad.read();
    if (pad.cycleFrame) this.pickFrame(FRAMES[(FRAMES.indexOf(this.frame) + 1) % FRAMES.length]!);
    const cmd = combine(pad.command, this.o.keyboard.read());
    if (cmd.deadman && !this.deadmanWas) this.takeOverFromPolicy();
    this.deadmanWas = cmd.deadman;
    this.handBackWhenLetGo(now);
    const inputState = `${pad.pad ? "gamepad" : "no gamepad"} · dead-man ${cmd.deadman ? "held" : "released"}`;
    if (inputState !== this.inputState) this.onInputState?.((this.inputState = inputState));
    const step = increments(cmd, this.o.speed(), dt);
    if (step && this.hasControl) this.send(step.dX, step.rotvec, this.frame, now);
    return pad;
  }

  /** One XR frame at `now` (ms): the controller that drives (null: none). While its grip
   * is held, its motion since the last frame, scaled by the speed, moves the gripper. */
  xrFrame(controller: XRControllerReading | null, now: number): void {
    if (!controller) {
      this.xr.update(false, [0, 0, 0], [0, 0, 0, 1], 0);
      this.gripWas = false;
      this.handBackWhenLetGo(now);
      return;
    }
    if (controller.gripping && !this.gripWas) this.takeOverFromPolicy();
    this.gripWas = controller.gripping;
    this.handBackWhenLetGo(now);
    const delta = this.xr.update(controller.gripping, controller.position, controller.orientation, now / 1000);
    if (!delta || !this.hasControl) return;
    const speed = this.o.speed();
    this.send(delta.dX.map((v) => v * speed) as Vec3, delta.rotvec.map((v) => v * speed) as Vec3, "base", now);
  }

  /** The dead-man or the grip went down while a policy holds control: take over. The
   * server stops the arm where it is; the increments drive from there once the STATE
   * says this page has control (none is sent before). */
  private takeOverFromPolicy(): void {
    if (this.o.policyHolds?.() && !this.hasControl) {
      this.take();
      this.heldTakeover = true;
    }
  }

  /** A correction begun by holding hands back once the dead-man and the grip have both
   * been let go for HAND_BACK_MS (the server then gives control to the policy). */
  private handBackWhenLetGo(now: number): void {
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

  /** Send an increment in `frame`, and give the local model the very same one. */
  private send(dX: Vec3, rotvec: Vec3, frame: DriveFrame, now: number): void {
    if (frame === "view") {
      const view = this.o.view;
      if (view) [dX, rotvec] = [viewToBase(view, dX), viewToBase(view, rotvec)];
      frame = "base";
    }
    this.o.link.cartesian(dX, rotvec, FRAME_IDS[frame]);
    this.o.arm.commandCartesian(dX, rotvec, frame, now);
  }
}
