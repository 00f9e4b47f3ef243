// The two camera images, frozen from the stereo video (left half, right half), each
// on its canvas with the clicks drawn over it.
import type { Vec3 } from "../../robot/math";
import type { Projection } from "../../ar/projection";
import { $ } from "../dom";
import { CAMERAS, type CameraName, type Clicks } from "./clicks";
import { drawImage } from "./draw";

export class FrozenImages {
  readonly frozen: Partial<Record<CameraName, ImageData>> = {};
  readonly canvases: Record<CameraName, HTMLCanvasElement> = { left: $<HTMLCanvasElement>("left"), right: $<HTMLCanvasElement>("right") };

  constructor(
    private readonly video: HTMLVideoElement,
    private readonly clicks: Clicks,
  ) {}

  get ready(): boolean {
    return this.frozen.left !== undefined;
  }

  /** Draw the video's current frame on each image not frozen yet: the boxes show the
   * scene live until it is frozen (blank boxes looked broken). False with no video yet. */
  live(): boolean {
    const w = this.video.videoWidth / 2;
    const h = this.video.videoHeight;
    if (!w || !h) return false;
    CAMERAS.forEach((cam, i) => {
      if (this.frozen[cam]) return;
      const canvas = this.canvases[cam];
      if (canvas.width !== w || canvas.height !== h) [canvas.width, canvas.height] = [w, h];
      canvas.getContext("2d")!.drawImage(this.video, i * w, 0, w, h, 0, 0, w, h);
    });
    return true;
  }

  /** Freeze the video's current frame (each image's clicks start again); false with no video yet. */
  freeze(): boolean {
    if (!this.video.videoWidth) return false;
    const w = this.video.videoWidth / 2;
    const h = this.video.videoHeight;
    const whole = document.createElement("canvas");
    whole.width = 2 * w;
    whole.height = h;
    const g = whole.getContext("2d")!;
    g.drawImage(this.video, 0, 0);
    CAMERAS.forEach((cam, i) => {
      this.canvases[cam].width = w;
      this.canvases[cam].height = h;
      this.frozen[cam] = g.getImageData(i * w, 0, w, h);
      this.clicks.clear(cam);
      this.draw(cam);
    });
    return true;
  }

  /** The image, its clicks, and a fit's projection of the fiducials if given. */
  draw(cam: CameraName, fit?: { P: Projection; fiducials: Vec3[] }): void {
    drawImage(this.canvases[cam], this.frozen[cam], this.clicks.byCamera[cam], fit);
  }
}
