// Bicubic remaps of fixed source images in WebAssembly with 128-bit SIMD (wasm.ts): the warp-guided references'
// shots (references.ts warpReferences) and the scene the head layer moves (composite.ts). remap.ts's bicubic remap
// (cv2.remap INTER_CUBIC of uint8 RGB: float weights at the exact position, Keys' a = -0.75, rounded half to even and
// saturated), with the dense maps made from the coarse grid (remap.ts densifyGrid's second pass) and their validity
// mask (tps.ts warpValidMask) beside it. Each source pixel is stored once as four float32 (R, G, B, 0), so that a
// tap is one load and a pixel's three channels go through one float32x4 lane each: the same float32 weights,
// products and sums, in the same order, as remap.ts's JavaScript (the weights of x and of y computed side by side in
// one register): the same bytes out (the same float32 maps, the same masks). Pixels whose taps leave the source read
// the nearest edge pixels there under the replicated border (the warps'); under the other borders, and far off, they
// are listed and left to remap.ts (remapCubicListed, with the border rule). The maps can be written straight into the
// module's memory (`mapSlots`), so that nothing is copied in. Where WebAssembly or its SIMD is missing,
// `CubicSources.create` gives null and the callers keep to remap.ts.

import { BorderMode, CoarseGrid, Interpolation, densifyRows, gridAcross, remapCubic, remapCubicListed } from "./remap.js";
import { Tensor, tensor } from "./tensor.js";
import { F32, Func, I32, V, V128, compileModule, float32, func, op, reserveMemory, signed, simd, unsigned,
         webAssemblyWanted } from "./wasm.js";

const PIXEL = 16;  // bytes of a source pixel: (R, G, B, 0) float32

/** remap(src, width, height, mapX, mapY, dst, count, only, replicate, listed) -> listed count: for each i < count
 * (where `only` is 0, or only[i] is not), dst[3i .. 3i + 2] from (mapX[i], mapY[i]) where its 4 x 4 taps lie inside
 * the source, or where `replicate` is 1 and |x|, |y| < 1e7 (the taps outside read the nearest edge pixel, as
 * remap.ts cubicAt's replicated border); else i appended to the int32 list at `listed`. src: the source as (R, G, B,
 * 0) float32 per pixel, (height, width); mapX, mapY: float32; dst: uint8 RGB; only: uint8. Pixels not written are left
 * as they are. A pixel's three channels are the lanes of one float32x4: its weights, each tap's product and each sum
 * rounded to float32 in remap.ts cubicInside3's order (the same bytes). */
