// Bicubic remaps of fixed source images in WebAssembly with 128-bit SIMD (wasm.ts): the warp-guided references'
// shots (references.ts warpReferences) and the scene the head layer moves (composite.ts). remap.ts's bicubic remap
// (cv2.remap INTER_CUBIC of uint8 RGB: float weights at the exact position, Keys' a = -0.75, rounded half to even and
// saturated), with the dense maps made from the coarse grid (remap.ts densifyGrid's second pass) and their validity
// mask (tps.ts warpValidMask) beside it. Each source pixel is stored once as four float32 (R, G, B, 0), so that a
// tap is two loads of a channel pair widened to float64, and the pairs go through the same float64 products and sums,
// in the same order, as remap.ts's JavaScript (the weights of x and of y computed side by side in one register): the
// same bytes out (the same float32 maps, the same masks). The pixels whose taps leave the source are listed and left
// to remap.ts (remapCubicListed, with the border rule). The maps can be written straight into the module's memory
// (`mapSlots`), so that nothing is copied in. Where WebAssembly or its SIMD is missing, `CubicSources.create` gives
// null and the callers keep to remap.ts.

import { BorderMode, CoarseGrid, Interpolation, densifyRows, gridAcross, remapCubicListed } from "./remap.js";
import { F32, F64, Func, I32, V, V128, compileModule, float64, func, op, reserveMemory, signed, simd, unsigned,
         webAssemblyWanted } from "./wasm.js";

const PIXEL = 16;  // bytes of a source pixel: (R, G, B, 0) float32

/** remap(src, width, mapX, mapY, dst, count, xEnd, yEnd, only, listed) -> listed count: for each i < count (where
 * `only` is 0, or only[i] is not), dst[3i .. 3i + 2] where (mapX[i], mapY[i]) lies in [1, xEnd) x [1, yEnd), else i
 * appended to the int32 list at `listed`. src: the source as (R, G, B, 0) float32 per pixel, `width` pixels a row;
 * mapX, mapY: float32; dst: uint8 RGB; only: uint8. Pixels not written are left as they are. */
