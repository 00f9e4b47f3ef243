// ChArUco intrinsics: views of the board from both cameras (a printed board held up
// to real cameras, or the simulation's board at its 12 poses), sent to the server.
import type { Api, MessageLog } from "../../api";
import { $ } from "../dom";
import { CAMERAS, type CameraName } from "./clicks";

export const SIMULATED_POSES = 12;
export const MIN_VIEWS = 4;

/** Resolves after the video has presented `n` more frames. */
export function nextFrames(video: HTMLVideoElement, n: number): Promise<void> {
  return new Promise<void>((resolve) => {
    const step = (left: number) => (left <= 0 ? resolve() : video.requestVideoFrameCallback(() => step(left - 1)));
    step(n);
  });
}

export class BoardViews {
  /** JPEG data URLs of each camera's views, in the same order. */
  readonly views: Record<CameraName, string[]> = { left: [], right: [] };

  constructor(
    private readonly video: HTMLVideoElement,
    private readonly api: Api,
    private readonly log: MessageLog,
  ) {}

  /** The video's current frame, one view per camera. */
  add(): void {
    if (!this.video.videoWidth) return this.log.add("no video yet", true);
    const w = this.video.videoWidth / 2;
    const h = this.video.videoHeight;
    const eye = document.createElement("canvas");
    eye.width = w;
    eye.height = h;
    const g = eye.getContext("2d")!;
    CAMERAS.forEach((cam, i) => {
      g.drawImage(this.video, i * w, 0, w, h, 0, 0, w, h);
      this.views[cam].push(eye.toDataURL("image/jpeg", 0.95));
    });
    this.showCount();
  }

  /** Each camera's intrinsics from its views (then the views are let go). */
  async calibrate(): Promise<void> {
    for (const cam of CAMERAS) {
      const r = await this.api.request("post", "/api/v1/calibration/intrinsics/views", { body: { camera: cam, images: this.views[cam] } });
      this.log.add(`${cam}: intrinsics from ${r.views_used} of ${this.views[cam].length} views, rms ${r.rms_px.toFixed(2)} px`);
    }
    this.views.left = [];
    this.views.right = [];
    this.showCount();
  }

  /** On the simulation the server holds the board up at its poses in the live video
   * (with real cameras, hold a printed board and use "Add view" instead). */
  async captureSimulated(): Promise<void> {
    const putAway = () => this.api.request("post", "/api/v1/calibration/board", { body: { view: null } });
    try {
      for (let view = 0; view < SIMULATED_POSES; view++) {
        await this.api.request("post", "/api/v1/calibration/board", { body: { view } });
        await nextFrames(this.video, 4); // the new pose has reached the decoder
        this.add();
      }
    } catch (e) {
      await putAway().catch(() => undefined);
      throw e;
    }
    await putAway();
  }

  private showCount(): void {
    $("view-count").textContent = String(this.views.left.length);
    $<HTMLButtonElement>("use-views").disabled = this.views.left.length < MIN_VIEWS;
  }
}
