// The inputs → commands: the keyboard, the gamepad and (wiring/frames.ts) a WebXR
// controller or hand into one input loop; rumble in proportion to the contact force.
import { GamepadInput } from "../input/gamepad";
import { KeyboardInput } from "../input/keyboard";
import { InputLoop } from "../input/loop";
import { ContactRumble, rumbleStrength } from "../input/rumble";
import { viewFrame } from "../input/viewframe";
import type { RealtimeLink } from "../transport/link";
import { $, numberIn } from "../ui/dom";
import type { PageContext } from "./context";
import { type PageArm, driveArms } from "./page-arms";

export interface InputsHandle {
  keyboard: KeyboardInput;
  gamepad: GamepadInput;
  loop: InputLoop;
  rumble: ContactRumble;
  /** The arm the keys drive (and the gamepad alone). */
  selected(): PageArm;
}

export function setupInputs(ctx: PageContext, link: RealtimeLink): InputsHandle {
  const { arms, cell, view } = ctx;
  const keyboard = new KeyboardInput(window);
  const gamepad = new GamepadInput();
  const loop = new InputLoop({
    link,
    arm: arms.list[0]!.predicted,
    flags: () => arms.combined?.flags ?? 0,
    speed: () => numberIn("speed"),
    gamepad,
    keyboard,
    view: cell.cameras[0] ? viewFrame(cell.cameras[0].P) : null, // the left camera's
    now: performance.now(),
    policyHolds: () => ctx.late.supervision?.policyHolds ?? false,
  });
  loop.setArms(driveArms(arms.list));
  view.setBallCount(arms.list.length);
  const rumble = new ContactRumble((i) => {
    const f = arms.list[i]?.force;
    return f ? rumbleStrength(Math.hypot(...f.values.slice(0, 3)), ctx.safety.force_limit_n) : 0;
  });
  const rumbleBox = $<HTMLInputElement>("rumble");
  rumble.enabled = rumbleBox.checked;
  rumbleBox.onchange = () => (rumble.enabled = rumbleBox.checked);
  return { keyboard, gamepad, loop, rumble, selected: () => arms.list[loop.selected] ?? arms.list[0]! };
}
