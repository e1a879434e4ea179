// remap.ts gaussianBlurF32 (cv2.GaussianBlur of a float32 image, reflect-101 border) in WebAssembly (wasm.ts): the
// composite's colour offset, the eye bank's, the mouth's and the lids' feathers blur a few patches each frame, 1.8 ms
// of the page's thread in JavaScript. Two outputs at a time in float64 lanes, each summed as the JavaScript sums it
// (s = 0, then kernel[k] * value for k in order, the float32 kernel and values promoted exactly, the sum rounded to
// float32 once): the same values out. Across the rows, two channels of a pixel where it has two or more (their taps
// side by side in memory), else two neighbouring pixels; down the columns, two neighbouring values.

import { Func, I32, V, V128, func, op, reserveMemory, sharedInstance, signed, simd, webAssemblyWanted } from "./wasm.js";

/** across(src, out, width, height, channels, kernel, n, index): out[y, x, c] = sum_k kernel[k] src[y, index[x, k] + c]
 * (index: int32 (width, n) element offsets of each tap's pixel, reflect-101's, times channels; kernel: float64 (n,);
 * src, out: float32 (height, width, channels)). */
function acrossFunction(): Func {
  const [src, out, width, height, channels, kernel, n, index] = [0, 1, 2, 3, 4, 5, 6, 7];
  const [y, x, c, k, row, taps, taps2, at] = [8, 9, 10, 11, 12, 13, 14, 15];  // i32
  const [SUM, TAP] = [16, 17];  // v128
  return func([I32, I32, I32, I32, I32, I32, I32, I32], [], [[8, I32], [2, V128]], (emit) => {
    const get = (l: number) => emit(op.get, l), set = (l: number) => emit(op.set, l);
    const i32 = (v: number) => emit(op.i32Const, signed(v));
    const loop = (counter: number, start: () => void, done: () => void, step: () => void, body: () => void) => {
      start(); set(counter);
      emit(op.block, op.void, op.loop, op.void);
      done(); emit(op.brIf, 1);
      body();
      step();
      emit(op.br, 0, op.end, op.end);
    };
    // the kernel's k-th value in both lanes
    const weight = () => { get(kernel); get(k); i32(3); emit(op.i32Shl, op.i32Add, simd(V.load64Splat), 3, 0); };
    // the byte address of src[y, tapIndex + c] where tapIndex is index[x', k] (taps: x' n, times 4)
    const tapAddress = (tapsOf: number) => {
      get(src); get(row); get(index); get(tapsOf); get(k); emit(op.i32Add); i32(2); emit(op.i32Shl, op.i32Add);
      emit(op.i32Load, 2, 0, op.i32Add); get(c); emit(op.i32Add); i32(2); emit(op.i32Shl, op.i32Add);
    };
    // SUM = sum_k weight * (the two values `load` pushes, promoted)
    const sumTaps = (load: () => void) => {
      emit(simd(V.const), Array(16).fill(0)); set(SUM);
      loop(k, () => i32(0), () => { get(k); get(n); emit(op.i32GeS); }, () => { get(k); i32(1); emit(op.i32Add); set(k); },
           () => { get(SUM); load(); emit(simd(V.f64x2Promote)); weight(); emit(simd(V.f64x2Mul), simd(V.f64x2Add)); set(SUM); });
    };
    // the byte address of out[y, x, c]
    const outAddress = () => {
      get(out); get(row); get(x); get(channels); emit(op.i32Mul, op.i32Add); get(c); emit(op.i32Add);
      i32(2); emit(op.i32Shl, op.i32Add); set(at);
    };
    loop(y, () => i32(0), () => { get(y); get(height); emit(op.i32GeS); }, () => { get(y); i32(1); emit(op.i32Add); set(y); }, () => {
      get(y); get(width); emit(op.i32Mul); get(channels); emit(op.i32Mul); set(row);  // element offset of the row
      get(channels); i32(1); emit(op.i32Eq, op.if, op.void);
      // one channel: two neighbouring pixels (each tap's value from its own index)
      i32(0); set(c);
      loop(x, () => i32(0), () => { get(x); i32(1); emit(op.i32Add); get(width); emit(op.i32GeS); },
           () => { get(x); i32(2); emit(op.i32Add); set(x); }, () => {
             get(x); get(n); emit(op.i32Mul); set(taps);
             get(taps); get(n); emit(op.i32Add); set(taps2);
             sumTaps(() => {
               tapAddress(taps); emit(simd(V.load32Zero), 2, 0); set(TAP);
               tapAddress(taps2); get(TAP); emit(simd(V.load32Lane), 2, 0, 1);
             });
             outAddress(); get(at); get(SUM); emit(simd(V.f32x4DemoteF64x2Zero), simd(V.store64Lane), 2, 0, 0);
           });
      get(x); get(width); emit(op.i32LtS, op.if, op.void);  // an odd width's last pixel: lane 0 alone
      get(x); get(n); emit(op.i32Mul); set(taps);
      sumTaps(() => { tapAddress(taps); emit(simd(V.load32Zero), 2, 0); });
      outAddress(); get(at); get(SUM); emit(simd(V.f32x4DemoteF64x2Zero), simd(V.f32x4Extract), 0, op.f32Store, 2, 0);
      emit(op.end);
      emit(op.else);
      // two or more channels: each pixel's channels two at a time (their taps side by side)
      loop(x, () => i32(0), () => { get(x); get(width); emit(op.i32GeS); }, () => { get(x); i32(1); emit(op.i32Add); set(x); }, () => {
        get(x); get(n); emit(op.i32Mul); set(taps);
        loop(c, () => i32(0), () => { get(c); i32(1); emit(op.i32Add); get(channels); emit(op.i32GeS); },
             () => { get(c); i32(2); emit(op.i32Add); set(c); }, () => {
               sumTaps(() => { tapAddress(taps); emit(simd(V.load64Zero), 2, 0); });
               outAddress(); get(at); get(SUM); emit(simd(V.f32x4DemoteF64x2Zero), simd(V.store64Lane), 2, 0, 0);
             });
        get(c); get(channels); emit(op.i32LtS, op.if, op.void);  // an odd channel count's last
        sumTaps(() => { tapAddress(taps); emit(simd(V.load32Zero), 2, 0); });
        outAddress(); get(at); get(SUM); emit(simd(V.f32x4DemoteF64x2Zero), simd(V.f32x4Extract), 0, op.f32Store, 2, 0);
        emit(op.end);
      });
      emit(op.end);
    });
  });
}