function remapFunction(): Func {
  // parameters 0-9, then the locals
  const [src, width, mapX, mapY, dst, count, xEnd, yEnd, only, listed] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9];
  const [i, n, ix, iy, row, rowBytes] = [10, 11, 12, 13, 14, 15];  // i32
  const [x, y] = [16, 17];  // f64
  // v128: the fractions (x, y), the four weights of x and of y side by side, each weight for x and for y in both lanes
  const [T, S, W0, W1, W2, W3, X0, X1, X2, X3, Y0, Y1, Y2, Y3, RG, B] =
    [18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29, 30, 31, 32, 33];
  const A = -0.75;
  const params = [I32, I32, I32, I32, I32, I32, F64, F64, I32, I32];
  const constants = [1, A, 5 * A, 8 * A, 4 * A, A + 2, A + 3, 0, 255, 2 ** 52];  // each in both lanes of a v128 local from 34
  return func(params, [I32], [[6, I32], [2, F64], [16 + constants.length, V128]], (emit) => {
    const get = (l: number) => emit(op.get, l), set = (l: number) => emit(op.set, l);
    const i32 = (v: number) => emit(op.i32Const, signed(v));
    const f64 = (v: number) => emit(op.f64Const, float64(v));
    const both = (v: number) => get(34 + constants.indexOf(v));  // v in both lanes
    constants.forEach((v, k) => { emit(simd(V.const), float64(v), float64(v)); set(34 + k); });
    const [mul, add, sub] = [simd(V.f64x2Mul), simd(V.f64x2Add), simd(V.f64x2Sub)];
    // w = ((A p - 5 A) p + 8 A) p - 4 A, p = t + 1 (remap.ts cubicInside3's first weight)
    const outer = (into: number) => {
      get(T); both(1); emit(add); set(S);
      both(A); get(S); emit(mul); both(5 * A); emit(sub); get(S); emit(mul); both(8 * A); emit(add);
      get(S); emit(mul); both(4 * A); emit(sub); set(into);
    };
    // w = ((A + 2) v - (A + 3)) v v + 1
    const inner = (value: number, into: number) => {
      both(A + 2); get(value); emit(mul); both(A + 3); emit(sub); get(value); emit(mul); get(value); emit(mul);
      both(1); emit(add); set(into);
    };
    // one lane of a weight in both lanes
    const lane = (from: number, at: 0 | 1, into: number) => {
      const bytes = Array.from({ length: 16 }, (_, k) => 8 * at + (k % 8));
      get(from); get(from); emit(simd(V.shuffle), bytes); set(into);
    };
    // one row's channel pair at byte `offset` of a pixel (0: R, G; 8: B, 0): sum over taps of pixel * X_j, in order
    const taps = (offset: number) => {
      [X0, X1, X2, X3].forEach((X, j) => {
        get(row); emit(simd(V.load64Zero), 3, unsigned(offset + PIXEL * j), simd(V.f64x2Promote));
        get(X); emit(mul);
        if (j > 0) emit(add);
      });
    };
    // saturated, then rounded half to even by adding 2^52 (where a float64's unit is 1): each lane's low byte is the
    // value (the order does not matter: the bounds are integers)
    const rounded = (sum: number) => {
      get(sum); both(0); emit(simd(V.f64x2Pmax)); both(255); emit(simd(V.f64x2Pmin)); both(2 ** 52); emit(add);
    };

    get(width); i32(4); emit(op.i32Shl); set(rowBytes);
    emit(op.block, op.void, op.loop, op.void);
    get(i); get(count); emit(op.i32GeS, op.brIf, 1);
    emit(op.block, op.void);  // a pixel done (or left) goes on past this block
    get(only); emit(op.if, op.void);
    get(only); get(i); emit(op.i32Add, op.i32Load8U, 0, 0, op.i32Eqz, op.brIf, 1);
    emit(op.end);
    get(mapX); get(i); i32(2); emit(op.i32Shl, op.i32Add, op.f32Load, 2, 0, op.f64PromoteF32); set(x);
    get(mapY); get(i); i32(2); emit(op.i32Shl, op.i32Add, op.f32Load, 2, 0, op.f64PromoteF32); set(y);
    get(x); f64(1); emit(op.f64Ge); get(x); get(xEnd); emit(op.f64Lt, op.i32And);
    get(y); f64(1); emit(op.f64Ge, op.i32And); get(y); get(yEnd); emit(op.f64Lt, op.i32And, op.i32Eqz);
    emit(op.if, op.void);  // taps outside the source (or NaN): listed
    get(listed); get(n); i32(2); emit(op.i32Shl, op.i32Add); get(i); emit(op.i32Store, 2, 0);
    get(n); i32(1); emit(op.i32Add); set(n);
    emit(op.br, 1, op.end);
    get(x); emit(op.i32TruncF64S); set(ix);
    get(y); emit(op.i32TruncF64S); set(iy);
    get(x); get(ix); emit(op.f64ConvertI32S, op.f64Sub, simd(V.f64x2Splat));
    get(y); get(iy); emit(op.f64ConvertI32S, op.f64Sub, simd(V.f64x2Replace), 1); set(T);
    outer(W0);
    inner(T, W1);
    both(1); get(T); emit(sub); set(S);
    inner(S, W2);
    both(1); get(W0); emit(sub); get(W1); emit(sub); get(W2); emit(sub); set(W3);
    lane(W0, 0, X0); lane(W1, 0, X1); lane(W2, 0, X2); lane(W3, 0, X3);
    lane(W0, 1, Y0); lane(W1, 1, Y1); lane(W2, 1, Y2); lane(W3, 1, Y3);
    // the 4 x 4 taps from (ix - 1, iy - 1): sum over rows of Y_k * (the row's sum), for both channel pairs
    get(src); get(iy); i32(1); emit(op.i32Sub); get(width); emit(op.i32Mul); get(ix); emit(op.i32Add);
    i32(1); emit(op.i32Sub); i32(4); emit(op.i32Shl, op.i32Add); set(row);
    [Y0, Y1, Y2, Y3].forEach((Y, k) => {
      if (k > 0) get(RG);
      taps(0); get(Y); emit(mul);
      if (k > 0) emit(add);
      set(RG);
      if (k > 0) get(B);
      taps(8); get(Y); emit(mul);
      if (k > 0) emit(add);
      set(B);
      if (k < 3) { get(row); get(rowBytes); emit(op.i32Add); set(row); }
    });
    // R, G and B as bytes 0-2 of S, stored at dst + 3 i
    rounded(RG); rounded(B);
    emit(simd(V.shuffle), [0, 8, 16, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]); set(S);
    get(dst); get(i); i32(3); emit(op.i32Mul, op.i32Add); set(row);
    get(row); get(S); emit(simd(V.store16Lane), 0, 0, 0);
    get(row); get(S); emit(simd(V.store8Lane), 0, 2, 2);
    emit(op.end);  // block
    get(i); i32(1); emit(op.i32Add); set(i);
    emit(op.br, 0, op.end, op.end);  // loop, block
    get(n);
  });
}

