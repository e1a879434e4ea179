// tps.ts evaluate (landmarks.warp.tps ThinPlateSpline.dense: a fitted spline at every point of a coarse grid) in
// WebAssembly: the warps' spline (all the nearest shots' maps from one solve) and the head layer's (composite.ts) are
// evaluated at thousands of grid points against ~50-80 control points each frame. Per point, the kernel row
// U(r) = r^2 log r^2 two control points at a time (float64 lanes), its log `splineLog` below (fdlibm's e_log.c
// reduction and polynomial, one path for every lane, written out twice: here and in JavaScript, so that both give
// the same float64 values; within an ulp of Math.log, which the engine calls out of WebAssembly at three times the
// cost), then each pair of output columns summed in one SIMD register, four pairs per pass over the row, the affine
// part first and the kernel terms by control point, as evaluate's JavaScript sums each column.

import { F64, Func, I32, V, V128, float64, func, op, reserveMemory, signed, simd,
         sharedInstance, webAssemblyWanted } from "./wasm.js";

// fdlibm's e_log.c: ln 2 in two parts and the minimax polynomial's coefficients (its Lg1..Lg7)
const LN2_HI = 6.93147180369123816490e-01, LN2_LO = 1.90821492927058770002e-10;
const LG = [6.666666666666735130e-01, 3.999999999940941908e-01, 2.857142874366239149e-01, 2.222219843214978396e-01,
            1.818357216161805012e-01, 1.531383769920937332e-01, 1.479819860511658591e-01];
const LOG_VALUE = new Float64Array(1), LOG_WORDS = new Uint32Array(LOG_VALUE.buffer);  // little-endian: [low, high]

/** ln x for a finite x > 0 (a normal float64): x = 2^k m with m in [sqrt(2)/2, sqrt(2)), f = m - 1, s = f / (2 + f),
 * ln m = f - (f^2 / 2 - s (f^2 / 2 + R(s^2))) (fdlibm's general path for every x), k ln 2 in two parts. The kernel
 * below computes it in the same operations, two lanes at a time. */
export function splineLog(x: number): number {
  LOG_VALUE[0] = x;
  const high = LOG_WORDS[1];
  let k = (high >>> 20) - 1023;
  LOG_WORDS[1] = (high & 0xfffff) | 0x3ff00000;  // the mantissa with 1's exponent: [1, 2)
  let m = LOG_VALUE[0];
  if (m > Math.SQRT2) { m = m * 0.5; k = k + 1; }
  const f = m - 1, s = f / (2 + f), z = s * s, w = z * z;
  const t1 = w * (LG[1] + w * (LG[3] + w * LG[5])), t2 = z * (LG[0] + w * (LG[2] + w * (LG[4] + w * LG[6])));
  const r = t2 + t1, halfSquare = 0.5 * f * f;
  return k * LN2_HI - ((halfSquare - (s * (halfSquare + r) + k * LN2_LO)) - f);
}

/** spline(points, total, controlX, controlY, count, weights, affine, columns, out, row, cx, cy, scale): for each of
 * `total` points (x, y) float64, its normalised (x', y') = ((x - cx) / scale, (y - cy) / scale), the kernel row
 * row[i] = U(|(x', y') - control[i]|^2) (0 where the squared distance is not > 0), then out[p, c] =
 * affine[0, c] + x' affine[1, c] + y' affine[2, c] + sum_i row[i] weights[i, c], two columns at a time. Float64
 * (count,) controlX and controlY (padded to an even count), (count, columns) weights, (3, columns) affine,
 * (total, columns) out, row (an even count); `columns` even. */
