// One-Euro smoothing of the driver's landmarks, as the live session runs it: landmarks/motion/smooth.py (OneEuroFilter,
// driving_cutoffs) and lsr/core/live_session.py (LiveSession.prepare: the filter's rate follows the frames' spacing, within
// MIN_FPS..MAX_FPS, and a frame without a face resets it). Same constants, same float32 output.

import { Tensor, tensor } from "./tensor.js";

export const EXPRESSIVE_CUTOFF = 12.0; // Hz: eyelids and lips (points 36-67)
export const LIVE_MIN_FPS = 2.0;
export const LIVE_MAX_FPS = 60.0;
const LIVE_START_FPS = 25.0; // LiveSession's OneEuroFilter(25.0, ...) before the first spacing is known

/** Per-point min_cutoff for driving landmarks (68,) Hz: the head steady, eyes and lips quick
 * (landmarks.motion.smooth.driving_cutoffs). */
export function drivingCutoffs(rigid = 1.0, expressive = EXPRESSIVE_CUTOFF): Float64Array {
  const cutoffs = new Float64Array(68).fill(rigid);
  for (let i = 36; i < 68; i++) cutoffs[i] = expressive;
  return cutoffs;
}

/** Smoothing factor of a first-order low-pass at `cutoff` Hz sampled at `fps` (landmarks.motion.smooth._alpha). */
function alpha(cutoff: number, fps: number): number {
  const tau = 1.0 / (2.0 * Math.PI * cutoff);
  return 1.0 / (1.0 + tau * fps);
}

/** Stateful One-Euro filter over (P, 2) point sets (landmarks.motion.smooth.OneEuroFilter). minCutoff: one value or one per
 * point (e.g. drivingCutoffs()). Each call returns the filtered points rounded to float32, as Python's does. */
export class OneEuroFilter {
  fps: number;
  readonly minCutoff: Float64Array | number;
  readonly beta: number;
  readonly dCutoff: number;
  private previous: Float64Array | null = null;
  private speed: Float64Array | null = null;

  constructor(fps: number, minCutoff: Float64Array | number = 1.0, beta = 0.05, dCutoff = 1.0) {
    const cutoffs = typeof minCutoff === "number" ? [minCutoff] : Array.from(minCutoff);
    if (!(fps > 0) || cutoffs.some((c) => !(c > 0)) || !(beta >= 0) || !(dCutoff > 0)) {
      throw new Error("need fps > 0, min_cutoff > 0, beta >= 0, d_cutoff > 0");
    }
    this.fps = fps;
    this.minCutoff = minCutoff;
    this.beta = beta;
    this.dCutoff = dCutoff;
  }

  /** Forget the past (across a gap: smoothing must not bridge missing frames). */
  reset(): void {
    this.previous = null;
    this.speed = null;
  }

  /** points (P, 2) -> filtered (P, 2) float64 holding float32 values. A non-finite input resets and passes through. */
  filter(points: Tensor): Tensor<Float64Array> {
    if (points.shape.length !== 2 || points.shape[1] !== 2) {
      throw new Error(`points must be (P, 2), got [${points.shape}]`);
    }
    const n = points.shape[0], data = points.data, out = new Float64Array(2 * n);
    let finite = true;
    for (let i = 0; i < 2 * n; i++) if (!Number.isFinite(data[i])) { finite = false; break; }
    if (!finite || this.previous === null || this.previous.length !== 2 * n) {
      if (!finite) this.reset();
      else { this.previous = Float64Array.from(data); this.speed = new Float64Array(n); }
      for (let i = 0; i < 2 * n; i++) out[i] = Math.fround(data[i]);
      return tensor(out, [n, 2]);
    }
    const previous = this.previous, speed = this.speed as Float64Array, fps = this.fps;
    const dAlpha = alpha(this.dCutoff, fps);
    for (let p = 0; p < n; p++) {
      const x = data[2 * p], y = data[2 * p + 1];
      const vx = (x - previous[2 * p]) * fps, vy = (y - previous[2 * p + 1]) * fps;
      speed[p] = speed[p] + dAlpha * (Math.sqrt(vx * vx + vy * vy) - speed[p]);
      const cutoff = typeof this.minCutoff === "number" ? this.minCutoff : this.minCutoff[p];
      const a = alpha(cutoff + this.beta * speed[p], fps);
      previous[2 * p] = previous[2 * p] + a * (x - previous[2 * p]);
      previous[2 * p + 1] = previous[2 * p + 1] + a * (y - previous[2 * p + 1]);
      out[2 * p] = Math.fround(previous[2 * p]);
      out[2 * p + 1] = Math.fround(previous[2 * p + 1]);
    }
    return tensor(out, [n, 2]);
  }
}

/** The live session's smoothing (lsr.core.live_session.LiveSession: its OneEuroFilter(25, driving_cutoffs()), the rate set
 * from each frame's spacing to the last, clipped to LIVE_MIN_FPS..LIVE_MAX_FPS). `step` on each frame with a face,
 * `gap` on each frame without one (LiveSession.still: the filter is reset, the spacing forgotten). */
export class LiveSmoother {
  readonly oneEuro = new OneEuroFilter(LIVE_START_FPS, drivingCutoffs());
  private lastTime: number | null = null;

  /** The tracker's (68, 2) frame points and the frame's capture time in seconds -> the smoothed points. */
  step(points: Tensor, timestamp: number): Tensor<Float64Array> {
    if (this.lastTime !== null && timestamp > this.lastTime) {
      this.oneEuro.fps = Math.min(Math.max(1.0 / (timestamp - this.lastTime), LIVE_MIN_FPS), LIVE_MAX_FPS);
    }
    const smoothed = this.oneEuro.filter(points);
    this.lastTime = timestamp;
    return smoothed;
  }

  /** A frame without a face: never smooth across it. */
  gap(): void {
    this.lastTime = null;
    this.oneEuro.reset();
  }
}

/** A whole track through the smoothing, for tests: points (T, 68, 2) (a non-finite frame = no face: a gap, and a NaN
 * row out) -> (T, 68, 2). timing: a number = a fixed rate, one OneEuroFilter(fps, driving_cutoffs()) as
 * landmarks.motion.smooth runs it; a (T,) tensor of capture times in seconds = the live session's LiveSmoother. */
export function smoothSequence(points: Tensor, timing: number | Tensor): Tensor<Float64Array> {
  if (points.shape.length !== 3 || points.shape[1] !== 68 || points.shape[2] !== 2) {
    throw new Error(`points must be (T, 68, 2), got [${points.shape}]`);
  }
  const frames = points.shape[0], size = 136, out = new Float64Array(frames * size);
  const fixed = typeof timing === "number" ? new OneEuroFilter(timing, drivingCutoffs()) : null;
  const live = fixed === null ? new LiveSmoother() : null;
  for (let t = 0; t < frames; t++) {
    const frame = tensor(points.data.subarray(t * size, (t + 1) * size) as Float64Array, [68, 2]);
    let finite = true;
    for (const value of frame.data) if (!Number.isFinite(value)) { finite = false; break; }
    if (!finite) {
      if (live !== null) live.gap(); else (fixed as OneEuroFilter).reset();
      out.fill(NaN, t * size, (t + 1) * size);
      continue;
    }
    const smoothed = live !== null ? live.step(frame, (timing as Tensor).data[t])
      : (fixed as OneEuroFilter).filter(frame);
    out.set(smoothed.data, t * size);
  }
  return tensor(out, [frames, 68, 2]);
}
