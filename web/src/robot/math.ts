// Small 4×4 / 3×3 helpers (row-major number arrays): the robot model needs little.
export type Vec3 = [number, number, number];
export type Mat3 = number[]; // 9, row-major
export type Mat4 = number[]; // 16, row-major

export function identity4(): Mat4 {
  return [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];
}

export function mul4(a: Mat4, b: Mat4): Mat4 {
  const out = Array.from({ length: 16 }, () => 0);
  for (let i = 0; i < 4; i++)
    for (let j = 0; j < 4; j++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += (a[4 * i + k] ?? 0) * (b[4 * k + j] ?? 0);
      out[4 * i + j] = s;
    }
  return out;
}

export function fromRows(rows: number[][]): Mat4 {
  return rows.flat();
}

export function position(t: Mat4): Vec3 {
  return [t[3] ?? 0, t[7] ?? 0, t[11] ?? 0];
}

export function rotation(t: Mat4): Mat3 {
  return [t[0]!, t[1]!, t[2]!, t[4]!, t[5]!, t[6]!, t[8]!, t[9]!, t[10]!];
}

export function pose(r: Mat3, p: Vec3): Mat4 {
  return [r[0]!, r[1]!, r[2]!, p[0], r[3]!, r[4]!, r[5]!, p[1], r[6]!, r[7]!, r[8]!, p[2], 0, 0, 0, 1];
}

export function mul3(a: Mat3, b: Mat3): Mat3 {
  const out = Array.from({ length: 9 }, () => 0);
  for (let i = 0; i < 3; i++)
    for (let j = 0; j < 3; j++) {
      let s = 0;
      for (let k = 0; k < 3; k++) s += (a[3 * i + k] ?? 0) * (b[3 * k + j] ?? 0);
      out[3 * i + j] = s;
    }
  return out;
}

export function mulVec3(r: Mat3, v: Vec3): Vec3 {
  return [
    r[0]! * v[0] + r[1]! * v[1] + r[2]! * v[2],
    r[3]! * v[0] + r[4]! * v[1] + r[5]! * v[2],
    r[6]! * v[0] + r[7]! * v[1] + r[8]! * v[2],
  ];
}

/** Rodrigues: the rotation matrix of a rotation vector (axis × angle, radians). */
export function rotvecToMatrix(v: Vec3): Mat3 {
  const angle = Math.hypot(v[0], v[1], v[2]);
  if (angle < 1e-12) return [1, 0, 0, 0, 1, 0, 0, 0, 1];
  const [x, y, z] = [v[0] / angle, v[1] / angle, v[2] / angle];
  const c = Math.cos(angle);
  const s = Math.sin(angle);
  const t = 1 - c;
  return [
    t * x * x + c, t * x * y - s * z, t * x * z + s * y,
    t * x * y + s * z, t * y * y + c, t * y * z - s * x,
    t * x * z - s * y, t * y * z + s * x, t * z * z + c,
  ];
}

export function inverseRigid(t: Mat4): Mat4 {
  const r = rotation(t);
  const rt = [r[0]!, r[3]!, r[6]!, r[1]!, r[4]!, r[7]!, r[2]!, r[5]!, r[8]!];
  const p = mulVec3(rt, position(t));
  return pose(rt, [-p[0], -p[1], -p[2]]);
}

/** The rotation vector (axis × angle, radians) of a rotation matrix: rotvecToMatrix's inverse. */
export function matrixToRotvec(r: Mat3): Vec3 {
  const cos = Math.max(-1, Math.min(1, (r[0]! + r[4]! + r[8]! - 1) / 2));
  const angle = Math.acos(cos);
  if (angle < 1e-9) return [(r[7]! - r[5]!) / 2, (r[2]! - r[6]!) / 2, (r[3]! - r[1]!) / 2];
  if (Math.PI - angle < 1e-6) {
    // Half a turn: the axis is the column of R + I with the largest norm.
    const cols = [0, 1, 2].map((j) => [r[j]! + (j === 0 ? 1 : 0), r[3 + j]! + (j === 1 ? 1 : 0), r[6 + j]! + (j === 2 ? 1 : 0)] as Vec3);
    const best = cols.reduce((a, b) => (Math.hypot(...b) > Math.hypot(...a) ? b : a));
    const n = Math.hypot(...best);
    return [(best[0] / n) * angle, (best[1] / n) * angle, (best[2] / n) * angle];
  }
  const k = angle / (2 * Math.sin(angle));
  return [(r[7]! - r[5]!) * k, (r[2]! - r[6]!) * k, (r[3]! - r[1]!) * k];
}

/** Solve the square system A x = b (A: n×n rows) by Gaussian elimination with partial
 * pivoting; null if A is singular. */
export function solveLinear(A: number[][], b: number[]): number[] | null {
  const n = b.length;
  const m = A.map((row, i) => [...row, b[i]!]);
  for (let c = 0; c < n; c++) {
    let p = c;
    for (let r = c + 1; r < n; r++) if (Math.abs(m[r]![c]!) > Math.abs(m[p]![c]!)) p = r;
    if (Math.abs(m[p]![c]!) < 1e-14) return null;
    [m[c], m[p]] = [m[p]!, m[c]!];
    for (let r = c + 1; r < n; r++) {
      const f = m[r]![c]! / m[c]![c]!;
      for (let k = c; k <= n; k++) m[r]![k]! -= f * m[c]![k]!;
    }
  }
  const x = Array.from({ length: n }, () => 0);
  for (let r = n - 1; r >= 0; r--) {
    let s = m[r]![n]!;
    for (let k = r + 1; k < n; k++) s -= m[r]![k]! * x[k]!;
    x[r] = s / m[r]![r]!;
  }
  return x;
}

export function dot3(a: Vec3, b: Vec3): number {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

export function cross3(a: Vec3, b: Vec3): Vec3 {
  return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
}

/** `v` scaled to length 1 (the zero vector stays zero). */
export function normalize3(v: Vec3): Vec3 {
  const n = Math.hypot(v[0], v[1], v[2]);
  return n > 0 ? [v[0] / n, v[1] / n, v[2] / n] : [0, 0, 0];
}

/** The 3×3 matrix whose columns are `x`, `y`, `z`. */
export function fromColumns(x: Vec3, y: Vec3, z: Vec3): Mat3 {
  return [x[0], y[0], z[0], x[1], y[1], z[1], x[2], y[2], z[2]];
}

/** Column `j` of a 3×3 matrix. */
export function column3(r: Mat3, j: number): Vec3 {
  return [r[j]!, r[3 + j]!, r[6 + j]!];
}