/** down(src, out, line, height, kernel, n, index): out[y, i] = sum_k kernel[k] src[index[y, k] + i] for each of the
 * `line` values of a row (index: int32 (height, n) element offsets of each tap's row; kernel: float64 (n,)). */
function downFunction(): Func {
  const [src, out, line, height, kernel, n, index] = [0, 1, 2, 3, 4, 5, 6];
  const [y, i, k, taps] = [7, 8, 9, 10];  // i32
  const [SUM] = [11];  // v128
  return func([I32, I32, I32, I32, I32, I32, I32], [], [[4, I32], [1, V128]], (emit) => {
    const get = (l: number) => emit(op.get, l), set = (l: number) => emit(op.set, l);
    const i32 = (v: number) => emit(op.i32Const, signed(v));
    const loop = (counter: number, done: () => void, by: number, body: () => void) => {
      i32(0); set(counter);
      emit(op.block, op.void, op.loop, op.void);
      done(); emit(op.brIf, 1);
      body();
      get(counter); i32(by); emit(op.i32Add); set(counter);
      emit(op.br, 0, op.end, op.end);
    };
    // SUM over the taps of values i, i + 1 (lanes), `wide`: both, else lane 0 alone
    const sumTaps = (wide: boolean) => {
      emit(simd(V.const), Array(16).fill(0)); set(SUM);
      loop(k, () => { get(k); get(n); emit(op.i32GeS); }, 1, () => {
        get(SUM);
        get(src); get(index); get(taps); get(k); emit(op.i32Add); i32(2); emit(op.i32Shl, op.i32Add);
        emit(op.i32Load, 2, 0); get(i); emit(op.i32Add); i32(2); emit(op.i32Shl, op.i32Add);
        emit(simd(wide ? V.load64Zero : V.load32Zero), 2, 0, simd(V.f64x2Promote));
        get(kernel); get(k); i32(3); emit(op.i32Shl, op.i32Add, simd(V.load64Splat), 3, 0);
        emit(simd(V.f64x2Mul), simd(V.f64x2Add)); set(SUM);
      });
    };
    loop(y, () => { get(y); get(height); emit(op.i32GeS); }, 1, () => {
      get(y); get(n); emit(op.i32Mul); set(taps);
      loop(i, () => { get(i); i32(1); emit(op.i32Add); get(line); emit(op.i32GeS); }, 2, () => {
        sumTaps(true);
        get(out); get(y); get(line); emit(op.i32Mul); get(i); emit(op.i32Add); i32(2); emit(op.i32Shl, op.i32Add);
        get(SUM); emit(simd(V.f32x4DemoteF64x2Zero), simd(V.store64Lane), 2, 0, 0);
      });
      get(i); get(line); emit(op.i32LtS, op.if, op.void);  // an odd line's last value
      sumTaps(false);
      get(out); get(y); get(line); emit(op.i32Mul); get(i); emit(op.i32Add); i32(2); emit(op.i32Shl, op.i32Add);
      get(SUM); emit(simd(V.f32x4DemoteF64x2Zero), simd(V.f32x4Extract), 0, op.f32Store, 2, 0);
      emit(op.end);
    });
  });
}

const kernels = sharedInstance(() => [["across", acrossFunction()], ["down", downFunction()]]);

const aligned = (bytes: number) => Math.ceil(bytes / 16) * 16;

/** gaussianBlurF32's two passes in WebAssembly: (h, w, channels) float32 `src` with the float32 `kernel` (n,) and the
 * reflect-101 tap indices `xIndex` (width, n; times channels) and `yIndex` (height, n; times the row's length) ->
 * the blurred float32 image, the JavaScript's values; null without WebAssembly SIMD. */
export function blurInWasm(src: Float32Array, width: number, height: number, channels: number, kernel: Float32Array,
                           xIndex: Int32Array, yIndex: Int32Array): Float32Array | null {
  const wasm = webAssemblyWanted() ? kernels() : null;
  if (wasm === null) return null;
  const n = kernel.length, values = src.length;
  const srcAt = 0, rowsAt = aligned(4 * values), outAt = rowsAt + aligned(4 * values);
  const kernelAt = outAt + aligned(4 * values), xAt = kernelAt + aligned(8 * n), yAt = xAt + aligned(4 * xIndex.length);
  reserveMemory(wasm.memory, yAt + aligned(4 * yIndex.length));
  const buffer = wasm.memory.buffer;
  new Float32Array(buffer, srcAt, values).set(src);
  new Float64Array(buffer, kernelAt, n).set(kernel);
  new Int32Array(buffer, xAt, xIndex.length).set(xIndex);
  new Int32Array(buffer, yAt, yIndex.length).set(yIndex);
  wasm.kernels.across(srcAt, rowsAt, width, height, channels, kernelAt, n, xAt);
  wasm.kernels.down(rowsAt, outAt, width * channels, height, kernelAt, n, yAt);
  return new Float32Array(buffer, outAt, values).slice();
}
