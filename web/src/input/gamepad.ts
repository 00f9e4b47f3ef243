// Gamepad API, standard mapping: left stick x/y → y/x, right stick y → z, right
// stick x → yaw, triggers → pitch; R1 (button 5) is the dead-man; Y cycles the frame.
// Each side on its own too, for two arms (input/arms.ts): L1 (button 4) and the left
// stick, R1 and the right stick; the stick moves forward/back and left/right, and with
// its trigger (L2, R2) pulled halfway up/down and turns. Back/Select (button 8) swaps
// between both arms and one; the D-pad's left and right (14, 15) select the arm.
import { PICK_BUTTONS, SWAP_BUTTON } from "./arms";
import { type MotionCommand, IDLE, deadzone } from "./motion";

export interface GamepadState {
  command: MotionCommand;
  cycleFrame: boolean;
  pad: Gamepad | null;
  /** Each side's command (two arms: L1 + left stick, R1 + right stick). */
  left?: MotionCommand;
  right?: MotionCommand;
  /** Back/Select went down: both arms ↔ one. */
  swapArms?: boolean;
  /** The D-pad picked the previous (−1) or next (+1) arm; 0: neither. */
  pickArm?: number;
}

/** A trigger pulled this far turns its side's stick to up/down and yaw. */
export const SHIFT_TRIGGER = 0.5;
const L1 = 4;
const R1 = 5;

export class GamepadInput {
  deadzone = 0.15;
  private was = new Set<number>(); // the edge-triggered buttons held at the last read
  // Each dead-man held through a loss of control: ignored until released.
  private readonly latched = new Set<number>();

  /** Control was lost or the arm halted: a held dead-man stops driving until released. */
  latch(): void {
    this.latched.add(L1).add(R1);
  }

  read(): GamepadState {
    const pads = navigator.getGamepads ? navigator.getGamepads() : [];
    const pad = [...pads].find((p): p is Gamepad => p !== null && p.connected) ?? null;
    if (!pad) return { command: IDLE, cycleFrame: false, pad: null };
    const ax = (i: number) => deadzone(pad.axes[i] ?? 0, this.deadzone);
    const btn = (i: number) => pad.buttons[i]?.pressed ?? false;
    const value = (i: number) => pad.buttons[i]?.value ?? 0;
    for (const b of [L1, R1]) if (!btn(b)) this.latched.delete(b);
    const deadman = (b: number) => btn(b) && !this.latched.has(b);
    const pressed = (i: number) => btn(i) && !this.was.has(i);
    const pick = Object.entries(PICK_BUTTONS).find(([b]) => pressed(Number(b)))?.[1] ?? 0;
    const state: GamepadState = {
      pad,
      cycleFrame: pressed(3),
      swapArms: pressed(SWAP_BUTTON),
      pickArm: pick,
      command: {
        deadman: deadman(R1),
        linear: [-ax(1), -ax(0), -ax(3)],
        angular: [0, value(7) - value(6), -ax(2)],
      },
      left: side(deadman(L1), ax(0), ax(1), value(6)),
      right: side(deadman(R1), ax(2), ax(3), value(7)),
    };
    this.was = new Set([3, SWAP_BUTTON, ...Object.keys(PICK_BUTTONS).map(Number)].filter(btn));
    return state;
  }
}

/** One side's command: the stick forward/back and left/right, or with the trigger
 * pulled, up/down and yaw. */
export function side(deadman: boolean, x: number, y: number, trigger: number): MotionCommand {
  if (trigger >= SHIFT_TRIGGER) return { deadman, linear: [0, 0, -y], angular: [0, 0, -x] };
  return { deadman, linear: [-y, -x, 0], angular: [0, 0, 0] };
}
