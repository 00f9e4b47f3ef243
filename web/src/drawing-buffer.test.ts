import { describe, expect, it } from "vitest";
import { drawingBufferSize } from "./view/stereo";

const CAMERA = { width: 2560, height: 692 }; // 2×1280×720 side by side, 28 rows cropped

describe("drawingBufferSize", () => {
  it("draws as many pixels as the box shows on the screen", () => {
    expect(drawingBufferSize(CAMERA, { width: 640, height: 173 }, 1)).toEqual({ width: 640, height: 173 });
    // A screen of 2 device pixels to a CSS pixel shows twice as many each way.
    expect(drawingBufferSize(CAMERA, { width: 640, height: 173 }, 2)).toEqual({ width: 1280, height: 346 });
  });

  it("keeps the picture's shape whatever the box's", () => {
    const { width, height } = drawingBufferSize(CAMERA, { width: 1000, height: 100 }, 1);
    expect(width / height).toBeCloseTo(CAMERA.width / CAMERA.height, 1);
    expect(height).toBe(100);
  });

  it("never draws more than the camera's own pixels", () => {
    expect(drawingBufferSize(CAMERA, { width: 3000, height: 900 }, 2)).toEqual(CAMERA);
  });

  it("draws the camera's pixels until it is laid out, or in a box of nothing", () => {
    expect(drawingBufferSize(CAMERA, null, 1)).toEqual(CAMERA);
    expect(drawingBufferSize(CAMERA, { width: 0, height: 0 }, 1)).toEqual(CAMERA);
    expect(drawingBufferSize(CAMERA, { width: 1, height: 1 }, 1)).toEqual({ width: 1, height: 1 });
  });
});
