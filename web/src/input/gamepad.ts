// Gamepad API, standard mapping: left stick x/y → y/x, right stick y → z, right
// stick x → yaw, triggers → pitch; R1 (button 5) is the dead-man; Y cycles the frame.
import { type MotionCommand, IDLE, deadzone } from "./motion";

export interface GamepadState {
  command: MotionCommand;
  cycleFrame: boolean;
  pad: Gamepad | null;
}

export class GamepadInput {
  deadzone = 0.15;
  private wasCycle = false;
  private latched = false; // the dead-man held through a loss of control: ignored until released

  /** Control was lost or the arm halted: a held dead-man stops driving until released. */
  latch(): void {
    this.latched = true;
  }

  read(): GamepadState {
    const pads = navigator.getGamepads ? navigator.getGamepads() : [];
    const pad = [...pads].find((p): p is Gamepad => p !== null && p.connected) ?? null;
    if (!pad) return { command: IDLE, cycleFrame: false, pad: null };
    const ax = (i: number) => deadzone(pad.axes[i] ?? 0, this.deadzone);
    const btn = (i: number) => pad.buttons[i]?.pressed ?? false;
    const value = (i: number) => pad.buttons[i]?.value ?? 0;
    if (!btn(5)) this.latched = false;
    const cycle = btn(3);
    const cycleFrame = cycle && !this.wasCycle;
    this.wasCycle = cycle;
    return {
      pad,
      cycleFrame,
      command: {
        deadman: btn(5) && !this.latched,
        linear: [-ax(1), -ax(0), -ax(3)],
        angular: [0, value(7) - value(6), -ax(2)],
      },
    };
  }
}