/** densify(half, cols, lower, a0, a1, out, width, height): remap.ts densifyGrid's second pass, across each row:
 * out[y * width + x] = float32(a0[x] * half[y * cols + lower[x]] + a1[x] * half[y * cols + lower[x] + 1]) in float64
 * as JavaScript computes it, two columns at a time. half: float32 (height, cols); lower: int32 byte offsets
 * (4 lower[x]); a0, a1: float64 (the float32 weights); out: float32. */
function densifyFunction(): Func {
  const [half, cols, lower, a0, a1, out, width, height] = [0, 1, 2, 3, 4, 5, 6, 7];
  const [y, x, row, pairs] = [8, 9, 10, 11];  // i32
  const H = 12;  // v128
  return func([I32, I32, I32, I32, I32, I32, I32, I32], [], [[4, I32], [1, V128]], (emit) => {
    const get = (l: number) => emit(op.get, l), set = (l: number) => emit(op.set, l);
    const i32 = (v: number) => emit(op.i32Const, signed(v));
    // the address of half[y, lower[x + next]]
    const address = (next: number) => {
      get(row); get(lower); get(x); i32(2); emit(op.i32Shl, op.i32Add, op.i32Load, 2, 4 * next, op.i32Add);
    };
    // half[y, lower[x] + offset] of column x (and x + 1) as float64 lanes
    const halves = (offset: number, both: boolean) => {
      address(0); emit(simd(V.load32Zero), 2, offset);
      if (both) { set(H); address(1); get(H); emit(simd(V.load32Lane), 2, offset, 1); }
      emit(simd(V.f64x2Promote));
    };
    // out[x] (and out[x + 1]) = float32(a0 h0 + a1 h1)
    const columns = (both: boolean) => {
      get(out);
      get(a0); get(x); i32(3); emit(op.i32Shl, op.i32Add, simd(V.load), 3, 0); halves(0, both); emit(simd(V.f64x2Mul));
      get(a1); get(x); i32(3); emit(op.i32Shl, op.i32Add, simd(V.load), 3, 0); halves(4, both); emit(simd(V.f64x2Mul));
      emit(simd(V.f64x2Add), simd(V.f32x4DemoteF64x2Zero));
      if (both) emit(simd(V.store64Lane), 2, 0, 0);
      else emit(simd(V.f32x4Extract), 0, op.f32Store, 2, 0);
      get(out); i32(both ? 8 : 4); emit(op.i32Add); set(out);
      get(x); i32(both ? 2 : 1); emit(op.i32Add); set(x);
    };
    get(width); i32(-2); emit(op.i32And); set(pairs);  // the columns done two at a time
    emit(op.block, op.void, op.loop, op.void);  // rows
    get(y); get(height); emit(op.i32GeS, op.brIf, 1);
    get(half); get(y); get(cols); emit(op.i32Mul); i32(2); emit(op.i32Shl, op.i32Add); set(row);
    i32(0); set(x);
    emit(op.block, op.void, op.loop, op.void);  // column pairs
    get(x); get(pairs); emit(op.i32GeS, op.brIf, 1);
    columns(true);
    emit(op.br, 0, op.end, op.end);
    get(x); get(width); emit(op.i32Ne, op.if, op.void);  // an odd width's last column
    columns(false);
    emit(op.end);
    get(y); i32(1); emit(op.i32Add); set(y);
    emit(op.br, 0, op.end, op.end);
  });
}

/** valid(mapX, mapY, out, count, low, right, bottom): tps.ts warpValidMask, out[i] = 1 where low <= mapX[i] <= right
 * and low <= mapY[i] <= bottom (float32 compares), else 0 (NaN: 0), four at a time (up to 3 values past `count` are
 * read and written: the regions are of whole 16-byte blocks). */
