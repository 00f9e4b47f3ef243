// The AR ball: where the (predicted) gripper is, projected into each camera's image
// with the calibration (or the simulated cameras' ground truth until there is one).
import type { Schema } from "../api";
import { position, type Mat4 } from "../robot/math";
import type { Ball } from "../view/stereo";
import { project } from "./projection";

export type CameraCalibration = Pick<Schema<"CameraCalibration">, "name" | "P">;

export class ArBall {
  /** Pixels in the left and the right image; null until there is a pose. */
  readonly ball: Ball = { left: null, right: null };
  private left: CameraCalibration | undefined;
  private right: CameraCalibration | undefined;

  /** `cameras`: the left camera's, then the right's. */
  constructor(cameras: readonly CameraCalibration[]) {
    this.setCameras(cameras);
  }

  /** Other cameras (a restarted server): the ball is not drawn until the next pose. */
  setCameras(cameras: readonly CameraCalibration[]): void {
    [this.left, this.right] = cameras;
    this.ball.left = this.ball.right = null;
  }

  /** Move the ball to the tool pose `T` (the last place stays while there is none). */
  update(T: Mat4 | null): Ball {
    if (T && this.left && this.right) {
      const p = position(T);
      this.ball.left = project(this.left.P, p);
      this.ball.right = project(this.right.P, p);
    }
    return this.ball;
  }
}
