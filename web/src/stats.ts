// Rolling statistics for the live panels (the thesis's histograms, live).
export class Rolling {
  private values: number[] = [];
  private last: number | null = null;

  constructor(private readonly capacity = 600) {}

  /** Values ever added (``count`` stops at the capacity). */
  total = 0;

  add(v: number): void {
    this.total += 1;
    this.values.push(v);
    if (this.values.length > this.capacity) this.values.shift();
  }

  /** Record the interval since the previous call (ms). */
  tick(nowMs: number): void {
    if (this.last !== null) this.add(nowMs - this.last);
    this.last = nowMs;
  }

  get count(): number {
    return this.values.length;
  }

  percentile(p: number): number {
    if (this.values.length === 0) return NaN;
    const sorted = [...this.values].sort((a, b) => a - b);
    const idx = Math.min(sorted.length - 1, Math.max(0, Math.round((p / 100) * (sorted.length - 1))));
    return sorted[idx] ?? NaN;
  }

  histogram(bins: number, max: number): number[] {
    const out = Array.from({ length: bins }, () => 0);
    for (const v of this.values) out[Math.min(bins - 1, Math.max(0, Math.floor((v / max) * bins)))]! += 1;
    return out;
  }

  snapshot(): number[] {
    return [...this.values];
  }
}
