// The operator's buttons and the Driving panel, wired to the input loop and the link.
import { TRY_KEY } from "../api";
import type { DriveFrame, InputLoop } from "../input/loop";
import { $ } from "./dom";

export function setupControls(loop: InputLoop, link: { reset(): void }): void {
  $("take").onclick = () => loop.take();
  $("release").onclick = () => loop.release();
  $("estop").onclick = () => loop.estop();
  $("reset").onclick = () => link.reset();
  $<HTMLInputElement>("token").onchange = (e) => {
    // Tried once in this tab; remembered only if the server accepts it.
    sessionStorage.setItem(TRY_KEY, (e.target as HTMLInputElement).value);
    location.reload();
  };
  const frame = $<HTMLSelectElement>("frame");
  frame.onchange = () => {
    loop.frame = frame.value as DriveFrame;
  };
  frame.value = loop.frame; // the page's default (view), whatever the HTML says
  loop.onFrameChange = (name) => {
    frame.value = name;
  };
  loop.onInputState = (text) => {
    $("input-state").textContent = text;
  };
}
