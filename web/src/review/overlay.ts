// What the review draws over the recorded picture, per arm and per eye: the ghost arm and
// the AR ball at the recorded *predicted* pose (the commanded target joints, as the live
// page draws them) beside a thin ring at the recorded actual tool position, projected
// with the calibration in force at that moment — a multi-arm recording's each arm through
// P · its mount, labelled by its name. And, for tests, those pixels (`overlay`).
import { GHOST_RGB, type Pixel, ghostChain } from "../ar/ghost";
import { project, type Projection } from "../ar/projection";
import { tracePolyline } from "../view/overlay";
import { mountedProjection } from "./arms";
import type { Picture } from "./player";
import { armStatesAt, camerasAt, type ArmModel, type ArmState, type ReviewContext } from "./recording";
import type { ReviewTestView } from "./test-view";

/** One arm's tool in each eye (0 left, 1 right): predicted and actual, camera pixels. */
export interface ArmPixels {
  predicted: (Pixel | null)[];
  actual: (Pixel | null)[];
}
/** What the overlay shows now, per eye: the first arm's tools, and every arm's by name. */
export interface OverlayPixels extends ArmPixels {
  arms: Record<string, ArmPixels>;
}

export interface OverlayHandle {
  /** Draws over the picture at timeline time t (drawn first: see PlayerHandle.drawPicture). */
  update(t: number): void;
  testView: Pick<ReviewTestView, "overlay">;
}

/** Nothing shown yet, for the arms named. */
export function emptyOverlay(armNames: readonly string[]): OverlayPixels {
  return { predicted: [null, null], actual: [null, null], arms: Object.fromEntries(armNames.map((a) => [a, { predicted: [null, null], actual: [null, null] }])) };
}

/** An arm in one eye through projection P: the ghost's joints (none without a model or a
 * commanded pose for it), its tool (the ball; null: none or behind the camera), and where
 * the tool actually was (the ring). */
export function armInEye(model: ArmModel | null | undefined, state: ArmState | undefined, P: Projection): { chain: Pixel[]; tool: Pixel; actual: Pixel } {
  const p = state?.position;
  const q = state?.target_joints;
  const chain = model && q && q.length === model.joints.length ? ghostChain(model, q, P) : [];
  const actual = p && p.length === 3 ? project(P, [p[0] ?? 0, p[1] ?? 0, p[2] ?? 0]) : null;
  return { chain, tool: chain[chain.length - 1] ?? null, actual };
}

export function setupOverlay({ recording }: ReviewContext, picture: Picture): OverlayHandle {
  const { arms, models, several } = recording;
  const { canvas, context, shown } = picture;
  const overlay = emptyOverlay(arms.map((a) => a.name));
  return {
    update(t) {
      if (!context) return;
      const cameras = camerasAt(recording, t);
      const now = armStatesAt(recording, t);
      arms.forEach((arm, k) => {
        const drawn = overlay.arms[arm.name] ?? { predicted: [null, null], actual: [null, null] };
        cameras.slice(0, 2).forEach((cam, eye) => {
          if (cam.P.length !== 3) return;
          // An arm's pose is in its own base frame: drawn through P · its mount.
          const P = several ? mountedProjection(cam.P, arm.mount) : cam.P;
          const { chain, tool, actual } = armInEye(models[k], now[k], P);
          drawn.predicted[eye] = tool;
          drawn.actual[eye] = actual;
          if (k === 0) {
            overlay.predicted[eye] = tool;
            overlay.actual[eye] = actual;
          }
          context.save();
          context.translate((eye * canvas.width) / 2, -shown.crop); // camera pixels, stripe cropped
          drawArm(context, chain, tool, actual, several ? arm.name : null);
          context.restore();
        });
      });
    },
    testView: { overlay },
  };
}

/** A circle's outline at `at` (camera pixels). */
function ring(context: CanvasRenderingContext2D, at: NonNullable<Pixel>, radius: number, colour: string, width: number): void {
  context.strokeStyle = colour;
  context.lineWidth = width;
  context.beginPath();
  context.arc(at[0], at[1], radius, 0, 2 * Math.PI);
  context.stroke();
}

/** One arm in one eye: the ghost arm and the ball where the gripper was commanded to be,
 * a thin white ring where it actually was, and (several arms) its name by the ball. */
function drawArm(context: CanvasRenderingContext2D, chain: readonly Pixel[], tool: Pixel, actual: Pixel, name: string | null): void {
  if (chain.length) {
    const [r, g, b] = GHOST_RGB;
    context.strokeStyle = `rgba(${r}, ${g}, ${b}, 0.45)`;
    context.lineWidth = 7;
    context.lineCap = context.lineJoin = "round";
    context.beginPath();
    tracePolyline(context, chain);
    context.stroke();
  }
  if (tool) ring(context, tool, 12, "#0f0", 3);
  if (actual) ring(context, actual, 6, "#fff", 1); // where it actually was: a thin white ring
  if (name !== null && tool) {
    context.fillStyle = "#fff";
    context.fillText(name, tool[0] + 14, tool[1] - 14);
  }
}