function validFunction(): Func {
  const [mapX, mapY, out, count, low, right, bottom] = [0, 1, 2, 3, 4, 5, 6];
  const [i, at] = [7, 8];  // i32
  const [L, R, B] = [9, 10, 11];  // v128
  return func([I32, I32, I32, I32, F32, F32, F32], [], [[2, I32], [3, V128]], (emit) => {
    const get = (l: number) => emit(op.get, l), set = (l: number) => emit(op.set, l);
    get(low); emit(simd(V.f32x4Splat)); set(L);
    get(right); emit(simd(V.f32x4Splat)); set(R);
    get(bottom); emit(simd(V.f32x4Splat)); set(B);
    emit(op.block, op.void, op.loop, op.void);
    get(i); get(count); emit(op.i32GeS, op.brIf, 1);
    get(i); emit(op.i32Const, signed(2), op.i32Shl); set(at);
    get(out); get(at); emit(op.i32Add);
    get(mapX); get(at); emit(op.i32Add, simd(V.load), 2, 0); get(L); emit(simd(V.f32x4Ge));
    get(mapX); get(at); emit(op.i32Add, simd(V.load), 2, 0); get(R); emit(simd(V.f32x4Le), simd(V.and));
    get(mapY); get(at); emit(op.i32Add, simd(V.load), 2, 0); get(L); emit(simd(V.f32x4Ge), simd(V.and));
    get(mapY); get(at); emit(op.i32Add, simd(V.load), 2, 0); get(B); emit(simd(V.f32x4Le), simd(V.and));
    emit(simd(V.const), Array.from(new Uint8Array(new Float32Array([1, 1, 1, 1]).buffer)), simd(V.and));
    emit(simd(V.store), 2, 0);
    get(i); emit(op.i32Const, signed(4), op.i32Add); set(i);
    emit(op.br, 0, op.end, op.end);
  });
}

// ---- the sources and their remaps ---------------------------------------------------------------------------

let compiled: WebAssembly.Module | null | undefined;

function module(): WebAssembly.Module | null {
  if (compiled === undefined) {
    compiled = compileModule([["remap", remapFunction()], ["densify", densifyFunction()], ["valid", validFunction()]]);
  }
  return compiled;
}

/** Whether the remaps run in WebAssembly here (false: remap.ts's JavaScript). */
export function remapsInWasm(): boolean {
  return webAssemblyWanted() && module() !== null;
}

/** Where things lie in a CubicSources' memory past the sources (byte offsets, 16-byte aligned): `slots` pairs of
 * maps of `values` entries each, the output, mask, `only` and list of one remap, the grid's rows and tables. */
interface Layout { values: number; slots: number; half: number; maps: number; dst: number; mask: number; only: number;
                   listed: number; halfX: number; halfY: number; lower: number; a0: number; a1: number; end: number }

function layout(start: number, values: number, slots: number, half: number, width: number): Layout {
  let at = start;
  const take = (bytes: number) => { const here = at; at += Math.ceil(bytes / 16) * 16; return here; };
  const maps = take(slots * 2 * values * 4), dst = take(values * 3 + 16), mask = take(values * 4), only = take(values);
  const listed = take(values * 4), halfX = take(half * 4), halfY = take(half * 4), lower = take(width * 4);
  const a0 = take(width * 8), a1 = take(width * 8);
  return { values, slots, half, maps, dst, mask, only, listed, halfX, halfY, lower, a0, a1, end: at };
}

/** A pair of dense maps (float32) in a CubicSources' memory: write them, then remap through them (`remapSlot`). */
export interface MapSlot { mapX: Float32Array; mapY: Float32Array }

/** `count` RGB uint8 images of one size, held in WebAssembly memory to be remapped (the warp-guided references'
 * shots, the scene of the head layer: the same for every frame). */
export class CubicSources {
  private readonly exports: Record<string, (...args: number[]) => number>;
  private readonly sourceBytes: number;
  private at: Layout;
  private across: Interpolation | null = null;  // the interpolation tables now in memory

  private constructor(private readonly memory: WebAssembly.Memory, instance: WebAssembly.Instance,
                      private images: Uint8Array, readonly count: number, readonly width: number,
                      readonly height: number) {
    this.exports = instance.exports as unknown as Record<string, (...args: number[]) => number>;
    this.sourceBytes = count * width * height * PIXEL;
    this.at = layout(this.sourceBytes, 0, 0, 0, width);
  }

