// Is the video still live? Frame arrivals are reported here; once none has come for the
// threshold the picture on screen is stale, however plausible it looks.

export class FrameWatch {
  /** When the last frame came (or the watch started, before the first one). */
  lastFrameAt: number;

  constructor(
    readonly thresholdMs: number,
    private readonly now: () => number,
  ) {
    this.lastFrameAt = now();
  }

  frame(at = this.now()): void {
    this.lastFrameAt = at;
  }

  /** How long since the last frame (ms) once that is at least the threshold; null while live. */
  stale(at = this.now()): number | null {
    const since = at - this.lastFrameAt;
    return since >= this.thresholdMs ? since : null;
  }
}
