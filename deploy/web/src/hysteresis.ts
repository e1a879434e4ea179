// Which bank entry a driven sequence shows, frame by frame: landmarks/parts/hysteresis.py (SWITCH, FADE, EntryTrack).
// The nearest entry, kept until another is clearly nearer, and cross-faded in when it changes (issue 63: a part that
// switched exemplars 50 times in 183 frames popped). The module's SWITCH and FADE are ENTRY_SWITCH and ENTRY_FADE
// here (interior.ts has a FADE of its own).

/** The track moves to another entry only when its cost is below the kept entry's by this much (hysteresis). */
export const ENTRY_SWITCH = 1.0;
/** Frames over which a changed entry cross-fades in. */
export const ENTRY_FADE = 3;

/** One frame's entry: the entry shown, the entry it fades from (null: none) and that one's weight in [0, 1). */
export type EntryStep = [number, number | null, number];

/** The entry a sequence shows (landmarks.parts.hysteresis.EntryTrack). `switches`: how often it changed. */
export class EntryTrack {
  current: number | null = null;
  previous: number | null = null;
  /** Frames of the cross-fade still to go. */
  fading = 0;
  switches = 0;

  constructor(readonly switchCost = ENTRY_SWITCH, readonly fade = ENTRY_FADE) {
    if (!(switchCost >= 0 && fade >= 0)) throw new Error(`switch and fade must be >= 0, got ${switchCost} and ${fade}`);
    this.fade = Math.trunc(fade);
  }

  /** A gap (no target): the next frame chooses afresh, with no cross-fade. */
  reset(): void {
    this.current = this.previous = null;
    this.fading = 0;
  }

  /** One frame's costs (N,) (Infinity: unusable) -> the entry shown, the entry it fades from and its weight. */
  step(cost: ArrayLike<number>): EntryStep {
    if (!cost.length) throw new Error("cost must be a non-empty (N,) array, got none");
    let best = 0;  // np.argmin: the first of equal costs
    for (let i = 1; i < cost.length; i++) if (cost[i] < cost[best]) best = i;
    if (this.current === null || this.current >= cost.length) {
      this.current = best;
      this.previous = null;
      this.fading = 0;
    } else if (best !== this.current && cost[best] < cost[this.current] - this.switchCost) {
      this.previous = this.current;
      this.current = best;
      this.fading = this.fade;
      this.switches += 1;
    }
    if (this.fading > 0 && this.previous !== null) {
      const weight = this.fading / (this.fade + 1);
      this.fading -= 1;
      return [this.current, this.previous, weight];
    }
    return [this.current, null, 0.0];
  }
}
