// The axis marker: the active driving frame's three axes drawn at the (predicted)
// gripper in each eye — x red, y green, z blue, each with its letter — so the operator
// sees which way each key moves. View: away from the camera, left and up in the image;
// base: the base axes; wrist/tool: the arm's wrist/tool orientation now. Projected with
// each camera's P and painted through the stereo view's overlay layer, which is redrawn
// only when the marker moved by half a pixel or more, or the frame changed.
import type { DriveFrame } from "../input/loop";
import { type Mat3, type Mat4, type Vec3, column3, inverseRigid, mul4, position, rotation } from "../robot/math";
import type { CameraCalibration } from "./ball";
import type { Eye, EyeSize, OverlayPainter } from "../view/overlay";
import { type Projection, project } from "./projection";

/** Where the marker is painted: the stereo view's overlay layer. */
export interface OverlayHost {
  addOverlay(painter: OverlayPainter): void;
  /** Painters are called again before the next frame is drawn. */
  overlayChanged(): void;
}

export const AXIS_COLOURS = ["#ff3030", "#30e030", "#3080ff"] as const; // x y z
const LETTERS = ["x", "y", "z"] as const;
/** Each axis's length in the scene, metres. */
export const AXIS_LENGTH = 0.08;
/** A smaller move than this (pixels) is not worth another overlay upload. */
export const REDRAW_PX = 0.5;
/** An axis drawn shorter than this part of the longest one points mostly along the line
 * of sight: it is also drawn as ⊗ (away from the camera) or ⊙ (towards it), since its
 * short stroke can hide under another axis (the view frame's x, "away", climbs the image
 * nearly as z, "up", does for a camera looking down at the work). */
export const FORESHORTENED = 0.45;

/** Per eye: the origin and the three axes' tips in that camera's pixels (null: behind it). */
export type MarkerPixels = [Pixel, Pixel, Pixel, Pixel];
type Pixel = [number, number] | null;

/** The active frame's axes (columns) in the base frame, at the tool pose `T`. */
export function frameAxes(frame: DriveFrame, T: Mat4, view: Mat3 | null, tool: Mat4): Mat3 {
  if (frame === "tool") return rotation(T);
  if (frame === "wrist") return rotation(mul4(T, inverseRigid(tool)));
  if (frame === "view" && view) return view;
  return [1, 0, 0, 0, 1, 0, 0, 0, 1];
}

/** The marker's origin and axis tips projected with `P`. */
export function projectMarker(P: Projection, origin: Vec3, axes: Mat3, length = AXIS_LENGTH): MarkerPixels {
  const tip = (j: number): Pixel => {
    const a = column3(axes, j);
    return project(P, [origin[0] + length * a[0], origin[1] + length * a[1], origin[2] + length * a[2]]);
  };
  return [project(P, origin), tip(0), tip(1), tip(2)];
}

/** Whether each axis points away from the camera (its tip is deeper than the origin). */
export function pointsAway(P: Projection, axes: Mat3): [boolean, boolean, boolean] {
  const r = P[2] ?? [0, 0, 0];
  const away = (j: number) => {
    const a = column3(axes, j);
    return (r[0] ?? 0) * a[0] + (r[1] ?? 0) * a[1] + (r[2] ?? 0) * a[2] > 0;
  };
  return [away(0), away(1), away(2)];
}

function moved(a: MarkerPixels | null, b: MarkerPixels | null): boolean {
  if (a === null || b === null) return a !== b;
  return a.some((p, i) => {
    const q = b[i] ?? null;
    if (p === null || q === null) return p !== q;
    return Math.hypot(p[0] - q[0], p[1] - q[1]) >= REDRAW_PX;
  });
}

export class AxisMarker implements OverlayPainter {
  /** What is drawn now, per eye (null: nothing). */
  readonly pixels: [MarkerPixels | null, MarkerPixels | null] = [null, null];
  /** Per eye: which axes point away from that camera. */
  private readonly away: [boolean, boolean, boolean][] = [
    [false, false, false],
    [false, false, false],
  ];
  private frame: DriveFrame | null = null;
  private shown = true;
  private cameras: (CameraCalibration | undefined)[];

  /** `cameras`: the left camera's, then the right's; `tool`: the arm's tool transform. */
  constructor(
    cameras: readonly CameraCalibration[],
    private tool: Mat4,
    private readonly host: OverlayHost | null,
  ) {
    this.cameras = [cameras[0], cameras[1]];
    host?.addOverlay(this);
  }

