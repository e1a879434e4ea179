// The warp-guided references' warps (tps.ts warpReferences) in WebAssembly with 128-bit SIMD, for fixed source
// images (the shots): remap.ts's bicubic remap (cv2.remap INTER_CUBIC of uint8 RGB: float weights at the exact
// position, Keys' a = -0.75, rounded half to even and saturated), with the dense maps made from the coarse grid
// (remap.ts densifyGrid's second pass) and their validity mask (tps.ts warpValidMask) beside it. Each source pixel is
// stored once as four float32 (R, G, B, 0), so that a tap is two loads of a channel pair widened to float64, and the
// pairs go through the same float64 products and sums, in the same order, as remap.ts's JavaScript: the same bytes
// out (the same float32 maps, the same masks), in about 60 % of the time. The module is a few hundred bytes, written
// here opcode by opcode (no toolchain); where WebAssembly or its SIMD is missing, `CubicSources.create` gives null
// and the caller keeps to remap.ts. Pixels whose taps leave the source go through remap.ts (remapCubicBorder).

import { BorderMode, CoarseGrid, Interpolation, densifyRows, gridAcross, remapCubicBorder } from "./remap.js";

// ---- a small WebAssembly writer ---------------------------------------------------------------------------

function unsigned(value: number): number[] {
  const out: number[] = [];
  do {
    let byte = value & 0x7f;
    value >>>= 7;
    if (value !== 0) byte |= 0x80;
    out.push(byte);
  } while (value !== 0);
  return out;
}

function signed(value: number): number[] {
  const out: number[] = [];
  for (;;) {
    const byte = value & 0x7f;
    value >>= 7;
    if ((value === 0 && (byte & 0x40) === 0) || (value === -1 && (byte & 0x40) !== 0)) { out.push(byte); return out; }
    out.push(byte | 0x80);
  }
}

function float64(value: number): number[] {
  return Array.from(new Uint8Array(new Float64Array([value]).buffer));
}

function section(id: number, body: number[]): number[] {
  return [id, ...unsigned(body.length), ...body];
}

function vector(items: number[][]): number[] {
  return [...unsigned(items.length), ...items.flat()];
}

function name(text: string): number[] {
  const bytes = Array.from(new TextEncoder().encode(text));
  return [...unsigned(bytes.length), ...bytes];
}

const I32 = 0x7f, F32 = 0x7d, F64 = 0x7c, V128 = 0x7b;
const op = {
  block: 0x02, loop: 0x03, br: 0x0c, brIf: 0x0d, end: 0x0b, void: 0x40,
  get: 0x20, set: 0x21,
  i32Load: 0x28, f32Load: 0x2a, f64Load: 0x2b, f32Store: 0x38, i32Store8: 0x3a, i32Const: 0x41, f64Const: 0x44,
  i32Eqz: 0x45, i32GeS: 0x4e, f32Le: 0x5f, f32Ge: 0x60, f64Lt: 0x63, f64Ge: 0x66,
  i32Add: 0x6a, i32Sub: 0x6b, i32Mul: 0x6c, i32And: 0x71, i32Shl: 0x74,
  f64Nearest: 0x9e, f64Add: 0xa0, f64Sub: 0xa1, f64Mul: 0xa2, f64Min: 0xa4, f64Max: 0xa5,
  i32TruncF64S: 0xaa, f32ConvertI32U: 0xb3, f32DemoteF64: 0xb6, f64ConvertI32S: 0xb7, f64PromoteF32: 0xbb,
};
const simd = (code: number) => [0xfd, ...unsigned(code)];
const V128_LOAD64_ZERO = 0x5d, F64X2_PROMOTE = 0x5f, F64X2_SPLAT = 0x14, F64X2_EXTRACT = 0x21, F64X2_ADD = 0xf0, F64X2_MUL = 0xf2;

/** One function's code: `params` then `locals` ([count, type] groups) numbered from 0; `build` emits its body. */
interface Func { params: number[]; locals: [number, number][]; code: number[] }

function func(params: number[], locals: [number, number][], build: (emit: (...bytes: (number | number[])[]) => void) => void
              ): Func {
  const code: number[] = [];
  build((...bytes) => { for (const b of bytes) Array.isArray(b) ? code.push(...b) : code.push(b); });
  code.push(op.end);
  return { params, locals, code };
}

