// tps.ts evaluate (landmarks.warp.tps ThinPlateSpline.dense: a fitted spline at every point of a coarse grid) in
// WebAssembly: the warps' spline (all the nearest shots' maps from one solve) and the head layer's (composite.ts) are
// evaluated at thousands of grid points against ~50-80 control points each frame. Per point, the kernel row
// U(r) = r^2 log r^2 with the engine's own Math.log (imported; engines differ in their last bit, so no log of our
// own), then each pair of output columns summed in one SIMD register, four pairs per pass over the row, the affine
// part first and the kernel terms by control point, as evaluate's JavaScript sums each column: the same float64
// values out.

import { F64, Func, I32, V, V128, compileModule, float64, func, op, reserveMemory, signed, simd,
         webAssemblyWanted } from "./wasm.js";

/** spline(points, total, control, count, weights, affine, columns, out, row, cx, cy, scale): for each of `total`
 * points (x, y) float64, its normalised (x', y') = ((x - cx) / scale, (y - cy) / scale), the kernel row
 * row[i] = U(|(x', y') - control[i]|^2) (0 where the squared distance is not > 0), then out[p, c] =
 * affine[0, c] + x' affine[1, c] + y' affine[2, c] + sum_i row[i] weights[i, c], two columns at a time. Float64
 * (count, 2) control, (count, columns) weights, (3, columns) affine, (total, columns) out; `columns` even. */
function splineFunction(): Func {
  const [points, total, control, count, weights, affine, columns, out, row, cx, cy, scale] =
    [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];
  const [p, i, c, at] = [12, 13, 14, 15];  // i32
  const [x, y, dx, dy, squared] = [16, 17, 18, 19, 20];  // f64
  const [X, Y, kernel] = [21, 22, 23];  // v128
  const sums = [24, 25, 26, 27];  // v128
  const params = [I32, I32, I32, I32, I32, I32, I32, I32, I32, F64, F64, F64];
  return func(params, [], [[4, I32], [5, F64], [7, V128]], (emit) => {
    const get = (l: number) => emit(op.get, l), set = (l: number) => emit(op.set, l), tee = (l: number) => emit(op.tee, l);
    const i32 = (v: number) => emit(op.i32Const, signed(v));
    const increment = (l: number, by: number) => { get(l); i32(by); emit(op.i32Add); set(l); };
    // loop over `counter` from 0 while < `limit`, with `body`
    const loop = (counter: number, limit: number, step: number, body: () => void) => {
      i32(0); set(counter);
      emit(op.block, op.void, op.loop, op.void);
      get(counter); get(limit); emit(op.i32GeS, op.brIf, 1);
      body();
      increment(counter, step);
      emit(op.br, 0, op.end, op.end);
    };
    const [add, mul] = [simd(V.f64x2Add), simd(V.f64x2Mul)];
    loop(p, total, 1, () => {
      get(points); get(p); i32(4); emit(op.i32Shl, op.i32Add); tee(at);
      emit(op.f64Load, 3, 0); get(cx); emit(op.f64Sub); get(scale); emit(op.f64Div); set(x);
      get(at); emit(op.f64Load, 3, 8); get(cy); emit(op.f64Sub); get(scale); emit(op.f64Div); set(y);
      loop(i, count, 1, () => {
        get(x); get(control); get(i); i32(4); emit(op.i32Shl, op.i32Add); tee(at); emit(op.f64Load, 3, 0, op.f64Sub); set(dx);
        get(y); get(at); emit(op.f64Load, 3, 8, op.f64Sub); set(dy);
        get(dx); get(dx); emit(op.f64Mul); get(dy); get(dy); emit(op.f64Mul, op.f64Add); set(squared);
        get(row); get(i); i32(3); emit(op.i32Shl, op.i32Add);
        get(squared); emit(op.f64Const, float64(0), op.f64Gt, op.if, F64);
        get(squared); get(squared); emit(op.call, 0, op.f64Mul);  // U = r^2 log r^2, Math.log imported as function 0
        emit(op.else, op.f64Const, float64(0), op.end, op.f64Store, 3, 0);
      });
      get(x); emit(simd(V.f64x2Splat)); set(X);
      get(y); emit(simd(V.f64x2Splat)); set(Y);
      // four pairs of columns at a time (each kernel value loaded once for eight sums), then pair by pair
      const pass = (pairs: number) => {
        const into = sums.slice(0, pairs);
        into.forEach((sum, q) => {  // affine[0, c] + x' affine[1, c] + y' affine[2, c], for columns c, c + 1
          get(affine); get(c); i32(3); emit(op.i32Shl, op.i32Add); tee(at); emit(simd(V.load), 3, 16 * q);
          get(X); get(at); get(columns); i32(3); emit(op.i32Shl, op.i32Add); tee(at); emit(simd(V.load), 3, 16 * q);
          emit(mul, add);
          get(Y); get(at); get(columns); i32(3); emit(op.i32Shl, op.i32Add); emit(simd(V.load), 3, 16 * q);
          emit(mul, add); set(sum);
        });
        // + row[i] weights[i, c] by control point
        get(weights); get(c); i32(3); emit(op.i32Shl, op.i32Add); set(at);
        loop(i, count, 1, () => {
          get(row); get(i); i32(3); emit(op.i32Shl, op.i32Add); emit(simd(V.load64Splat), 3, 0); set(kernel);
          into.forEach((sum, q) => { get(sum); get(kernel); get(at); emit(simd(V.load), 3, 16 * q, mul, add); set(sum); });
          get(at); get(columns); i32(3); emit(op.i32Shl, op.i32Add); set(at);
        });
        into.forEach((sum, q) => {
          get(out); get(p); get(columns); emit(op.i32Mul); get(c); emit(op.i32Add); i32(3); emit(op.i32Shl, op.i32Add);
          get(sum); emit(simd(V.store), 3, 16 * q);
        });
        increment(c, 2 * pairs);
      };
      i32(0); set(c);
      emit(op.block, op.void, op.loop, op.void);
      get(c); i32(8); emit(op.i32Add); get(columns); emit(op.i32GtS, op.brIf, 1);
      pass(4);
      emit(op.br, 0, op.end, op.end);
      emit(op.block, op.void, op.loop, op.void);
      get(c); get(columns); emit(op.i32GeS, op.brIf, 1);
      pass(1);
      emit(op.br, 0, op.end, op.end);
    });
  });
}

