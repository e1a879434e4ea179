// A bank's rows while it is read from a person's frames: landmarks/parts/bank_rows.py (BankRows, usable_face). One row
// per usable frame, bounded in memory while a long video streams by, evenly spread over the frames at the end.

import { finite } from "./retarget.js";
import { Tensor } from "./tensor.js";

/** Rows of a bank being built (landmarks.parts.bank_rows.BankRows): `add` keeps at most 4 x maxEntries (every other
 * one when full; a null row, a frame that gave none, is skipped); `spread` gives at most maxEntries of them, evenly
 * spread, in order. */
export class BankRows<Row> {
  rows: Row[] = [];

  constructor(readonly maxEntries: number) {
    if (!(Number.isInteger(maxEntries) && maxEntries >= 1)) throw new Error(`max_entries must be >= 1, got ${maxEntries}`);
  }

  add(row: Row | null): void {
    if (row === null) return;
    this.rows.push(row);
    if (this.rows.length >= 4 * this.maxEntries) this.rows = this.rows.filter((_, i) => i % 2 === 0);
  }

  /** np.linspace(0, len - 1, maxEntries).round() of the rows. */
  spread(): Row[] {
    const count = this.rows.length, wanted = this.maxEntries;
    if (count <= wanted) return [...this.rows];
    const step = (count - 1) / (wanted - 1);
    return Array.from({ length: wanted }, (_, i) => {
      const at = i === wanted - 1 ? count - 1 : i * step;  // linspace's last is the stop exactly
      return this.rows[roundHalfEvenIndex(at)];
    });
  }
}

function roundHalfEvenIndex(value: number): number {
  const rounded = Math.round(value);
  return rounded - value === 0.5 && rounded % 2 !== 0 ? rounded - 1 : rounded;
}

/** A bank's frame (H, W, 3) uint8 RGB and its 68 points -> the points flat, or null where they are null or not finite
 * (no face: skipped); a frame of another shape is an Error (landmarks.parts.bank_rows.usable_face). */
export function usableFace(frame: Tensor, points: Tensor | null): ArrayLike<number> | null {
  if (points === null) return null;
  if (points.shape.length !== 2 || points.shape[0] !== 68 || points.shape[1] !== 2) {
    throw new Error(`landmarks must be (68, 2), got [${points.shape}]`);
  }
  if (!finite(points.data)) return null;
  if (frame.shape.length !== 3 || frame.shape[2] !== 3 || !(frame.data instanceof Uint8Array)) {
    throw new Error(`bank frames must be (H, W, 3) uint8, got [${frame.shape}]`);
  }
  return points.data;
}
