// The page's keys and buttons around the input loop: the lease and e-stop buttons, the
// control-lost alerts (said over the video, with a sound), the help, and Escape, which
// closes an open dialog (the help…) and only that, else is the e-stop.
import type { RealtimeLink } from "../transport/link";
import type { Alignment } from "../ui/alignment";
import { type ControlWatch, showControlAlerts } from "../ui/control-alert";
import { setupControls } from "../ui/controls";
import { $ } from "../ui/dom";
import { HelpOverlay } from "../ui/help";
import { pageDialogs, routeKey } from "../ui/keys";
import type { PageContext } from "./context";
import type { ArmDrawingHandle } from "./arm-drawing";
import type { InputsHandle } from "./inputs";

export interface ControlsHandle {
  alarm: ReturnType<typeof showControlAlerts>;
  help: HelpOverlay;
}

export interface ControlsParts {
  link: RealtimeLink;
  control: ControlWatch;
  inputs: InputsHandle;
  drawing: ArmDrawingHandle;
  alignment: Alignment;
  toggleFullscreen: () => void;
}

export function setupPageControls(ctx: PageContext, parts: ControlsParts): ControlsHandle {
  const { link, control, inputs, drawing } = parts;
  const { loop, keyboard, gamepad } = inputs;
  loop.onArmChange = (why) => {
    // What a held key or dead-man drives has changed: it drives again once pressed anew.
    if (why !== "swap") keyboard.latch();
    if (why !== "select" || loop.padMode === "one") gamepad.latch();
    drawing.armChanged();
  };
  setupControls(loop, link);
  const alarm = showControlAlerts(control, [keyboard, gamepad], () => loop.take());
  loop.onRelease = () => control.released(); // handing back to a policy, too
  const arms = ctx.arms.list;
  const help = new HelpOverlay(document, $("help-button"), arms.map((a) => a.entry.name));
  ctx.late.help = help;
  const keyTargets = {
    dialogs: () => pageDialogs(document),
    help,
    loop,
    alignment: parts.alignment,
    fullscreen: parts.toggleFullscreen,
    deadmanHeld: () => keyboard.read().deadman,
  };
  keyboard.onKey = (key, e) => {
    routeKey(keyTargets, key, e);
    if (!e.repeat && !e.altKey && !e.ctrlKey && !e.metaKey) ctx.late.supervision?.key(key);
  };
  return { alarm, help };
}