interface SplineKernel { memory: WebAssembly.Memory; spline: (...args: number[]) => void }
let kernel: SplineKernel | null | undefined;

function splineKernel(): SplineKernel | null {
  if (kernel === undefined) {
    const compiled = compileModule([["spline", splineFunction()]], [{ label: "log", params: [F64], results: [F64] }]);
    try {
      const instance = compiled && new WebAssembly.Instance(compiled, { env: { log: Math.log } });
      kernel = instance ? { memory: instance.exports.memory as WebAssembly.Memory,
                            spline: instance.exports.spline as (...args: number[]) => void } : null;
    } catch {
      kernel = null;
    }
  }
  return kernel;
}

/** Whether splines are evaluated in WebAssembly here (false: tps.ts's JavaScript). */
export function splinesInWasm(): boolean {
  return webAssemblyWanted() && splineKernel() !== null;
}

/** The bytes `values` float64 take, rounded up to 16. */
function aligned(values: number): number {
  return Math.ceil((values * 8) / 16) * 16;
}

/** A fitted spline's parts (tps.ts ThinPlateSpline) at `points` (M, 2) flat -> (M, columns) flat, as tps.ts evaluate
 * gives them; null without WebAssembly SIMD. */
export function evaluateSpline(control: Float64Array, weights: Float64Array, affine: Float64Array, columns: number,
                               centre: [number, number], scale: number, points: Float64Array): Float64Array | null {
  const wasm = webAssemblyWanted() ? splineKernel() : null;
  if (wasm === null) return null;
  const count = control.length / 2, total = points.length / 2, even = columns + (columns % 2);
  // the float64 arrays' offsets, each 16-byte aligned (no closures made per call: V8 optimised those on every frame)
  const pointsAt = 0, controlAt = pointsAt + aligned(2 * total), weightsAt = controlAt + aligned(2 * count);
  const affineAt = weightsAt + aligned(count * even), rowAt = affineAt + aligned(3 * even), outAt = rowAt + aligned(count);
  reserveMemory(wasm.memory, outAt + aligned(total * even));
  const buffer = wasm.memory.buffer;
  new Float64Array(buffer, pointsAt, 2 * total).set(points);
  new Float64Array(buffer, controlAt, 2 * count).set(control);
  if (even === columns) {
    new Float64Array(buffer, weightsAt, count * even).set(weights);
    new Float64Array(buffer, affineAt, 3 * even).set(affine);
  } else {  // an odd column count: each row padded with a zero column
    const w = new Float64Array(buffer, weightsAt, count * even).fill(0);
    const a = new Float64Array(buffer, affineAt, 3 * even).fill(0);
    for (let i = 0; i < count; i++) w.set(weights.subarray(i * columns, (i + 1) * columns), i * even);
    for (let r = 0; r < 3; r++) a.set(affine.subarray(r * columns, (r + 1) * columns), r * even);
  }
  wasm.spline(pointsAt, total, controlAt, count, weightsAt, affineAt, even, outAt, rowAt, centre[0], centre[1], scale);
  const out = new Float64Array(buffer, outAt, total * even);
  if (even === columns) return out.slice();
  const trimmed = new Float64Array(total * columns);
  for (let p = 0; p < total; p++) trimmed.set(out.subarray(p * even, p * even + columns), p * columns);
  return trimmed;
}
