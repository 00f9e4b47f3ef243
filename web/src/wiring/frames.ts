// The page's two frame loops: each animation frame the inputs become commands, the
// gamepad rumbles and the arms are drawn; each WebXR frame (a headset pauses the page's
// own animation frames) a controller, else a tracked hand, is a 6-DoF master whose grip
// (the hand's pinch) is the dead-man. Two arms: each hand its arm (input/arms.ts), each
// its clutch.
import { handArms } from "../input/arms";
import { XRMasterInput } from "../input/xr";
import { $ } from "../ui/dom";
import type { ArmDrawingHandle } from "./arm-drawing";
import type { PageContext } from "./context";
import type { InputsHandle } from "./inputs";

export function startFrames(ctx: PageContext, inputs: InputsHandle, drawing: ArmDrawingHandle): void {
  const { arms, view } = ctx;
  const { loop, rumble } = inputs;
  const xrInput = new XRMasterInput();
  view.onXRFrame = (frame, space) => {
    const now = performance.now();
    if (arms.list.length > 1) {
      const hands = xrInput.readHands(frame, space);
      loop.xrHands(hands, now);
      drawing.draw(); // the arms follow here too
      const to = handArms(loop.armNames);
      if (hands.left?.gamepad) rumble.driveXR(now, hands.left.gamepad, to.left, "left");
      if (hands.right?.gamepad) rumble.driveXR(now, hands.right.gamepad, to.right, "right");
      return;
    }
    const controller = xrInput.read(frame, space);
    loop.xrFrame(controller, now);
    const only = arms.list[0]!; // the ghost follows here too
    if (only.ghost.update(only.predicted.joints)) view.overlayChanged();
    if (controller?.gamepad) rumble.driveXR(now, controller.gamepad);
  };
  const tick = () => {
    const now = performance.now();
    const pad = loop.tick(now).pad;
    // The gamepad's left motor feels the first arm's force (one arm), the selected
    // arm's (one arm alone), or the left arm's with the right's on its right motor.
    const to = handArms(loop.armNames);
    const motors = arms.list.length === 1 ? undefined : loop.padMode === "one" ? { strong: loop.selected, weak: null } : { strong: to.left, weak: to.right };
    rumble.drivePad(now, pad, motors);
    drawing.draw();
    drawing.axes.update(loop.frame, inputs.selected().predicted.pose, loop.view, $<HTMLInputElement>("ar").checked);
    requestAnimationFrame(tick);
  };
  requestAnimationFrame(tick);
}
