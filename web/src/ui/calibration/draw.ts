// Drawing on the frozen images: the clicks, and the fit to judge by eye (every fiducial
// where the model puts it, and the fiducial frame's axes); the loupe.
import { project, type Projection } from "../../ar/projection";
import type { Vec3 } from "../../robot/math";
import type { Pixel } from "./clicks";

const AXES = ["#ff4040", "#40ff40", "#4080ff"]; // x, y, z of the fiducial frame
const LOUPE_ZOOM = 8;

export function drawImage(canvas: HTMLCanvasElement, image: ImageData | undefined, clicks: readonly Pixel[], fit?: { P: Projection; fiducials: Vec3[] }): void {
  const g = canvas.getContext("2d")!;
  if (image) g.putImageData(image, 0, 0);
  g.lineWidth = 1.5;
  clicks.forEach(([u, v], i) => {
    g.strokeStyle = "#ff0";
    g.beginPath();
    g.moveTo(u - 8, v);
    g.lineTo(u + 8, v);
    g.moveTo(u, v - 8);
    g.lineTo(u, v + 8);
    g.stroke();
    g.fillStyle = "#ff0";
    g.fillText(String(i + 1), u + 6, v - 6);
  });
  if (!fit) return;
  const pts = fit.fiducials.map((p) => project(fit.P, p));
  g.strokeStyle = "#0ff";
  for (const p of pts) {
    if (!p) continue;
    g.beginPath();
    g.arc(p[0], p[1], 6, 0, 2 * Math.PI);
    g.stroke();
  }
  const o = pts[0];
  for (let k = 1; k <= 3; k++) {
    const p = pts[k];
    if (!o || !p) continue;
    g.strokeStyle = AXES[k - 1]!;
    g.lineWidth = 2.5;
    g.beginPath();
    g.moveTo(o[0], o[1]);
    g.lineTo(p[0], p[1]);
    g.stroke();
  }
}

/** The image around (u, v), magnified, with the pixel under the pointer marked. */
export function drawLoupe(loupe: HTMLCanvasElement, source: HTMLCanvasElement, u: number, v: number): void {
  const l = loupe.getContext("2d")!;
  l.imageSmoothingEnabled = false;
  const half = 100 / LOUPE_ZOOM;
  l.clearRect(0, 0, 200, 200);
  l.drawImage(source, u - half, v - half, 2 * half, 2 * half, 0, 0, 200, 200);
  l.strokeStyle = "#f0f";
  l.strokeRect(99, 99, 2, 2);
}

/** A pointer event's position in the canvas's own pixels. */
export function toPixel(canvas: HTMLCanvasElement, e: MouseEvent): Pixel {
  const r = canvas.getBoundingClientRect();
  return [((e.clientX - r.left) * canvas.width) / r.width, ((e.clientY - r.top) * canvas.height) / r.height];
}