function splineFunction(): Func {
  const [points, total, controlX, controlY, count, weights, affine, columns, out, row, cx, cy, scale] =
    [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12];
  const [p, i, c, at] = [13, 14, 15, 16];  // i32
  const [x, y] = [17, 18];  // f64
  const [X, Y, kernel] = [19, 20, 21];  // v128
  const sums = [22, 23, 24, 25, 37];  // v128 (37: after the log's locals)
  const [SQ, E, M, BIG, DK, F, S, Z, W, T, HALF] = [26, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36];  // v128: the log's
  // the log's constants, each in a local set once (a v128.const in the loop was rebuilt on every pass)
  const CONSTANTS = [Math.SQRT2, 0.5, 2 ** 52 + 1023, 1, 2, LN2_HI, LN2_LO, 0, ...LG];
  const MASKS = [[0xffffffff, 0xfffff], [0, 0x3ff00000], [0, 0x43300000]];  // mantissa, 1's exponent, 2^52's
  const firstConstant = 38, constantCount = CONSTANTS.length + MASKS.length;
  const params = [I32, I32, I32, I32, I32, I32, I32, I32, I32, I32, F64, F64, F64];
  return func(params, [], [[4, I32], [2, F64], [19 + constantCount, V128]], (emit) => {
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
    const [add, sub, mul, div] = [simd(V.f64x2Add), simd(V.f64x2Sub), simd(V.f64x2Mul), simd(V.f64x2Div)];
    CONSTANTS.forEach((value, k) => { emit(simd(V.const), float64(value), float64(value)); set(firstConstant + k); });
    MASKS.forEach(([low, high], k) => {  // i64x2 constants of two 32-bit words, both lanes
      const lane = Array.from(new Uint8Array(new Uint32Array([low, high]).buffer));
      emit(simd(V.const), lane, lane); set(firstConstant + CONSTANTS.length + k);
    });
    const constant = (k: number) => {
      if (k < 0) throw new Error("a spline kernel constant is missing from its table");
      get(firstConstant + k);
    };
    const both = (value: number) => constant(CONSTANTS.indexOf(value));  // value in both lanes
    const words = (low: number, high: number) => {  // an i64x2 mask of MASKS
      const k = MASKS.findIndex(([l, h]) => l === low && h === high);
      constant(k < 0 ? k : CONSTANTS.length + k);
    };
    /** row[i, i + 1] = U(SQ) per lane: splineLog's operations, then SQ log SQ where SQ > 0, else 0. */
    const kernelPair = () => {
      get(SQ); i32(52); emit(simd(V.i64x2ShrU)); set(E);  // the biased exponent (SQ > 0: no sign bit)
      get(SQ); words(0xffffffff, 0xfffff); emit(simd(V.and)); words(0, 0x3ff00000); emit(simd(V.or)); set(M);
      get(M); both(Math.SQRT2); emit(simd(V.f64x2Gt)); set(BIG);
      get(M); both(0.5); emit(mul); get(M); get(BIG); emit(simd(V.bitselect)); set(M);
      // k = (2^52 + exponent) - (2^52 + 1023), exactly; + 1 where m was halved
      get(E); words(0, 0x43300000); emit(simd(V.or)); both(2 ** 52 + 1023); emit(sub); set(DK);
      get(DK); both(1); emit(add); get(DK); get(BIG); emit(simd(V.bitselect)); set(DK);
      get(M); both(1); emit(sub); set(F);
      get(F); both(2); get(F); emit(add, div); set(S);
      get(S); get(S); emit(mul); tee(Z); get(Z); emit(mul); set(W);
      get(W); both(LG[5]); emit(mul); both(LG[3]); emit(add); get(W); emit(mul); both(LG[1]); emit(add); get(W);
      emit(mul); set(T);  // t1
      get(W); both(LG[6]); emit(mul); both(LG[4]); emit(add); get(W); emit(mul); both(LG[2]); emit(add); get(W);
      emit(mul); both(LG[0]); emit(add); get(Z); emit(mul);  // t2
      get(T); emit(add); set(T);  // r = t2 + t1
      both(0.5); get(F); emit(mul); get(F); emit(mul); set(HALF);
      get(DK); both(LN2_HI); emit(mul);
      get(HALF); get(HALF); get(T); emit(add); get(S); emit(mul); get(DK); both(LN2_LO); emit(mul, add, sub);
      get(F); emit(sub, sub);  // ln SQ
      get(SQ); emit(mul);  // U = SQ ln SQ
      both(0); get(SQ); both(0); emit(simd(V.f64x2Gt), simd(V.bitselect));
    };
    loop(p, total, 1, () => {
      get(points); get(p); i32(4); emit(op.i32Shl, op.i32Add); tee(at);
      emit(op.f64Load, 3, 0); get(cx); emit(op.f64Sub); get(scale); emit(op.f64Div); set(x);
      get(at); emit(op.f64Load, 3, 8); get(cy); emit(op.f64Sub); get(scale); emit(op.f64Div); set(y);
      get(x); emit(simd(V.f64x2Splat)); set(X);
      get(y); emit(simd(V.f64x2Splat)); set(Y);
      loop(i, count, 2, () => {  // two control points at a time: dx^2 + dy^2, then the kernel
        get(i); i32(3); emit(op.i32Shl); set(at);
        get(X); get(controlX); get(at); emit(op.i32Add, simd(V.load), 3, 0, sub); tee(kernel); get(kernel); emit(mul);
        get(Y); get(controlY); get(at); emit(op.i32Add, simd(V.load), 3, 0, sub); tee(kernel); get(kernel); emit(mul);
        emit(add); set(SQ);
        get(row); get(at); emit(op.i32Add);
        kernelPair();
        emit(simd(V.store), 3, 0);
      });
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
      // four pairs a pass while six or more are left, then the 1 to 5 left in one pass: each pass's sums are
      // independent chains, so the five pairs of five references take one pass (five chains), not four and one
      i32(0); set(c);
      emit(op.block, op.void, op.loop, op.void);
      get(c); i32(12); emit(op.i32Add); get(columns); emit(op.i32GtS, op.brIf, 1);
      pass(4);
      emit(op.br, 0, op.end, op.end);
      for (let pairs = 5; pairs >= 1; pairs--) {
        get(columns); get(c); emit(op.i32Sub); i32(2 * pairs); emit(op.i32Eq, op.if, op.void);
        pass(pairs);
        emit(op.end);
      }
    });
  });
}