/** A module of functions (each of its own type, exported by name) and one exported memory of one page. */
function moduleBytes(functions: [string, Func][]): Uint8Array {
  return Uint8Array.from([
    0x00, 0x61, 0x73, 0x6d, 0x01, 0x00, 0x00, 0x00,
    ...section(1, vector(functions.map(([, f]) => [0x60, ...vector(f.params.map((type) => [type])), 0]))),
    ...section(3, vector(functions.map((_, index) => [index]))),
    ...section(5, vector([[0x00, 1]])),
    ...section(7, vector([...functions.map(([label], index) => [...name(label), 0x00, index]), [...name("memory"), 0x02, 0]])),
    ...section(10, vector(functions.map(([, f]) => {
      const body = [...vector(f.locals.map(([count, type]) => [count, type])), ...f.code];
      return [...unsigned(body.length), ...body];
    }))),
  ]);
}

/** remap(src, width, mapX, mapY, dst, count, xEnd, yEnd) writes, for each i < count whose (mapX[i], mapY[i]) lies in
 * [1, xEnd) x [1, yEnd), dst[3i .. 3i + 2]; src: the source as (R, G, B, 0) float32 per pixel, `width` pixels a row;
 * mapX, mapY: float32; dst: uint8 RGB. Other pixels are left as they are. */
function remapFunction(): Func {
  // parameters 0-7, then the locals
  const [src, width, mapX, mapY, dst, count, xEnd, yEnd] = [0, 1, 2, 3, 4, 5, 6, 7];
  const [i, ix, iy, row, rowBytes] = [8, 9, 10, 11, 12];  // i32
  const [x, y, t, s, w0, w1, w2, w3, h0, h1, h2, h3] = [13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24];  // f64
  const [W0, W1, W2, W3, H0, H1, H2, H3, total] = [25, 26, 27, 28, 29, 30, 31, 32, 33];  // v128
  const A = -0.75;
  return func([I32, I32, I32, I32, I32, I32, F64, F64], [[5, I32], [12, F64], [9, V128]], (emit) => {
    const get = (l: number) => emit(op.get, l), set = (l: number) => emit(op.set, l);
    const f64 = (v: number) => emit(op.f64Const, float64(v));
    // w = ((A p - 5 A) p + 8 A) p - 4 A, p = value + 1 (remap.ts's first weight), into `into`
    const outer = (value: number, into: number) => {
      get(value); f64(1); emit(op.f64Add); set(s);
      f64(A); get(s); emit(op.f64Mul); f64(5 * A); emit(op.f64Sub); get(s); emit(op.f64Mul); f64(8 * A); emit(op.f64Add);
      get(s); emit(op.f64Mul); f64(4 * A); emit(op.f64Sub); set(into);
    };
    // w = ((A + 2) v - (A + 3)) v v + 1
    const inner = (value: number, into: number) => {
      f64(A + 2); get(value); emit(op.f64Mul); f64(A + 3); emit(op.f64Sub); get(value); emit(op.f64Mul); get(value);
      emit(op.f64Mul); f64(1); emit(op.f64Add); set(into);
    };
    const weights = (fraction: number, a: number, b: number, c: number, d: number) => {
      outer(fraction, a);
      inner(fraction, b);
      f64(1); get(fraction); emit(op.f64Sub); set(s);
      inner(s, c);
      f64(1); get(a); emit(op.f64Sub); get(b); emit(op.f64Sub); get(c); emit(op.f64Sub); set(d);
    };
    const splat = (from: number, into: number) => { get(from); emit(simd(F64X2_SPLAT)); set(into); };
    // two float32 of the pixel at `row` + offset, as float64
    const load = (offset: number) => { get(row); emit(simd(V128_LOAD64_ZERO), 3, ...unsigned(offset), simd(F64X2_PROMOTE)); };
    // one channel pair (offset 0: R, G; 8: B, 0): sum over rows of H_k * (sum over taps of pixel * W_j)
    const pair = (offset: number) => {
      get(src); get(iy); emit(op.i32Const, signed(1), op.i32Sub); get(width); emit(op.i32Mul); get(ix); emit(op.i32Add);
      emit(op.i32Const, signed(1), op.i32Sub, op.i32Const, signed(4), op.i32Shl, op.i32Add); set(row);
      [H0, H1, H2, H3].forEach((H, k) => {
        [W0, W1, W2, W3].forEach((W, j) => {
          load(offset + 16 * j); get(W); emit(simd(F64X2_MUL));
          if (j > 0) emit(simd(F64X2_ADD));
        });
        get(H); emit(simd(F64X2_MUL));
        if (k > 0) emit(simd(F64X2_ADD));
        if (k < 3) { get(row); get(rowBytes); emit(op.i32Add); set(row); }
      });
      set(total);
    };
    // rounded half to even, saturated, stored at dst + 3 i + channel
    const store = (lane: number, channel: number) => {
      get(dst); get(i); emit(op.i32Const, signed(3), op.i32Mul, op.i32Add);
      get(total); emit(simd(F64X2_EXTRACT), lane, op.f64Nearest); f64(0); emit(op.f64Max); f64(255); emit(op.f64Min);
      emit(op.i32TruncF64S, op.i32Store8, 0, ...unsigned(channel));
    };

    get(width); emit(op.i32Const, signed(4), op.i32Shl); set(rowBytes);
    emit(op.block, op.void, op.loop, op.void);
    get(i); get(count); emit(op.i32GeS, op.brIf, 1);
    emit(op.block, op.void);
    get(mapX); get(i); emit(op.i32Const, signed(2), op.i32Shl, op.i32Add, op.f32Load, 2, 0, op.f64PromoteF32); set(x);
    get(mapY); get(i); emit(op.i32Const, signed(2), op.i32Shl, op.i32Add, op.f32Load, 2, 0, op.f64PromoteF32); set(y);
    get(x); f64(1); emit(op.f64Ge, op.i32Eqz, op.brIf, 0);
    get(x); get(xEnd); emit(op.f64Lt, op.i32Eqz, op.brIf, 0);
    get(y); f64(1); emit(op.f64Ge, op.i32Eqz, op.brIf, 0);
    get(y); get(yEnd); emit(op.f64Lt, op.i32Eqz, op.brIf, 0);
    get(x); emit(op.i32TruncF64S); set(ix);
    get(y); emit(op.i32TruncF64S); set(iy);
    get(x); get(ix); emit(op.f64ConvertI32S, op.f64Sub); set(t);
    weights(t, w0, w1, w2, w3);
    get(y); get(iy); emit(op.f64ConvertI32S, op.f64Sub); set(t);
    weights(t, h0, h1, h2, h3);
    splat(w0, W0); splat(w1, W1); splat(w2, W2); splat(w3, W3);
    splat(h0, H0); splat(h1, H1); splat(h2, H2); splat(h3, H3);
    pair(0);
    store(0, 0); store(1, 1);
    pair(8);
    store(0, 2);
    emit(op.end);  // block: a pixel outside goes on here
    get(i); emit(op.i32Const, signed(1), op.i32Add); set(i);
    emit(op.br, 0, op.end, op.end);  // loop, block
  });
}

