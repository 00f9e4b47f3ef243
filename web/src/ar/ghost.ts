// The ghost arm: the whole predicted arm (the base, each joint on the way to the tool,
// the tool, from the local model's predicted joints; a branch such as a gripper's jaw
// is not drawn) over both eyes' video as a translucent skeleton, so the operator sees
// where the arm is going before the video shows it.
// Projected with each camera's P, like the AR ball; redrawn only when it moved.
import { jointOrigins, type RobotModelInfo } from "../robot/model";
import { tracePolyline, type Eye, type EyeSize, type OverlayPainter } from "../view/overlay";
import type { CameraCalibration } from "./ball";
import { project, type Projection } from "./projection";

export type Pixel = [number, number] | null; // null: behind the camera
/** The ghost's colour: the joints opaque, the links translucent. */
export const GHOST_RGB = [255, 0, 255] as const;
const LINK_ALPHA = 0.45;
const LINK_WIDTH = 7; // camera pixels
const JOINT_RADIUS = 5;
/** A smaller move is not worth an overlay upload (costly on a software GPU). */
export const REDRAW_PX = 0.5;
export const GHOST_KEY = "telerobot.ghost";

/** The arm's chain (base → each joint of the tool's chain → tool) in one camera's pixels. */
export function ghostChain(model: RobotModelInfo, q: number[], P: Projection): Pixel[] {
  return jointOrigins(model, q).map((p) => project(P, p));
}

/** How far the chain moved, in pixels (the largest of its points); Infinity when a
 * point appeared, vanished, or the chain's length changed. */
export function largestShift(a: readonly Pixel[], b: readonly Pixel[]): number {
  if (a.length !== b.length) return Infinity;
  let most = 0;
  for (let i = 0; i < a.length; i++) {
    const p = a[i];
    const q = b[i];
    if (!p || !q) {
      if (p !== q) return Infinity;
      continue;
    }
    most = Math.max(most, Math.hypot(p[0] - q[0], p[1] - q[1]));
  }
  return most;
}

export class GhostArm implements OverlayPainter {
  /** The chain as last drawn, in the left and the right camera's pixels. */
  readonly pixels: [Pixel[], Pixel[]] = [[], []];
  private shown = true;
  private P: [Projection, Projection] | null = null;

  /** `cameras`: the left camera's, then the right's. */
  constructor(
    private model: RobotModelInfo,
    cameras: readonly CameraCalibration[],
  ) {
    this.setArm(model, cameras);
  }

  /** Another arm or other cameras (a restarted server): nothing is drawn until the next
   * update; true when something was drawn (the overlay must be redrawn). */
  setArm(model: RobotModelInfo, cameras: readonly CameraCalibration[]): boolean {
    const [l, r] = cameras;
    this.model = model;
    this.P = l && r ? [l.P, r.P] : null;
    const drawn = this.pixels[0].length + this.pixels[1].length > 0;
    this.pixels[0] = [];
    this.pixels[1] = [];
    return drawn && this.shown;
  }

  get enabled(): boolean {
    return this.shown;
  }

  /** Show or hide it; true when that changed (the overlay must be redrawn). */
  setEnabled(on: boolean): boolean {
    const changed = on !== this.shown;
    this.shown = on;
    return changed;
  }

  /** Move the ghost to joints `q` (null: none yet, it stays); true when it moved by
   * REDRAW_PX or more in either eye, and is shown (the overlay must be redrawn). */
  update(q: number[] | null): boolean {
    if (!q || !this.P) return false;
    const next = [ghostChain(this.model, q, this.P[0]), ghostChain(this.model, q, this.P[1])] as const;
    const moved = Math.max(largestShift(this.pixels[0], next[0]), largestShift(this.pixels[1], next[1]));
    if (moved < REDRAW_PX) return false;
    this.pixels[0] = next[0];
    this.pixels[1] = next[1];
    return this.shown;
  }

  paint(ctx: CanvasRenderingContext2D, eye: Eye, _size: EyeSize): void {
    if (!this.shown) return;
    const chain = this.pixels[eye];
    const [r, g, b] = GHOST_RGB;
    ctx.lineCap = "round";
    ctx.lineJoin = "round";
    ctx.lineWidth = LINK_WIDTH;
    ctx.strokeStyle = `rgba(${r}, ${g}, ${b}, ${LINK_ALPHA})`;
    ctx.beginPath();
    tracePolyline(ctx, chain);
    ctx.stroke();
    ctx.fillStyle = `rgb(${r}, ${g}, ${b})`;
    for (const p of chain) {
      if (!p) continue;
      ctx.beginPath();
      ctx.arc(p[0], p[1], JOINT_RADIUS, 0, 2 * Math.PI);
      ctx.fill();
    }
  }
}

/** The "Ghost arm" checkbox: remembered in `storage` (on unless switched off), and
 * `changed` is called with the new setting. */
export function setupGhostSwitch(box: HTMLInputElement, ghost: GhostArm, storage: Storage, changed: () => void): void {
  box.checked = storage.getItem(GHOST_KEY) !== "off";
  ghost.setEnabled(box.checked);
  box.addEventListener("change", () => {
    storage.setItem(GHOST_KEY, box.checked ? "on" : "off");
    if (ghost.setEnabled(box.checked)) changed();
  });
}
