// Which input drives which arm, on a server with two arms or more (one arm: every input
// drives it, as always). Pure, so every case is tested (arms.test.ts).
//   XR: the left controller (or hand) drives the arm named "left", else the first; the
//       right the arm named "right", else the next one; each with its own grip clutch.
//   Gamepad, both arms (the default): L1 + the left stick (+ L2) drive the left arm,
//       R1 + the right stick (+ R2) the right one; Back/Select swaps to one arm (the
//       selected one, with the one-arm mapping: both sticks, R1) for fine work, and back.
//       D-pad ←/→ select the previous / next arm.
//   Keyboard: the keys drive the selected arm; [ and ] select the previous / next.
import { IDLE, combine, type MotionCommand } from "./motion";

/** The gamepad drives both arms at once (a side each) or the selected one alone. */
export type PadMode = "both" | "one";

/** Keys that select the arm the keys drive (KeyboardEvent.code): a step through the
 * arms, no wrap (with two, [ is the left and ] the right). */
export const ARM_KEYS: Readonly<Record<string, -1 | 1>> = { BracketLeft: -1, BracketRight: 1 };

/** Gamepad buttons (standard mapping) of the arms: Back/Select swaps both ↔ one, the
 * D-pad's left and right select. */
export const SWAP_BUTTON = 8;
export const PICK_BUTTONS: Readonly<Record<number, -1 | 1>> = { 14: -1, 15: 1 };

/** The arm each hand (and each side of the gamepad) drives: the arm named "left" (else
 * the first) and the one named "right" (else the first other than the left's). With
 * one arm both are it. */
export function handArms(names: readonly string[]): { left: number; right: number } {
  const named = (n: string) => names.indexOf(n);
  const left = named("left") >= 0 ? named("left") : 0;
  let right = named("right");
  if (right < 0 || right === left) right = names.length > 1 ? (left === 1 ? 0 : 1) : left;
  return { left, right };
}

/** The selected arm after a step (-1, +1), kept within the arms. */
export function stepArm(selected: number, step: number, count: number): number {
  return Math.max(0, Math.min(count - 1, selected + step));
}

/** What the gamepad gives each frame (gamepad.ts): the one-arm command, and each side's. */
export interface PadCommands {
  command: MotionCommand;
  left?: MotionCommand | undefined;
  right?: MotionCommand | undefined;
}

export interface Routing {
  count: number;
  /** The arm the keys drive (and the gamepad in "one"). */
  selected: number;
  padMode: PadMode;
  hands: { left: number; right: number };
}

/** Each arm's command this frame (index as the arms): one arm takes the gamepad's and
 * the keys' together; with more, the keys drive the selected arm, and the gamepad
 * either each side's arm ("both") or the selected one with the one-arm mapping. */
export function armCommands(r: Routing, pad: PadCommands, keys: MotionCommand): MotionCommand[] {
  if (r.count <= 1) return [combine(pad.command, keys)];
  const out: MotionCommand[] = Array.from({ length: r.count }, () => IDLE);
  const add = (i: number, c: MotionCommand | undefined) => {
    if (c && i >= 0 && i < r.count) out[i] = combine(out[i]!, c);
  };
  add(r.selected, keys);
  if (r.padMode === "one") add(r.selected, pad.command);
  else {
    add(r.hands.left, pad.left);
    add(r.hands.right, pad.right);
  }
  return out;
}

/** What the inputs drive now, said under Driving ("keys: left · gamepad: both arms"). */
export function routingText(names: readonly string[], r: Routing): string {
  if (r.count <= 1) return "";
  const sel = names[r.selected] ?? `arm ${r.selected + 1}`;
  const pad = r.padMode === "one" ? `${sel} alone` : `${names[r.hands.left] ?? "?"} (L1, left stick) + ${names[r.hands.right] ?? "?"} (R1, right stick)`;
  return `keys: ${sel} · gamepad: ${pad}`;
}
