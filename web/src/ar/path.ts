// A task's path (docs/tasks.md): the tool's recorded positions (base frame) drawn over both
// eyes' video as a cyan polyline, a dot at its start and an arrowhead at its end, so the
// operator sees where a repeated motion will take the arm before it runs. Projected with
// each camera's P like the ghost arm; the overlay is redrawn only when the path changes.
// When the tool is away from the path's start, the approach (a slow joint move there, from
// POST /tasks/preview) leads in dashed amber from the tool to the cyan start.
import type { Vec3 } from "../robot/math";
import { tracePolyline, type Eye, type EyeSize, type OverlayPainter } from "../view/overlay";
import type { OverlayHost } from "./axes";
import type { CameraCalibration } from "./ball";
import { project, type Projection } from "./projection";

export type Pixel = [number, number] | null; // null: behind the camera
export const PATH_RGB = [0, 255, 255] as const;
export const APPROACH_RGB = [255, 190, 0] as const;
const APPROACH_DASH = [10, 8]; // camera pixels
const LINE_WIDTH = 4; // camera pixels
const START_RADIUS = 6;
const END_RADIUS = 4;
const ARROW_LENGTH = 16;
/** The most points drawn (the server's task path has at most 400 too). */
export const MAX_PATH_POINTS = 400;

/** The path in one camera's pixels. */
export function projectPath(P: Projection, points: readonly Vec3[]): Pixel[] {
  return points.map((p) => project(P, p));
}

/** At most `max` of `points`, evenly spread, the first and the last kept. */
export function thin<T>(points: readonly T[], max = MAX_PATH_POINTS): T[] {
  const n = points.length;
  if (n <= max) return points.slice();
  const out: T[] = [];
  let last = -1;
  for (let k = 0; k < max; k++) {
    const i = Math.round((k * (n - 1)) / (max - 1));
    if (i !== last) out.push(points[i]!);
    last = i;
  }
  return out;
}

/** One recorded state as the recording's timeline gives it (`t`: server clock, s). */
/** The path's length (m). */
export function pathLength(points: readonly Vec3[]): number {
  let sum = 0;
  for (let i = 1; i < points.length; i++) {
    const a = points[i - 1]!;
    const b = points[i]!;
    sum += Math.hypot(b[0] - a[0], b[1] - a[1], b[2] - a[2]);
  }
  return sum;
}

/** The last visible segment's direction at the path's end, for the arrowhead (null: none). */
export function endDirection(pixels: readonly Pixel[], minPx = 1): [number, number] | null {
  const end = [...pixels].reverse().find((p) => p !== null);
  if (!end) return null;
  for (let i = pixels.length - 1; i >= 0; i--) {
    const p = pixels[i];
    if (!p) continue;
    const d = Math.hypot(end[0] - p[0], end[1] - p[1]);
    if (d >= minPx) return [(end[0] - p[0]) / d, (end[1] - p[1]) / d];
  }
  return null;
}

export class PathOverlay implements OverlayPainter {
  /** The path as drawn, in the left and the right camera's pixels (empty: none). */
  readonly pixels: [Pixel[], Pixel[]] = [[], []];
  /** The path shown (base frame), or null. */
  points: Vec3[] | null = null;
  /** The approach to its start shown (base frame; empty: none). */
  approach: Vec3[] = [];
  /** The approach as drawn, in the left and the right camera's pixels. */
  readonly approachPixels: [Pixel[], Pixel[]] = [[], []];
  private P: [Projection, Projection] | null = null;

  /** `cameras`: the left camera's, then the right's; `host`: the stereo view. */
  constructor(
    cameras: readonly CameraCalibration[],
    private readonly host: OverlayHost | null,
  ) {
    this.setCameras(cameras);
    host?.addOverlay(this);
  }

  /** Other cameras (a restarted server, maybe with another arm): a path shown is the old
   * server's and goes. */
  setCameras(cameras: readonly CameraCalibration[]): void {
    const [l, r] = cameras;
    this.P = l && r ? [l.P, r.P] : null;
    this.clear();
  }

  get shown(): boolean {
    return this.points !== null && this.points.length > 0;
  }

