// Drawing no faster than the GPU finishes. With a software GPU (SwiftShader) on a busy
// machine the GPU process falls behind, and a WebGL call that finds its command buffer
// full waits for it on the page's main thread: the page stood still 1–2.4 s at a time,
// its keys went unread and its dead-man heartbeats stopped (docs/PERFORMANCE.md, a page
// holding control). So a draw is never queued behind an unfinished one: the frame
// waits, and only the newest waiting one is drawn once the GPU is done. On a machine
// that keeps up every frame is drawn at once, as before.

/** While the GPU is behind, how often (ms) the pacer looks whether it has caught up. */
export const GPU_POLL_MS = 15;

export class DrawPacer {
  /** Frames never drawn: a newer one came while the GPU was still on an older draw. */
  skipped = 0;
  /** Draws put off until the GPU had finished the one before. */
  waited = 0;
  private pending = false;

  /** A draw is waiting for the GPU: what is shown is older than what was asked for. */
  get waiting(): boolean {
    return this.pending;
  }

  constructor(
    private readonly gpuBusy: () => boolean,
    private readonly draw: () => void,
    private readonly later: (f: () => void, ms: number) => void = (f, ms) => void setTimeout(f, ms),
  ) {}

  /** A new frame (or a change) wants drawing: now, or once the GPU is done. */
  request(): void {
    if (this.pending) {
      this.skipped += 1; // the waiting draw will show this newer frame instead
      return;
    }
    if (!this.gpuBusy()) return this.draw();
    this.pending = true;
    this.waited += 1;
    this.later(() => this.retry(), GPU_POLL_MS);
  }

  private retry(): void {
    if (this.gpuBusy()) return this.later(() => this.retry(), GPU_POLL_MS);
    this.pending = false;
    this.draw();
  }
}

/** The GPU's progress through WebGL 2 fences: `busy()` never blocks (a zero timeout).
 * Without WebGL 2 it is never busy (drawing as before). */
export class GpuFence {
  private sync: WebGLSync | null = null;

  constructor(private readonly gl: () => WebGL2RenderingContext | null) {}

  /** Mark the end of a draw just issued. */
  drew(): void {
    const gl = this.gl();
    if (!gl) return;
    if (this.sync !== null) gl.deleteSync(this.sync);
    this.sync = gl.fenceSync(gl.SYNC_GPU_COMMANDS_COMPLETE, 0);
    gl.flush(); // the fence goes now, not with the next draw
  }

  busy(): boolean {
    const gl = this.gl();
    if (!gl || this.sync === null) return false;
    if (gl.clientWaitSync(this.sync, 0, 0) === gl.TIMEOUT_EXPIRED) return true;
    gl.deleteSync(this.sync);
    this.sync = null;
    return false;
  }
}