const splineKernel = sharedInstance(() => [["spline", splineFunction()]]);

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
  const pointsAt = 0, controlXAt = pointsAt + aligned(2 * total), controlYAt = controlXAt + aligned(count);
  const weightsAt = controlYAt + aligned(count), affineAt = weightsAt + aligned(count * even);
  const rowAt = affineAt + aligned(3 * even), outAt = rowAt + aligned(count);
  reserveMemory(wasm.memory, outAt + aligned(total * even));
  const buffer = wasm.memory.buffer;
  new Float64Array(buffer, pointsAt, 2 * total).set(points);
  // the control points' x and y apart, each padded to an even count with 0 (a lane whose kernel is never read)
  const controlX = new Float64Array(buffer, controlXAt, aligned(count) / 8).fill(0);
  const controlY = new Float64Array(buffer, controlYAt, aligned(count) / 8).fill(0);
  for (let i = 0; i < count; i++) { controlX[i] = control[2 * i]; controlY[i] = control[2 * i + 1]; }
  if (even === columns) {
    new Float64Array(buffer, weightsAt, count * even).set(weights);
    new Float64Array(buffer, affineAt, 3 * even).set(affine);
  } else {  // an odd column count: each row padded with a zero column
    const w = new Float64Array(buffer, weightsAt, count * even).fill(0);
    const a = new Float64Array(buffer, affineAt, 3 * even).fill(0);
    for (let i = 0; i < count; i++) w.set(weights.subarray(i * columns, (i + 1) * columns), i * even);
    for (let r = 0; r < 3; r++) a.set(affine.subarray(r * columns, (r + 1) * columns), r * even);
  }
  wasm.kernels.spline(pointsAt, total, controlXAt, controlYAt, count, weightsAt, affineAt, even, outAt, rowAt, centre[0],
              centre[1], scale);
  const out = new Float64Array(buffer, outAt, total * even);
  if (even === columns) return out.slice();
  const trimmed = new Float64Array(total * columns);
  for (let p = 0; p < total; p++) trimmed.set(out.subarray(p * even, p * even + columns), p * columns);
  return trimmed;
}
