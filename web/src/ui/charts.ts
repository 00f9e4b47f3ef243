// The small canvases of the operator's panels: inter-arrival histograms and the force arrow.
import type { Vec3 } from "../robot/math";
import type { Rolling } from "../stats";
import { canvas2d } from "../canvas2d";

export function drawHistogram(canvas: HTMLCanvasElement, stats: Rolling, max: number, label: string): void {
  const ctx = canvas2d(canvas);
  if (!ctx) return;
  const bins = stats.histogram(40, max);
  const top = Math.max(1, ...bins);
  ctx.fillStyle = "#111";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = "#4a8";
  bins.forEach((n, i) => {
    const h = (n / top) * (canvas.height - 14);
    ctx.fillRect((i * canvas.width) / bins.length, canvas.height - h, canvas.width / bins.length - 1, h);
  });
  ctx.fillStyle = "#ccc";
  ctx.font = "10px sans-serif";
  ctx.fillText(`${label} · p50 ${stats.percentile(50).toFixed(2)} p99 ${stats.percentile(99).toFixed(2)}`, 2, 10);
}

export function drawArrow(canvas: HTMLCanvasElement, f: Vec3, limit: number): void {
  const ctx = canvas2d(canvas);
  if (!ctx) return;
  ctx.fillStyle = "#111";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  const cx = canvas.width / 2;
  const cy = canvas.height / 2;
  const k = 50 / limit;
  // An oblique view of the sensor frame: x right, y up-right, z up.
  const ex = [1, 0];
  const ey = [0.5, -0.35];
  const ez = [0, -1];
  const tip = [cx + k * (f[0] * ex[0]! + f[1] * ey[0]! + f[2] * ez[0]!), cy + k * (f[0] * ex[1]! + f[1] * ey[1]! + f[2] * ez[1]!)];
  ctx.strokeStyle = "#555";
  for (const e of [ex, ey, ez]) {
    ctx.beginPath();
    ctx.moveTo(cx, cy);
    ctx.lineTo(cx + 40 * e[0]!, cy + 40 * e[1]!);
    ctx.stroke();
  }
  ctx.strokeStyle = "#f84";
  ctx.lineWidth = 3;
  ctx.beginPath();
  ctx.moveTo(cx, cy);
  ctx.lineTo(tip[0]!, tip[1]!);
  ctx.stroke();
  ctx.lineWidth = 1;
}