  /** `cached` where it holds these images (`holds`), else new sources of them; null where WebAssembly SIMD is not
   * available, or turned off (wasm.ts useWebAssembly). */
  static of(cached: CubicSources | null, images: Uint8Array, count: number, width: number, height: number
            ): CubicSources | null {
    if (!webAssemblyWanted()) return null;
    return cached?.holds(images, count, width, height) ? cached : CubicSources.create(images, count, width, height);
  }

  /** `of` for images that change from call to call (a face crop, every frame): `cached` with them loaded into it
   * where it is of their count and size. */
  static reload(cached: CubicSources | null, images: Uint8Array, count: number, width: number, height: number
                ): CubicSources | null {
    if (!webAssemblyWanted()) return null;
    if (cached?.count !== count || cached.width !== width || cached.height !== height) {
      return CubicSources.create(images, count, width, height);
    }
    cached.load(images);
    return cached;
  }

  /** The sources (count, height, width, 3) uint8 flat, or null where WebAssembly SIMD is not available. */
  static create(images: Uint8Array, count: number, width: number, height: number): CubicSources | null {
    const compiledModule = webAssemblyWanted() ? module() : null;
    if (compiledModule === null || width < 4 || height < 4 || images.length !== count * width * height * 3) return null;
    try {
      const instance = new WebAssembly.Instance(compiledModule, {});
      const memory = instance.exports.memory as WebAssembly.Memory;
      const sources = new CubicSources(memory, instance, images, count, width, height);
      sources.reserve(width * height, 1, 0);
      sources.load(images);
      return sources;
    } catch {
      return null;
    }
  }

  /** Other images of the same count and size in place of these (a face crop that changes every frame). */
  load(images: Uint8Array): void {
    if (images.length !== this.count * this.width * this.height * 3) throw new Error("the images must be of the same size");
    const expanded = new Float32Array(this.memory.buffer, 0, images.length / 3 * 4);
    for (let p = 0, j = 0; j < images.length; p += 4, j += 3) {
      expanded[p] = images[j]; expanded[p + 1] = images[j + 1]; expanded[p + 2] = images[j + 2];
    }
    this.images = images;
  }

  /** Room past the sources for `slots` pairs of maps of `values` entries (and grids of `half` rows x cols). */
  private reserve(values: number, slots: number, half: number): Layout {
    if (values > this.at.values || slots > this.at.slots || half > this.at.half) {
      this.at = layout(this.sourceBytes, Math.max(values, this.at.values), Math.max(slots, this.at.slots),
                       Math.max(half, this.at.half), this.width);
      this.across = null;
      reserveMemory(this.memory, this.at.end);
    }
    return this.at;
  }

  /** Whether these are `images` (the same array, whose values must not have changed since). */
  holds(images: Uint8Array, count: number, width: number, height: number): boolean {
    return images === this.images && count === this.count && width === this.width && height === this.height;
  }

  /** `slots` pairs of dense maps of `values` entries in memory, to be written and remapped through (remapSlot,
   * densifySlot, validSlot). They stay until the next call of `mapSlots`, `remap` or `warp`. */
  mapSlots(slots: number, values: number): MapSlot[] {
    const at = this.reserve(values, slots, values), buffer = this.memory.buffer;  // room for densifySlot's rows too
    return Array.from({ length: slots }, (_, k) => ({
      mapX: new Float32Array(buffer, at.maps + 2 * k * values * 4, values),
      mapY: new Float32Array(buffer, at.maps + (2 * k + 1) * values * 4, values),
    }));
  }

  /** remapCubic(source `index`, mapX, mapY, border, dst, only): the same bytes. dst: (mapX.length * 3) uint8; only:
   * when given, the pixels where it is 0 are left as dst has them. */
  remap(index: number, mapX: Float32Array, mapY: Float32Array, border: BorderMode, dst: Uint8Array,
        only?: Uint8Array): void {
    const values = mapX.length;
    if (mapY.length !== values || dst.length !== values * 3) throw new Error("mapX, mapY and the output must be of one size");
    const [slot] = this.mapSlots(1, values);
    slot.mapX.set(mapX);
    slot.mapY.set(mapY);
    this.remapSlot(slot, index, border, dst, only);
  }

