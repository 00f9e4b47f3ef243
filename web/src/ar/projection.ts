// Pinhole projection with a 3×4 matrix (the calibration's, or the simulated
// camera's ground truth until a calibration exists).
import type { Vec3 } from "../robot/math";

export type Projection = number[][]; // 3 × 4

export function project(P: Projection, p: Vec3): [number, number] | null {
  const row = (i: number) => {
    const r = P[i] ?? [0, 0, 0, 0];
    return (r[0] ?? 0) * p[0] + (r[1] ?? 0) * p[1] + (r[2] ?? 0) * p[2] + (r[3] ?? 0);
  };
  const w = row(2);
  if (w <= 1e-9) return null; // behind the camera
  return [row(0) / w, row(1) / w];
}
