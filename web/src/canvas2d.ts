// The live page's 2D canvases (the view's overlay, the panels' plots) are drawn on the CPU.
// In Chromium an accelerated 2D canvas on a software GPU (SwiftShader: no GPU, a VM, a
// headless browser) makes the page's main thread wait for the GPU process at each frame
// ("GPU backpressure via GL_COMMANDS_COMPLETED_CHROMIUM" in a trace): 1–4 s at a time on a
// 2-core machine, every ~3 s, long enough for the realtime worker to stop the dead-man
// heartbeats of a page that looked hung (bench.held_control measures it).
// These canvases are text, lines and small plots: the CPU draws them in well under a
// millisecond, and uploads the overlay to WebGL as a plain copy.
export function canvas2d(canvas: HTMLCanvasElement): CanvasRenderingContext2D | null {
  return canvas.getContext("2d", { willReadFrequently: true });
}
