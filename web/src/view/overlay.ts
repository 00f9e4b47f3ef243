// The overlay layer of the stereo view: what other modules draw over the video, in each
// camera's own pixels. StereoView keeps one hidden 2D canvas (the left eye's image on the
// left half, the right eye's on the right, at OVERLAY_SCALE of the video's resolution),
// calls every painter once per eye when something changed, and uploads it as a second
// texture that the shader composites at the same pixel as the video (so the right
// image's alignment shift moves it too, and it is shown in every mode and in WebXR).

import { canvas2d } from "../canvas2d";

export type Eye = 0 | 1; // 0: the left camera's image, 1: the right camera's
export interface EyeSize {
  width: number;
  height: number;
} // one camera's image, in its pixels
/** Drawn over the video in both eyes, in every view mode and in WebXR, in each camera's own
 * pixel coordinates (origin at the top-left of that camera's full image, as the calibration's P projects). */
export interface OverlayPainter {
  paint(ctx: CanvasRenderingContext2D, eye: Eye, size: EyeSize): void;
}

/** Add a line through `points` to the context's current path, broken where a point is
 * null (behind the camera): for painters of chains and paths. */
export function tracePolyline(ctx: Pick<CanvasRenderingContext2D, "moveTo" | "lineTo">, points: readonly (readonly [number, number] | null)[]): void {
  let drawing = false;
  for (const p of points) {
    if (!p) {
      drawing = false;
      continue;
    }
    if (drawing) ctx.lineTo(p[0], p[1]);
    else ctx.moveTo(p[0], p[1]);
    drawing = true;
  }
}

/** The overlay's resolution against the video's: a software GPU (SwiftShader) uploads a
 * quarter of the pixels four times faster, and overlays are text and lines. */
export const OVERLAY_SCALE = 0.5;

/** One canvas for both eyes; `paint` redraws it with every painter, each eye in its half. */
export class OverlayCanvas {
  readonly canvas: HTMLCanvasElement;
  private readonly ctx: CanvasRenderingContext2D;
  private readonly painters: OverlayPainter[] = [];
  private eye: EyeSize = { width: 0, height: 0 };
  /** Painters are called again before the next frame is drawn. */
  dirty = true;
  /** Painted over all the others (the view's own STALE warning). */
  top: OverlayPainter | null = null;

  constructor(readonly scale = OVERLAY_SCALE) {
    this.canvas = document.createElement("canvas");
    const ctx = canvas2d(this.canvas);
    if (!ctx) throw new Error("no 2D canvas for the overlay");
    this.ctx = ctx;
  }

  add(painter: OverlayPainter): void {
    this.painters.push(painter);
    this.dirty = true;
  }

  get empty(): boolean {
    return this.painters.length === 0;
  }

  /** Size the canvas for eyes of `size` (camera pixels); true when it changed. */
  resize(size: EyeSize): boolean {
    if (size.width === this.eye.width && size.height === this.eye.height) return false;
    this.eye = { ...size };
    this.canvas.width = Math.max(1, Math.round(2 * size.width * this.scale));
    this.canvas.height = Math.max(1, Math.round(size.height * this.scale));
    this.dirty = true;
    return true;
  }

  /** Call every painter for each eye (clipped to its half, in its camera's pixels). */
  paint(): void {
    const { ctx, canvas } = this;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    for (const eye of [0, 1] as const) {
      for (const painter of this.top ? [...this.painters, this.top] : this.painters) {
        ctx.save();
        ctx.setTransform(this.scale, 0, 0, this.scale, eye * this.eye.width * this.scale, 0);
        ctx.beginPath();
        ctx.rect(0, 0, this.eye.width, this.eye.height);
        ctx.clip();
        try {
          painter.paint(ctx, eye, { ...this.eye });
        } catch (e) {
          console.error("overlay painter failed", e);
        }
        ctx.restore();
      }
    }
    this.dirty = false;
  }
}