  /** The maps of `slot` made dense from a coarse grid of their size (tps.ts GridMap: mapX, mapY (rows, cols)) as
   * densifyGrid makes them. False (nothing done) for a grid of step 1 or wider than the sources. */
  densifySlot(slot: MapSlot, grid: CoarseGrid, mapX: ArrayLike<number>, mapY: ArrayLike<number>): boolean {
    const { width, height } = grid, cols = grid.xs.length, rows = height * cols, at = this.at;
    if (grid.step === 1 || width > this.width || slot.mapX.length !== width * height) return false;
    const buffer = this.slotBuffer(slot);  // the rows fit: mapSlots made room for as many values
    densifyRows(grid, mapX, new Float32Array(buffer, at.halfX, rows));
    densifyRows(grid, mapY, new Float32Array(buffer, at.halfY, rows));
    const across = gridAcross(grid);
    if (this.across !== across) {
      const lower = new Int32Array(buffer, at.lower, width);
      for (let x = 0; x < width; x++) lower[x] = across.lower[x] * 4;
      new Float64Array(buffer, at.a0, width).set(across.w0);
      new Float64Array(buffer, at.a1, width).set(across.w1);
      this.across = across;
    }
    const { densify } = this.exports;
    densify(at.halfX, cols, at.lower, at.a0, at.a1, slot.mapX.byteOffset, width, height);
    densify(at.halfY, cols, at.lower, at.a0, at.a1, slot.mapY.byteOffset, width, height);
    return true;
  }

  /** warpValidMask of the maps of `slot` (the sources' size) into mask: the same values. */
  validSlot(slot: MapSlot, mask: Float32Array): void {
    const at = this.at, values = slot.mapX.length, f = Math.fround, slack = 1e-3;
    this.slotBuffer(slot);
    this.exports.valid(slot.mapX.byteOffset, slot.mapY.byteOffset, at.mask, values, f(-slack),
                       f(this.width - 1 + slack), f(this.height - 1 + slack));
    mask.set(new Float32Array(this.memory.buffer, at.mask, values));
  }

  /** The maps on a coarse grid of the sources' size made dense as densifyGrid makes them, source `index` remapped
   * through them as `remap` does into dst ((height * width * 3) uint8), and their warpValidMask into mask ((height *
   * width) float32): the same values. False (nothing done) for a grid of step 1 or of another size. */
  warp(index: number, grid: CoarseGrid, mapX: ArrayLike<number>, mapY: ArrayLike<number>, border: BorderMode,
       dst: Uint8Array, mask: Float32Array): boolean {
    const values = this.width * this.height;
    if (grid.step === 1 || grid.width !== this.width || grid.height !== this.height) return false;
    if (dst.length !== values * 3 || mask.length !== values) throw new Error("the output and mask must be the sources' size");
    const [slot] = this.mapSlots(1, values);
    this.densifySlot(slot, grid, mapX, mapY);
    this.validSlot(slot, mask);
    this.remapSlot(slot, index, border, dst);
    return true;
  }

  /** The memory `slot` lies in: this one's, as mapSlots gave it (else an Error). */
  private slotBuffer(slot: MapSlot): ArrayBuffer {
    const buffer = this.memory.buffer;
    if (slot.mapX.buffer !== buffer || slot.mapY.buffer !== buffer) throw new Error("the maps are not this memory's slots");
    return buffer;
  }

  /** remapCubic of source `index` through the maps of `slot` into dst (only: as `remap`). */
  remapSlot(slot: MapSlot, index: number, border: BorderMode, dst: Uint8Array, only?: Uint8Array): void {
    const { width, height } = this, at = this.at, buffer = this.slotBuffer(slot), values = slot.mapX.length;
    if (dst.length !== values * 3 || (only && only.length !== values)) throw new Error("the output must be the maps' size");
    if (only) {
      new Uint8Array(buffer, at.only, values).set(only);
      new Uint8Array(buffer, at.dst, values * 3).set(dst);
    }
    const listed = this.exports.remap(index * width * height * PIXEL, width, slot.mapX.byteOffset, slot.mapY.byteOffset,
                                      at.dst, values, width - 2, height - 2, only ? at.only : 0, at.listed);
    dst.set(new Uint8Array(buffer, at.dst, values * 3));
    const image = this.images.subarray(index * width * height * 3, (index + 1) * width * height * 3);
    remapCubicListed({ data: image, width, height, channels: 3 }, slot.mapX, slot.mapY, border, dst,
                     new Int32Array(buffer, at.listed, listed), listed);
  }
}
