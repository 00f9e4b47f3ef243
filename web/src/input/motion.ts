// What every input device produces each frame: a velocity command while the
// dead-man is held. Velocities are in [-1, 1] and scaled by the speed setting.
export interface MotionCommand {
  deadman: boolean;
  linear: [number, number, number]; // base/wrist/tool axes x y z
  angular: [number, number, number];
}

export const IDLE: MotionCommand = { deadman: false, linear: [0, 0, 0], angular: [0, 0, 0] };

export function deadzone(v: number, zone: number): number {
  if (Math.abs(v) <= zone) return 0;
  return (Math.sign(v) * (Math.abs(v) - zone)) / (1 - zone);
}

export function combine(a: MotionCommand, b: MotionCommand): MotionCommand {
  const add = (x: number[], y: number[]) => x.map((v, i) => Math.max(-1, Math.min(1, v + (y[i] ?? 0)))) as [number, number, number];
  return { deadman: a.deadman || b.deadman, linear: add(a.linear, b.linear), angular: add(a.angular, b.angular) };
}