/** densify(half, cols, lower, a0, a1, out, width, height): remap.ts densifyGrid's second pass, across each row:
 * out[y * width + x] = float32(a0[x] * half[y * cols + lower[x]] + a1[x] * half[y * cols + lower[x] + 1]) in float64
 * as JavaScript computes it. half: float32 (height, cols); lower: int32 byte offsets (4 lower[x]); a0, a1: float64
 * (the float32 weights); out: float32. */
function densifyFunction(): Func {
  const [half, cols, lower, a0, a1, out, width, height] = [0, 1, 2, 3, 4, 5, 6, 7];
  const [y, x, row, at] = [8, 9, 10, 11];  // i32
  return func([I32, I32, I32, I32, I32, I32, I32, I32], [[4, I32]], (emit) => {
    const get = (l: number) => emit(op.get, l), set = (l: number) => emit(op.set, l);
    emit(op.block, op.void, op.loop, op.void);  // rows
    get(y); get(height); emit(op.i32GeS, op.brIf, 1);
    get(half); get(y); get(cols); emit(op.i32Mul, op.i32Const, signed(2), op.i32Shl, op.i32Add); set(row);
    emit(op.i32Const, signed(0)); set(x);
    emit(op.block, op.void, op.loop, op.void);  // columns
    get(x); get(width); emit(op.i32GeS, op.brIf, 1);
    get(row); get(lower); get(x); emit(op.i32Const, signed(2), op.i32Shl, op.i32Add, op.i32Load, 2, 0, op.i32Add); set(at);
    get(out);
    get(a0); get(x); emit(op.i32Const, signed(3), op.i32Shl, op.i32Add, op.f64Load, 3, 0);
    get(at); emit(op.f32Load, 2, 0, op.f64PromoteF32, op.f64Mul);
    get(a1); get(x); emit(op.i32Const, signed(3), op.i32Shl, op.i32Add, op.f64Load, 3, 0);
    get(at); emit(op.f32Load, 2, 4, op.f64PromoteF32, op.f64Mul, op.f64Add, op.f32DemoteF64, op.f32Store, 2, 0);
    get(out); emit(op.i32Const, signed(4), op.i32Add); set(out);
    get(x); emit(op.i32Const, signed(1), op.i32Add); set(x);
    emit(op.br, 0, op.end, op.end);
    get(y); emit(op.i32Const, signed(1), op.i32Add); set(y);
    emit(op.br, 0, op.end, op.end);
  });
}

