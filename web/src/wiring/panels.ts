// The side panels (state, joints, force, links and latencies, the Home button), each
// showing the selected arm's where there are several.
import { startPanels } from "../ui/panels";
import type { PageContext } from "./context";
import type { InputsHandle } from "./inputs";
import type { RealtimeHandle } from "./realtime";
import type { VideoHandle } from "./video";

export function setupPanels(ctx: PageContext, realtime: RealtimeHandle, video: VideoHandle, inputs: InputsHandle): ReturnType<typeof startPanels> {
  const { arms } = ctx;
  const several = () => arms.list.length > 1;
  return startPanels({
    state: () => arms.combined,
    armState: () => inputs.selected().state,
    armName: () => (several() ? inputs.selected().entry.name : ""),
    arms: () => (several() ? arms.list.map((a) => a.entry.name) : []),
    force: () => inputs.selected().force,
    link: realtime.link,
    glass: video.glass,
    videoInterval: video.videoInterval,
    forceLimitN: ctx.safety.force_limit_n,
    controller: () => ctx.controller,
    policyHolds: () => ctx.late.supervision?.policyHolds ?? false,
    get jointNames() {
      return inputs.selected().entry.model.joint_names;
    },
    api: ctx.api,
    log: ctx.log,
  });
}
