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
const LABEL_PX = 16; // camera pixels
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

/** How a ghost is drawn: its colour, and a name by its base (two arms or more). */
export interface GhostStyle {
  rgb: readonly [number, number, number];
  label?: string;
}
/** An arm not driven now (two arms or more) is drawn fainter: its links and joints at
 * this part of their opacity. */
export const IDLE_ALPHA = 0.45;

export class GhostArm implements OverlayPainter {
  /** The chain as last drawn, in the left and the right camera's pixels. */
  readonly pixels: [Pixel[], Pixel[]] = [[], []];
  private shown = true;
  private P: [Projection, Projection] | null = null;
  /** Driven now (drawn at full strength) or not. */
  private highlit = true;

  /** `cameras`: the left camera's, then the right's (an arm's own: P · its mount). */
  constructor(
    private model: RobotModelInfo,
    cameras: readonly CameraCalibration[],
    readonly style: GhostStyle = { rgb: GHOST_RGB },
  ) {
    this.setArm(model, cameras);
  }

  get highlighted(): boolean {
    return this.highlit;
  }

  /** Driven now or not; true when that changed what is drawn (the overlay must be redrawn). */
  setHighlight(on: boolean): boolean {
    const changed = on !== this.highlit;
    this.highlit = on;
    return changed && this.shown;
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
    const [r, g, b] = this.style.rgb;
    const a = this.highlit ? 1 : IDLE_ALPHA;
    ctx.lineCap = "round";
    ctx.lineJoin = "round";
    ctx.lineWidth = this.highlit ? LINK_WIDTH : LINK_WIDTH - 2;
    ctx.strokeStyle = `rgba(${r}, ${g}, ${b}, ${LINK_ALPHA * a})`;
    ctx.beginPath();
    tracePolyline(ctx, chain);
    ctx.stroke();
    ctx.fillStyle = a === 1 ? `rgb(${r}, ${g}, ${b})` : `rgba(${r}, ${g}, ${b}, ${a})`;
    for (const p of chain) {
      if (!p) continue;
      ctx.beginPath();
      ctx.arc(p[0], p[1], JOINT_RADIUS, 0, 2 * Math.PI);
      ctx.fill();
    }
    const base = chain[0];
    if (this.style.label && base) {
      // The arm's name under its base, outlined to read on any background; bold while driven.
      ctx.save();
      ctx.font = `${this.highlit ? "bold " : ""}${LABEL_PX}px sans-serif`;
      ctx.textAlign = "center";
      ctx.textBaseline = "top";
      ctx.lineWidth = 3;
      ctx.strokeStyle = `rgba(0, 0, 0, ${0.8 * a})`;
      ctx.strokeText(this.style.label, base[0], base[1] + 2 * JOINT_RADIUS);
      ctx.fillStyle = `rgba(${r}, ${g}, ${b}, ${a})`;
      ctx.fillText(this.style.label, base[0], base[1] + 2 * JOINT_RADIUS);
      ctx.restore();
    }
  }
}

/** The "Ghost arm" checkbox: remembered in `storage` (on unless switched off), and
 * `changed` is called with the new setting. */
export function setupGhostSwitch(box: HTMLInputElement, ghost: Pick<GhostArm, "setEnabled">, storage: Storage, changed: () => void): void {
  box.checked = storage.getItem(GHOST_KEY) !== "off";
  ghost.setEnabled(box.checked);
  box.addEventListener("change", () => {
    storage.setItem(GHOST_KEY, box.checked ? "on" : "off");
    if (ghost.setEnabled(box.checked)) changed();
  });
}