/** valid(mapX, mapY, out, count, low, right, bottom): tps.ts warpValidMask, out[i] = 1 where low <= mapX[i] <= right
 * and low <= mapY[i] <= bottom (float32 compares), else 0 (NaN: 0). */
function validFunction(): Func {
  const [mapX, mapY, out, count, low, right, bottom] = [0, 1, 2, 3, 4, 5, 6];
  const [i, x, y] = [7, 8, 9];
  return func([I32, I32, I32, I32, F32, F32, F32], [[1, I32], [2, F32]], (emit) => {
    const get = (l: number) => emit(op.get, l), set = (l: number) => emit(op.set, l);
    emit(op.block, op.void, op.loop, op.void);
    get(i); get(count); emit(op.i32GeS, op.brIf, 1);
    get(mapX); get(i); emit(op.i32Const, signed(2), op.i32Shl, op.i32Add, op.f32Load, 2, 0); set(x);
    get(mapY); get(i); emit(op.i32Const, signed(2), op.i32Shl, op.i32Add, op.f32Load, 2, 0); set(y);
    get(out); get(i); emit(op.i32Const, signed(2), op.i32Shl, op.i32Add);
    get(x); get(low); emit(op.f32Ge); get(x); get(right); emit(op.f32Le, op.i32And);
    get(y); get(low); emit(op.f32Ge, op.i32And); get(y); get(bottom); emit(op.f32Le, op.i32And);
    emit(op.f32ConvertI32U, op.f32Store, 2, 0);
    get(i); emit(op.i32Const, signed(1), op.i32Add); set(i);
    emit(op.br, 0, op.end, op.end);
  });
}

// ---- the sources and their remaps ---------------------------------------------------------------------------

let compiled: WebAssembly.Module | null | undefined;

function module(): WebAssembly.Module | null {
  if (compiled === undefined) {
    try {
      const bytes = moduleBytes([["remap", remapFunction()], ["densify", densifyFunction()], ["valid", validFunction()]]) as Uint8Array<ArrayBuffer>;
      compiled = typeof WebAssembly === "object" && WebAssembly.validate(bytes) ? new WebAssembly.Module(bytes) : null;
    } catch {
      compiled = null;
    }
  }
  return compiled;
}

const PAGE = 65536;  // bytes in a WebAssembly memory page

/** Where things lie in a CubicSources' memory past the sources (byte offsets, 16-byte aligned). */
interface Layout { values: number; half: number; mapX: number; mapY: number; dst: number; mask: number; halfX: number;
                   halfY: number; lower: number; a0: number; a1: number; end: number }

function layout(start: number, values: number, half: number, width: number): Layout {
  let at = start;
  const take = (bytes: number) => { const here = at; at += Math.ceil(bytes / 16) * 16; return here; };
  const mapX = take(values * 4), mapY = take(values * 4), dst = take(values * 3 + 16), mask = take(values * 4);
  const halfX = take(half * 4), halfY = take(half * 4), lower = take(width * 4), a0 = take(width * 8), a1 = take(width * 8);
  return { values, half, mapX, mapY, dst, mask, halfX, halfY, lower, a0, a1, end: at };
}

/** `count` RGB uint8 images of one size, held in WebAssembly memory to be remapped (the warp-guided references'
 * shots: the same for every frame). */
export class CubicSources {
  private readonly exports: Record<string, (...args: number[]) => void>;
  private readonly sourceBytes: number;
  private at: Layout;
  private across: Interpolation | null = null;  // the interpolation tables now in memory

  private constructor(private readonly memory: WebAssembly.Memory, instance: WebAssembly.Instance,
                      private readonly images: Uint8Array, readonly count: number, readonly width: number,
                      readonly height: number) {
    this.exports = instance.exports as unknown as Record<string, (...args: number[]) => void>;
    this.sourceBytes = count * width * height * 16;
    this.at = layout(this.sourceBytes, 0, 0, width);
  }

