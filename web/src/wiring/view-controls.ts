// The view's own controls: its mode (side-by-side, anaglyph…), this browser's saved
// alignment, the WebXR button, full screen, the link to the 3D view, and the operator's
// name field.
import { Alignment } from "../ui/alignment";
import { $ } from "../ui/dom";
import { setupNameField } from "../ui/operator-name";
import { link3dView, setupFullscreen, setupModes, setupXRButton } from "../ui/view";
import type { ViewMode } from "../view/stereo";
import type { PageContext } from "./context";

export interface ViewControlsHandle {
  setMode: (mode: ViewMode) => void;
  alignment: Alignment;
  toggleFullscreen: () => void;
}

export async function setupViewControls(ctx: PageContext): Promise<ViewControlsHandle> {
  const { api, log, view } = ctx;
  const setMode = setupModes(view);
  const alignment = await Alignment.load(view, api, ctx.viewer, log);
  setupXRButton(view, log);
  const toggleFullscreen = setupFullscreen($("stage"), log);
  link3dView(api);
  setupNameField($<HTMLInputElement>("operator-name"), $("name-status"), localStorage, ctx.pageName, navigator.platform);
  return { setMode, alignment, toggleFullscreen };
}
