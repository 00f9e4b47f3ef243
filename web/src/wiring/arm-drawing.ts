// Each arm drawn in both eyes: its AR ball and ghost where its prediction is (with two
// arms or more the arms driven now at full strength, the others fainter), the selected
// arm's axis marker, and the header's chip for each arm (a click selects it).
import { AxisMarker } from "../ar/axes";
import { setupGhostSwitch } from "../ar/ghost";
import type { InputLoop } from "../input/loop";
import { ArmChipsView, armChips, armStyle, dimmed } from "../ui/arms";
import { $, numberIn } from "../ui/dom";
import { showBall } from "../ui/view";
import type { OverlayPainter } from "../view/stereo";
import type { PageContext } from "./context";
import type { PageArm } from "./page-arms";

export interface ArmDrawingHandle {
  /** The active frame's axes at the selected arm's gripper (shown with the AR ball). */
  axes: AxisMarker;
  chips: ArmChipsView;
  /** Another arm selected or driven: the axis marker moves to the selected arm, the
   * chips are drawn again at once (they also are every 200 ms). */
  armChanged(): void;
  /** Each arm's ball and ghost where its prediction is now. */
  draw(): void;
}

export function setupArmDrawing(ctx: PageContext, loop: InputLoop, selected: () => PageArm): ArmDrawingHandle {
  const { arms, view } = ctx;
  const first = arms.list[0]!;
  const axes = new AxisMarker(first.cameras, first.entry.model.tool.flat(), view);
  // The whole predicted arm, a translucent skeleton in both eyes (the "Ghost arm" switch);
  // each arm's, in its colour.
  const ghosts: OverlayPainter = { paint: (c, eye, size) => arms.list.forEach((a) => a.ghost.paint(c, eye, size)) };
  view.addOverlay(ghosts);
  setupGhostSwitch($<HTMLInputElement>("ghost"), { setEnabled: (on: boolean) => arms.setGhosts(on) }, localStorage, () => view.overlayChanged());
  const chips = new ArmChipsView($("arms"), (i) => loop.selectArm(i));
  const showChips = () =>
    chips.show(
      arms.list.length < 2
        ? []
        : armChips(
            arms.list.map((a, i) => ({
              name: a.entry.name,
              state: a.state,
              forceN: a.force ? Math.hypot(...a.force.values.slice(0, 3)) : null,
              selected: i === loop.selected,
              driven: loop.held.includes(i),
            })),
            ctx.safety.force_limit_n,
            $<HTMLInputElement>("ar-colour").value,
          ),
    );
  setInterval(showChips, 200);
  const draw = () => {
    if (arms.list.length === 1) {
      const only = arms.list[0]!;
      showBall(view, only.ball.update(only.predicted.pose));
      if (only.ghost.update(only.predicted.joints)) view.overlayChanged();
      return;
    }
    const driven = loop.driven;
    const show = $<HTMLInputElement>("ar").checked;
    const colour = $<HTMLInputElement>("ar-colour").value;
    const radius = numberIn("ar-size");
    arms.list.forEach((a, i) => {
      const on = driven.includes(i);
      view.setBall(a.ball.update(a.predicted.pose), show, dimmed(armStyle(i).ball ?? colour, on ? 1 : 0.6), radius, i);
      const moved = a.ghost.update(a.predicted.joints);
      if (a.ghost.setHighlight(on) || moved) view.overlayChanged();
    });
  };
  const armChanged = () => {
    const sel = selected();
    axes.setArm(sel.cameras, sel.entry.model.tool.flat());
    showChips();
  };
  return { axes, chips, armChanged, draw };
}