  /** The sources (count, height, width, 3) uint8 flat, or null where WebAssembly SIMD is not available. */
  static create(images: Uint8Array, count: number, width: number, height: number): CubicSources | null {
    const compiledModule = module();
    if (compiledModule === null || width < 4 || height < 4 || images.length !== count * width * height * 3) return null;
    try {
      const instance = new WebAssembly.Instance(compiledModule, {});
      const memory = instance.exports.memory as WebAssembly.Memory;
      const sources = new CubicSources(memory, instance, images, count, width, height);
      sources.reserve(width * height, 0);
      const expanded = new Float32Array(memory.buffer, 0, count * width * height * 4);
      for (let p = 0, j = 0; j < images.length; p += 4, j += 3) {
        expanded[p] = images[j]; expanded[p + 1] = images[j + 1]; expanded[p + 2] = images[j + 2];
      }
      return sources;
    } catch {
      return null;
    }
  }

  /** Room past the sources for maps of `values` entries (and grids of `half` rows x cols). */
  private reserve(values: number, half: number): Layout {
    if (values > this.at.values || half > this.at.half) {
      this.at = layout(this.sourceBytes, Math.max(values, this.at.values), Math.max(half, this.at.half), this.width);
      this.across = null;
      const have = this.memory.buffer.byteLength;
      if (this.at.end > have) this.memory.grow(Math.ceil((this.at.end - have) / PAGE));
    }
    return this.at;
  }

  /** Whether these are `images` (the same array, whose values must not have changed since). */
  holds(images: Uint8Array, count: number, width: number, height: number): boolean {
    return images === this.images && count === this.count && width === this.width && height === this.height;
  }

  /** remapCubic(source `index`, mapX, mapY, border, dst): the same bytes. dst: (mapX.length * 3) uint8. */
  remap(index: number, mapX: Float32Array, mapY: Float32Array, border: BorderMode, dst: Uint8Array): void {
    const values = mapX.length;
    if (mapY.length !== values || dst.length !== values * 3) throw new Error("mapX, mapY and the output must be of one size");
    const at = this.reserve(values, 0), buffer = this.memory.buffer;
    new Float32Array(buffer, at.mapX, values).set(mapX);
    new Float32Array(buffer, at.mapY, values).set(mapY);
    this.remapAt(index, at, values, border, dst);
  }

  /** The maps on a coarse grid of the sources' size (tps.ts GridMap: mapX, mapY (rows, cols)) made dense as
   * densifyGrid makes them, source `index` remapped through them as `remap` does into dst ((height * width * 3)
   * uint8), and their warpValidMask into mask ((height * width) float32): the same values. False (nothing done)
   * for a grid of step 1 or of another size. */
  warp(index: number, grid: CoarseGrid, mapX: ArrayLike<number>, mapY: ArrayLike<number>, border: BorderMode,
       dst: Uint8Array, mask: Float32Array): boolean {
    const { width, height } = this, values = width * height, cols = grid.xs.length, rows = height * cols;
    if (grid.step === 1 || grid.width !== width || grid.height !== height) return false;
    if (dst.length !== values * 3 || mask.length !== values) throw new Error("the output and mask must be the sources' size");
    const at = this.reserve(values, rows), buffer = this.memory.buffer;
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
    const { densify, valid } = this.exports, f = Math.fround, slack = 1e-3;
    densify(at.halfX, cols, at.lower, at.a0, at.a1, at.mapX, width, height);
    densify(at.halfY, cols, at.lower, at.a0, at.a1, at.mapY, width, height);
    valid(at.mapX, at.mapY, at.mask, values, f(-slack), f(width - 1 + slack), f(height - 1 + slack));
    mask.set(new Float32Array(buffer, at.mask, values));
    this.remapAt(index, at, values, border, dst);
    return true;
  }

  /** The remap of the maps already at at.mapX, at.mapY. */
  private remapAt(index: number, at: Layout, values: number, border: BorderMode, dst: Uint8Array): void {
    const { width, height } = this, buffer = this.memory.buffer;
    this.exports.remap(index * width * height * 16, width, at.mapX, at.mapY, at.dst, values, width - 2, height - 2);
    dst.set(new Uint8Array(buffer, at.dst, values * 3));
    const image = this.images.subarray(index * width * height * 3, (index + 1) * width * height * 3);
    remapCubicBorder({ data: image, width, height, channels: 3 }, new Float32Array(buffer, at.mapX, values),
                     new Float32Array(buffer, at.mapY, values), border, dst);
  }
}