  /** Show `points` (base frame, m), led into by `approach` (the tool's way to their
   * start; none by default); the overlay is redrawn only if they differ from what is shown. */
  show(points: readonly Vec3[], approach: readonly Vec3[] = []): void {
    const next = points.map((p) => [p[0], p[1], p[2]] as Vec3);
    const lead = approach.map((p) => [p[0], p[1], p[2]] as Vec3);
    if (this.points && samePoints(this.points, next) && samePoints(this.approach, lead)) return;
    this.points = next;
    this.approach = lead;
    for (const eye of [0, 1] as const) {
      this.pixels[eye] = this.P ? projectPath(this.P[eye], next) : [];
      this.approachPixels[eye] = this.P ? projectPath(this.P[eye], lead) : [];
    }
    this.host?.overlayChanged();
  }

  /** Hide the path (a redraw only if one was shown). */
  clear(): void {
    if (this.points === null) return;
    this.points = null;
    this.approach = [];
    this.pixels[0] = [];
    this.pixels[1] = [];
    this.approachPixels[0] = [];
    this.approachPixels[1] = [];
    this.host?.overlayChanged();
  }

  paint(ctx: CanvasRenderingContext2D, eye: Eye, size: EyeSize): void {
    const px = this.pixels[eye];
    if (!this.shown || px.length === 0) return;
    const scale = Math.max(1, size.width / 640);
    const [r, g, b] = PATH_RGB;
    const colour = `rgb(${r}, ${g}, ${b})`;
    ctx.save();
    ctx.lineCap = "round";
    ctx.lineJoin = "round";
    const lead = this.approachPixels[eye];
    if (lead.length > 1) {
      // The approach first, dashed, so the path's cyan start dot stays on top of its end.
      const [ar, ag, ab] = APPROACH_RGB;
      ctx.setLineDash(APPROACH_DASH.map((d) => d * scale));
      for (const [style, width] of [
        ["rgba(0, 0, 0, 0.5)", (LINE_WIDTH + 1) * scale],
        [`rgb(${ar}, ${ag}, ${ab})`, (LINE_WIDTH - 1) * scale],
      ] as const) {
        ctx.strokeStyle = style;
        ctx.lineWidth = width;
        ctx.beginPath();
        tracePolyline(ctx, lead);
        ctx.stroke();
      }
      ctx.setLineDash([]);
    }
    // A dark outline under the cyan line, so it reads on a bright background.
    for (const [style, width] of [
      ["rgba(0, 0, 0, 0.5)", (LINE_WIDTH + 3) * scale],
      [colour, LINE_WIDTH * scale],
    ] as const) {
      ctx.strokeStyle = style;
      ctx.lineWidth = width;
      ctx.beginPath();
      tracePolyline(ctx, px);
      ctx.stroke();
    }
    ctx.fillStyle = colour;
    const start = px.find((p) => p !== null);
    if (start) {
      ctx.beginPath();
      ctx.arc(start[0], start[1], START_RADIUS * scale, 0, 2 * Math.PI);
      ctx.fill();
    }
    const end = [...px].reverse().find((p) => p !== null);
    if (end) {
      const dir = endDirection(px);
      ctx.beginPath();
      if (dir) {
        // An arrowhead pointing along the path's last segment, its tip at the end.
        const len = ARROW_LENGTH * scale;
        const [dx, dy] = dir;
        ctx.moveTo(end[0], end[1]);
        ctx.lineTo(end[0] - len * dx - 0.5 * len * dy, end[1] - len * dy + 0.5 * len * dx);
        ctx.lineTo(end[0] - len * dx + 0.5 * len * dy, end[1] - len * dy - 0.5 * len * dx);
        ctx.closePath();
      } else ctx.arc(end[0], end[1], END_RADIUS * scale, 0, 2 * Math.PI);
      ctx.fill();
    }
    ctx.restore();
  }
}

function samePoints(a: readonly Vec3[], b: readonly Vec3[]): boolean {
  return a.length === b.length && a.every((p, i) => p[0] === b[i]![0] && p[1] === b[i]![1] && p[2] === b[i]![2]);
}
