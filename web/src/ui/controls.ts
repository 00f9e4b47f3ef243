// The operator's buttons and the Driving panel, wired to the input loop and the link.
import { saveToken } from "../api";
import type { InputLoop } from "../input/loop";
import type { FrameName } from "../robot/model";
import { $ } from "./dom";

export function setupControls(loop: InputLoop, link: { reset(): void }): void {
  $("take").onclick = () => loop.take();
  $("release").onclick = () => loop.release();
  $("estop").onclick = () => loop.estop();
  $("reset").onclick = () => link.reset();
  $<HTMLInputElement>("token").onchange = (e) => {
    saveToken(localStorage, (e.target as HTMLInputElement).value);
    location.reload();
  };
  const frame = $<HTMLSelectElement>("frame");
  frame.onchange = () => {
    loop.frame = frame.value as FrameName;
  };
  loop.onFrameChange = (name) => {
    frame.value = name;
  };
  loop.onInputState = (text) => {
    $("input-state").textContent = text;
  };
}