function remapFunction(): Func {
  const params = [I32, I32, I32, I32, I32, I32, I32, I32, I32, I32];
  const [src, width, height, mapX, mapY, dst, count, only, replicate, listed] = params.map((_, k) => k);
  let next = params.length;
  const take = (size: number) => Array.from({ length: size }, () => next++);
  const [i, n, ix, iy, row, rowBytes, c0, c1, c2, c3, r0, r1, r2, r3] = take(14);  // i32
  const [ix2, iy2, s0, s1, s2, s3] = take(6);  // i32: the second pixel of a pair's
  const [x, y, xEnd, yEnd, x2, y2] = take(6);  // f32
  // v128: the fractions (x, y) in lanes 0 and 1, the four weights of x and of y side by side, each weight of x and of
  // y in all four lanes, the sum, the bytes out
  const [T, S, W0, W1, W2, W3, X0, X1, X2, X3, Y0, Y1, Y2, Y3, SUM, OUT] = take(16);
  const [U0, U1, U2, U3, V0, V1, V2, V3, SUM2] = take(9);  // the second pixel's weights of x and y, and its sum
  const A = -0.75;
  const constants = [1, A, 5 * A, 8 * A, 4 * A, A + 2, A + 3];  // each in every lane of a v128 local
  const C = take(constants.length);
  return func(params, [I32], [[20, I32], [6, F32], [25 + constants.length, V128]], (emit) => {
    const get = (l: number) => emit(op.get, l), set = (l: number) => emit(op.set, l);
    const i32 = (v: number) => emit(op.i32Const, signed(v));
    const f32 = (v: number) => emit(op.f32Const, float32(v));
    const all = (v: number) => get(C[constants.indexOf(v)]);  // v in every lane
    constants.forEach((v, k) => { emit(simd(V.const), [0, 1, 2, 3].flatMap(() => float32(v))); set(C[k]); });
    const [mul, add, sub] = [simd(V.f32x4Mul), simd(V.f32x4Add), simd(V.f32x4Sub)];
    // w = ((A p - 5 A) p + 8 A) p - 4 A, p = t + 1 (remap.ts cubicWeights' first weight)
    const outer = (into: number) => {
      get(T); all(1); emit(add); set(S);
      all(A); get(S); emit(mul); all(5 * A); emit(sub); get(S); emit(mul); all(8 * A); emit(add);
      get(S); emit(mul); all(4 * A); emit(sub); set(into);
    };
    // w = ((A + 2) v - (A + 3)) v v + 1
    const inner = (value: number, into: number) => {
      all(A + 2); get(value); emit(mul); all(A + 3); emit(sub); get(value); emit(mul); get(value); emit(mul);
      all(1); emit(add); set(into);
    };
    // lane `at` of a weight in every lane
    const lane = (from: number, at: number, into: number) => {
      const bytes = Array.from({ length: 16 }, (_, k) => 4 * at + (k % 4));
      get(from); get(from); emit(simd(V.shuffle), bytes); set(into);
    };
    // the weights of T's fractions (x, y of a pixel in lanes 0, 1; with `pair`, a second pixel's in lanes 2, 3)
    const weights = (pair = false) => {
      outer(W0);
      inner(T, W1);
      all(1); get(T); emit(sub); set(S);
      inner(S, W2);
      all(1); get(W0); emit(sub); get(W1); emit(sub); get(W2); emit(sub); set(W3);
      lane(W0, 0, X0); lane(W1, 0, X1); lane(W2, 0, X2); lane(W3, 0, X3);
      lane(W0, 1, Y0); lane(W1, 1, Y1); lane(W2, 1, Y2); lane(W3, 1, Y3);
      if (!pair) return;
      lane(W0, 2, U0); lane(W1, 2, U1); lane(W2, 2, U2); lane(W3, 2, U3);
      lane(W0, 3, V0); lane(W1, 3, V1); lane(W2, 3, V2); lane(W3, 3, V3);
    };
    // into `total`: the sum over rows k of ys_k * (the sum over the row's taps j of pixel * xs_j, in order); tap(k, j)
    // pushes the address of tap (k, j) and gives the load's offset
    const sum = (tap: (k: number, j: number) => number, xs = [X0, X1, X2, X3], ys = [Y0, Y1, Y2, Y3], total = SUM) => {
      ys.forEach((Y, k) => {
        if (k > 0) get(total);
        xs.forEach((X, j) => {
          emit(simd(V.load), 4, unsigned(tap(k, j)));
          get(X); emit(mul);
          if (j > 0) emit(add);
        });
        get(Y); emit(mul);
        if (k > 0) emit(add);
        set(total);
      });
    };
    // `total` rounded half to even, saturated to [0, 255] by the two narrowings: R, G and B as bytes 0-2 of pixel
    // `pixel` (its index: pushed by `pixel()`)
    const store = (total: number, pixel: () => void) => {
      get(total); emit(simd(V.f32x4Nearest), simd(V.i32x4TruncSatF32x4S)); set(OUT);
      get(OUT); get(OUT); emit(simd(V.i16x8NarrowI32x4S)); set(OUT);
      get(OUT); get(OUT); emit(simd(V.i8x16NarrowI16x8U)); set(OUT);
      get(dst); pixel(); i32(3); emit(op.i32Mul, op.i32Add); set(row);
      get(row); get(OUT); emit(simd(V.store16Lane), 0, 0, 0);
      get(row); get(OUT); emit(simd(V.store8Lane), 0, 2, 2);
    };
    // the four tap rows' addresses of the pixel at (ix, iy) (its taps from (ix - 1, iy - 1)), into rows
    const tapRows = (atX: number, atY: number, rows: number[]) => {
      get(src); get(atY); i32(1); emit(op.i32Sub); get(width); emit(op.i32Mul); get(atX); emit(op.i32Add);
      i32(1); emit(op.i32Sub); i32(4); emit(op.i32Shl, op.i32Add); set(rows[0]);
      for (let k = 1; k < 4; k++) { get(rows[k - 1]); get(rowBytes); emit(op.i32Add); set(rows[k]); }
    };
    // whether (atX, atY) has its taps inside the source
    const inside = (atX: number, atY: number) => {
      get(atX); f32(1); emit(op.f32Ge); get(atX); get(xEnd); emit(op.f32Lt, op.i32And);
      get(atY); f32(1); emit(op.f32Ge, op.i32And); get(atY); get(yEnd); emit(op.f32Lt, op.i32And);
    };
    // (value + shift) clamped to [0, last], into `into`
    const clamped = (value: number, shift: number, last: number, into: number) => {
      get(value); i32(shift); emit(op.i32Add); set(into);
      i32(0); get(into); get(into); i32(0); emit(op.i32LtS, op.select); set(into);
      get(last); get(into); get(into); get(last); emit(op.i32GtS, op.select); set(into);
    };

    get(width); i32(4); emit(op.i32Shl); set(rowBytes);
    get(width); i32(2); emit(op.i32Sub, op.f32ConvertI32S); set(xEnd);
    get(height); i32(2); emit(op.i32Sub, op.f32ConvertI32S); set(yEnd);
    emit(op.block, op.void, op.loop, op.void);
    get(i); get(count); emit(op.i32GeS, op.brIf, 1);
    // two pixels at once where both are asked for and have their taps inside: their weights in one register, their
    // sums side by side (each pixel's operations as the single path's, in its order); else the single path
    emit(op.block, op.void);
    get(i); i32(1); emit(op.i32Add); get(count); emit(op.i32GeS, op.brIf, 0);
    get(only); emit(op.if, op.void);
    get(only); get(i); emit(op.i32Add, op.i32Load8U, 0, 0, op.i32Eqz, op.brIf, 1);
    get(only); get(i); emit(op.i32Add, op.i32Load8U, 0, 1, op.i32Eqz, op.brIf, 1);
    emit(op.end);
    get(mapX); get(i); i32(2); emit(op.i32Shl, op.i32Add); set(row);
    get(row); emit(op.f32Load, 2, 0); set(x); get(row); emit(op.f32Load, 2, 4); set(x2);
    get(mapY); get(i); i32(2); emit(op.i32Shl, op.i32Add); set(row);
    get(row); emit(op.f32Load, 2, 0); set(y); get(row); emit(op.f32Load, 2, 4); set(y2);
    inside(x, y); inside(x2, y2); emit(op.i32And, op.i32Eqz, op.brIf, 0);
    get(x); emit(op.i32TruncF32S); set(ix);
    get(y); emit(op.i32TruncF32S); set(iy);
    get(x2); emit(op.i32TruncF32S); set(ix2);
    get(y2); emit(op.i32TruncF32S); set(iy2);
    get(x); get(ix); emit(op.f32ConvertI32S, op.f32Sub, simd(V.f32x4Splat));  // exact: x >= 1
    get(y); get(iy); emit(op.f32ConvertI32S, op.f32Sub, simd(V.f32x4Replace), 1);
    get(x2); get(ix2); emit(op.f32ConvertI32S, op.f32Sub, simd(V.f32x4Replace), 2);
    get(y2); get(iy2); emit(op.f32ConvertI32S, op.f32Sub, simd(V.f32x4Replace), 3); set(T);
    weights(true);
    tapRows(ix, iy, [r0, r1, r2, r3]);
    tapRows(ix2, iy2, [s0, s1, s2, s3]);
    sum((k, j) => { get([r0, r1, r2, r3][k]); return PIXEL * j; });
    sum((k, j) => { get([s0, s1, s2, s3][k]); return PIXEL * j; }, [U0, U1, U2, U3], [V0, V1, V2, V3], SUM2);
    store(SUM, () => get(i));
    store(SUM2, () => { get(i); i32(1); emit(op.i32Add); });
    get(i); i32(2); emit(op.i32Add); set(i);
    emit(op.br, 1);  // the loop
    emit(op.end);
    emit(op.block, op.void);  // a pixel done (or left) goes on past this block
    get(only); emit(op.if, op.void);
    get(only); get(i); emit(op.i32Add, op.i32Load8U, 0, 0, op.i32Eqz, op.brIf, 1);
    emit(op.end);
    get(mapX); get(i); i32(2); emit(op.i32Shl, op.i32Add, op.f32Load, 2, 0); set(x);
    get(mapY); get(i); i32(2); emit(op.i32Shl, op.i32Add, op.f32Load, 2, 0); set(y);
    inside(x, y);
    emit(op.if, op.void);  // the taps inside: from (ix - 1, iy - 1), row after row
    get(x); emit(op.i32TruncF32S); set(ix);
    get(y); emit(op.i32TruncF32S); set(iy);
    get(x); get(ix); emit(op.f32ConvertI32S, op.f32Sub, simd(V.f32x4Splat));  // exact: x >= 1
    get(y); get(iy); emit(op.f32ConvertI32S, op.f32Sub, simd(V.f32x4Replace), 1); set(T);
    weights();
    tapRows(ix, iy, [r0, r1, r2, r3]);
    sum((k, j) => { get([r0, r1, r2, r3][k]); return PIXEL * j; });
    emit(op.else);
    // outside: the border replicated where asked and not far off (NaN fails these), else listed
    get(replicate); get(x); emit(op.f32Abs); f32(1e7); emit(op.f32Lt, op.i32And);
    get(y); emit(op.f32Abs); f32(1e7); emit(op.f32Lt, op.i32And, op.i32Eqz);
    emit(op.if, op.void);
    get(listed); get(n); i32(2); emit(op.i32Shl, op.i32Add); get(i); emit(op.i32Store, 2, 0);
    get(n); i32(1); emit(op.i32Add); set(n);
    emit(op.br, 2, op.end);
    get(x); emit(op.f32Floor, op.i32TruncF32S); set(ix);
    get(y); emit(op.f32Floor, op.i32TruncF32S); set(iy);
    get(x); get(x); emit(op.f32Floor, op.f32Sub, simd(V.f32x4Splat));
    get(y); get(y); emit(op.f32Floor, op.f32Sub, simd(V.f32x4Replace), 1); set(T);
    weights();
    get(width); i32(1); emit(op.i32Sub); set(row);
    [c0, c1, c2, c3].forEach((c, j) => { clamped(ix, j - 1, row, c); get(c); i32(4); emit(op.i32Shl); set(c); });
    get(height); i32(1); emit(op.i32Sub); set(row);
    [r0, r1, r2, r3].forEach((r, k) => {
      clamped(iy, k - 1, row, r); get(src); get(r); get(rowBytes); emit(op.i32Mul, op.i32Add); set(r);
    });
    sum((k, j) => { get([r0, r1, r2, r3][k]); get([c0, c1, c2, c3][j]); emit(op.i32Add); return 0; });
    emit(op.end);  // inside or outside
    store(SUM, () => get(i));
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

let imageSources: CubicSources | null = null;  // remapImage's: one instance, the image loaded into it each call

/** remapCubic of one (H, W, 3) uint8 image through float32 maps of one shape: in WebAssembly where the kernels run
 * (remapsInWasm; one instance kept, the image loaded into it each call), else in remap.ts; the same bytes either way
 * -> (...the maps' shape, 3). */
export function remapImage(image: Tensor<Uint8Array>, mapX: Tensor<Float32Array>, mapY: Tensor<Float32Array>,
                           border: BorderMode): Tensor<Uint8Array> {
  const [height, width, channels] = image.shape;
  if (image.shape.length !== 3 || channels !== 3) throw new Error(`the image must be (H, W, 3), got [${image.shape}]`);
  if (mapY.data.length !== mapX.data.length) throw new Error("mapX and mapY must be of one shape");
  const out = new Uint8Array(mapX.data.length * 3);
  imageSources = CubicSources.reload(imageSources, image.data, 1, width, height);
  if (imageSources) imageSources.remap(0, mapX.data, mapY.data, border, out);
  else remapCubic({ data: image.data, width, height, channels: 3 }, mapX.data, mapY.data, border, out);
  return tensor(out, [...mapX.shape, 3]);
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
    const listed = this.exports.remap(index * width * height * PIXEL, width, height, slot.mapX.byteOffset,
                                      slot.mapY.byteOffset, at.dst, values, only ? at.only : 0,
                                      border === "replicate" ? 1 : 0, at.listed);
    dst.set(new Uint8Array(buffer, at.dst, values * 3));
    const image = this.images.subarray(index * width * height * 3, (index + 1) * width * height * 3);
    remapCubicListed({ data: image, width, height, channels: 3 }, slot.mapX, slot.mapY, border, dst,
                     new Int32Array(buffer, at.listed, listed), listed);
  }
}