  /** Another arm's tool or other cameras (a restarted server): nothing is drawn until
   * the next update. */
  setArm(cameras: readonly CameraCalibration[], tool: Mat4): void {
    this.cameras = [cameras[0], cameras[1]];
    this.tool = tool;
    this.frame = null;
    this.pixels[0] = this.pixels[1] = null;
    this.host?.overlayChanged();
  }

  /** Place the marker for `frame` at the tool pose `T` (null: the arm's pose is not
   * known yet); asks for a redraw only when that changes what is drawn. */
  update(frame: DriveFrame, T: Mat4 | null, view: Mat3 | null, show = true): void {
    const axes = T ? frameAxes(frame, T, view, this.tool) : null;
    const next = [0, 1].map((eye) => {
      const cam = this.cameras[eye];
      if (!show || !T || !axes || !cam) return null;
      this.away[eye] = pointsAway(cam.P, axes);
      return projectMarker(cam.P, position(T), axes);
    });
    const changed = frame !== this.frame || show !== this.shown || next.some((p, eye) => moved(p ?? null, this.pixels[eye] ?? null));
    if (!changed) return;
    this.frame = frame;
    this.shown = show;
    this.pixels[0] = next[0] ?? null;
    this.pixels[1] = next[1] ?? null;
    this.host?.overlayChanged();
  }

  paint(ctx: CanvasRenderingContext2D, eye: Eye, size: EyeSize): void {
    const px = this.pixels[eye];
    const origin = px?.[0];
    if (!px || !origin) return;
    const scale = Math.max(1, size.width / 640);
    const lengths = [1, 2, 3].map((j) => {
      const tip = px[j];
      return tip ? Math.hypot(tip[0] - origin[0], tip[1] - origin[1]) : 0;
    });
    const longest = Math.max(...lengths);
    const letters: [string, string, number, number][] = []; // letter, colour, x, y
    ctx.save();
    ctx.lineCap = "round";
    ctx.lineWidth = 3 * scale;
    for (let j = 0; j < 3; j++) {
      const tip = px[j + 1];
      if (!tip) continue;
      const colour = AXIS_COLOURS[j]!;
      ctx.strokeStyle = colour;
      ctx.beginPath();
      ctx.moveTo(origin[0], origin[1]);
      ctx.lineTo(tip[0], tip[1]);
      ctx.stroke();
      const len = lengths[j]!;
      if (len < FORESHORTENED * longest) {
        // Along the line of sight: ⊗ away, ⊙ towards the camera, at the origin.
        const r = 7 * scale;
        ctx.beginPath();
        ctx.arc(origin[0], origin[1], r, 0, 2 * Math.PI);
        ctx.stroke();
        ctx.beginPath();
        if (this.away[eye]![j]) {
          const d = r * Math.SQRT1_2;
          ctx.moveTo(origin[0] - d, origin[1] - d);
          ctx.lineTo(origin[0] + d, origin[1] + d);
          ctx.moveTo(origin[0] + d, origin[1] - d);
          ctx.lineTo(origin[0] - d, origin[1] + d);
          ctx.stroke();
        } else {
          ctx.fillStyle = colour;
          ctx.arc(origin[0], origin[1], 2 * scale, 0, 2 * Math.PI);
          ctx.fill();
        }
        letters.push([LETTERS[j]!, colour, origin[0] + r + 7 * scale, origin[1] + r]);
      } else {
        // Just beyond the tip, along the axis.
        const out = 9 * scale;
        letters.push([LETTERS[j]!, colour, tip[0] + ((tip[0] - origin[0]) / len) * out, tip[1] + ((tip[1] - origin[1]) / len) * out]);
      }
    }
    // The letters over every line, outlined so that they read on any background.
    ctx.font = `bold ${Math.round(13 * scale)}px sans-serif`;
    ctx.textAlign = "center";
    ctx.textBaseline = "middle";
    ctx.lineWidth = 3 * scale;
    ctx.strokeStyle = "rgba(0, 0, 0, 0.8)";
    for (const [letter, colour, x, y] of letters) {
      ctx.strokeText(letter, x, y);
      ctx.fillStyle = colour;
      ctx.fillText(letter, x, y);
    }
    ctx.restore();
  }
}
