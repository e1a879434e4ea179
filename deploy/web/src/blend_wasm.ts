// The warp-guided generator's composite (models_def.composite.blend_with_reference_detail) on the page, in
// WebAssembly with 128-bit SIMD, four float32 pixels at a time: G^s's image and blend logits upsampled to the
// references' side, the per-pixel softmax over the references and the image, then the blend's low band plus the
// median of the references' masked detail (issue 65). The site's frame graph ends at G^s (`lsr export --web` ships
// the bundle's frame_network.onnx), so onnxruntime-web runs the network only: in its WASM build (one thread, Node)
// the shipped default's composite, some thirty passes over 256² planes, took 11.8 of the graph's 37.3 ms a frame;
// fused into these few passes it takes 5.0 ms. The same math in float32, summed in other orders and with its own exp
// (Cephes' expf): the face within about 1e-6 of the whole graph's (tests/deploy/test_web_blend.py). No JavaScript
// twin: the page's onnxruntime-web build needs WebAssembly SIMD as well.

import { Tensor, tensor } from "./tensor.js";
import { Emit, Func, I32, V, V128, compileModule, float32, func, op, reserveMemory, signed, simd, unsigned } from "./wasm.js";

/** Helpers over one function's emitter. */
function tools(emit: Emit) {
  const get = (l: number) => emit(op.get, l), set = (l: number) => emit(op.set, l);
  const i32 = (v: number) => emit(op.i32Const, signed(v));
  const f32 = (v: number) => emit(op.f32Const, float32(v));
  const v = (code: number) => emit(simd(code));
  const increment = (l: number, by: number | (() => void)) => {
    get(l);
    if (typeof by === "number") i32(by); else by();
    emit(op.i32Add); set(l);
  };
  /** for (counter = 0; counter < limit; counter += step) body(); limit: a local, or code leaving it on the stack */
  const loop = (counter: number, limit: number | (() => void), step: number, body: () => void) => {
    i32(0); set(counter);
    emit(op.block, op.void, op.loop, op.void);
    get(counter);
    if (typeof limit === "number") get(limit); else limit();
    emit(op.i32GeS, op.brIf, 1);
    body();
    increment(counter, step);
    emit(op.br, 0, op.end, op.end);
  };
  const load = (offset = 0) => emit(simd(V.load), 2, unsigned(offset));  // the address on the stack
  const store = (offset = 0) => emit(simd(V.store), 2, unsigned(offset));  // address, value on the stack
  const splat = (value: number) => { f32(value); v(V.f32x4Splat); };
  /** `product` (a v128 local) where `tap` is 0, else the v128 at out + xb plus it, on the stack: a blur's running sum */
  const tapSum = (tap: number, out: number, xb: number, product: number) => {
    get(tap); emit(op.if, V128); get(out); get(xb); emit(op.i32Add); load(); get(product); v(V.f32x4Add);
    emit(op.else); get(product); emit(op.end);
  };
  /** address = base + index * stride (locals), on the stack */
  const at = (base: number, index: number, stride: number) => {
    get(base); get(index); get(stride); emit(op.i32Mul, op.i32Add);
  };
  return { get, set, i32, f32, v, increment, loop, load, store, splat, at, tapSum };
}

/** hlerp(src, dst, rows, inCols, outCols, table): dst[r, x] = wa[x] src[r, ia[x]] + wb[x] src[r, ib[x]] for `rows`
 * rows, float32; table: per output column (ia, ib as int32 byte offsets into a row, wa, wb float32). */
function hlerpFunction(): Func {
  const [src, dst, rows, inCols, outCols, table] = [0, 1, 2, 3, 4, 5];
  const [r, x, row, out, entry] = [6, 7, 8, 9, 10];
  return func([I32, I32, I32, I32, I32, I32], [], [[5, I32]], (emit) => {
    const t = tools(emit);
    t.get(src); t.set(row); t.get(dst); t.set(out);
    t.loop(r, rows, 1, () => {
      t.get(table); t.set(entry);
      t.loop(x, outCols, 1, () => {
        t.get(out);
        // wa src[ia] + wb src[ib]: the entry's weights at bytes 8 and 12, its offsets at 0 and 4
        t.get(entry); emit(op.f32Load, 2, 8); t.get(row); t.get(entry);
        emit(op.i32Load, 2, 0, op.i32Add, op.f32Load, 2, 0, op.f32Mul);
        t.get(entry); emit(op.f32Load, 2, 12); t.get(row); t.get(entry);
        emit(op.i32Load, 2, 4, op.i32Add, op.f32Load, 2, 0, op.f32Mul);
        emit(op.f32Add, op.f32Store, 2, 0);
        t.increment(out, 4); t.increment(entry, 16);
      });
      t.increment(row, () => { t.get(inCols); t.i32(2); emit(op.i32Shl); });
    });
  });
}

/** vlerp(src, dst, planes, inRows, outRows, cols, table): per plane, dst[y] = wa[y] src[ra[y]] + wb[y] src[rb[y]],
 * rows of `cols` float32 (a multiple of 4), four at a time; table: per output row (ra, rb as int32 byte offsets
 * into a plane, wa, wb float32). */
function vlerpFunction(): Func {
  const [src, dst, planes, inRows, outRows, cols, table] = [0, 1, 2, 3, 4, 5, 6];
  const [p, y, xb, rowBytes, plane, out, entry, a, b] = [7, 8, 9, 10, 11, 12, 13, 14, 15];
  const [WA, WB] = [16, 17];
  return func([I32, I32, I32, I32, I32, I32, I32], [], [[9, I32], [2, V128]], (emit) => {
    const t = tools(emit);
    t.get(cols); t.i32(2); emit(op.i32Shl); t.set(rowBytes);
    t.get(src); t.set(plane); t.get(dst); t.set(out);
    t.loop(p, planes, 1, () => {
      t.get(table); t.set(entry);
      t.loop(y, outRows, 1, () => {
        t.get(plane); t.get(entry); emit(op.i32Load, 2, 0, op.i32Add); t.set(a);
        t.get(plane); t.get(entry); emit(op.i32Load, 2, 4, op.i32Add); t.set(b);
        t.get(entry); emit(simd(V.load32Splat), 2, 8); t.set(WA);
        t.get(entry); emit(simd(V.load32Splat), 2, 12); t.set(WB);
        t.loop(xb, rowBytes, 16, () => {
          t.get(out); t.get(xb); emit(op.i32Add);
          t.get(WA); t.get(a); t.get(xb); emit(op.i32Add); t.load(); t.v(V.f32x4Mul);
          t.get(WB); t.get(b); t.get(xb); emit(op.i32Add); t.load(); t.v(V.f32x4Mul);
          t.v(V.f32x4Add); t.store();
        });
        t.increment(out, () => t.get(rowBytes)); t.increment(entry, 16);
      });
      t.increment(plane, () => { t.get(inRows); t.get(rowBytes); emit(op.i32Mul); });
    });
  });
}

/** pool2(src, dst, rows, cols): the 2 x 2 mean of `rows` (even, all planes' rows together) rows of `cols` float32
 * (a multiple of 8): ((a + b) + c) + d over the square's row-major order, times 1/4. */
function poolFunction(): Func {
  const [src, dst, rows, cols] = [0, 1, 2, 3];
  const [i, xb, rowBytes, top, out] = [4, 5, 6, 7, 8];
  const [A, B] = [9, 10];
  const EVEN = [0, 1, 2, 3, 8, 9, 10, 11, 16, 17, 18, 19, 24, 25, 26, 27];
  const ODD = EVEN.map((lane) => lane + 4);
  return func([I32, I32, I32, I32], [], [[5, I32], [2, V128]], (emit) => {
    const t = tools(emit);
    t.get(cols); t.i32(2); emit(op.i32Shl); t.set(rowBytes);
    t.get(src); t.set(top); t.get(dst); t.set(out);
    t.loop(i, () => { t.get(rows); t.i32(1); emit(op.i32ShrU); }, 1, () => {  // rows / 2
      t.loop(xb, rowBytes, 32, () => {
        t.get(top); t.get(xb); emit(op.i32Add); t.load(); t.set(A);
        t.get(top); t.get(xb); emit(op.i32Add); t.load(16); t.set(B);
        t.get(out);
        t.get(A); t.get(B); emit(simd(V.shuffle), EVEN); t.get(A); t.get(B); emit(simd(V.shuffle), ODD); t.v(V.f32x4Add);
        t.get(top); t.get(rowBytes); t.get(xb); emit(op.i32Add, op.i32Add); t.load(); t.set(A);
        t.get(top); t.get(rowBytes); t.get(xb); emit(op.i32Add, op.i32Add); t.load(16); t.set(B);
        t.get(A); t.get(B); emit(simd(V.shuffle), EVEN); t.v(V.f32x4Add);
        t.get(A); t.get(B); emit(simd(V.shuffle), ODD); t.v(V.f32x4Add);
        t.splat(0.25); t.v(V.f32x4Mul); t.store();
        t.increment(out, 16);
      });
      t.increment(top, () => { t.get(rowBytes); t.i32(1); emit(op.i32Shl); });
    });
  });
}

/** unpack(src, count, pixels, dst): `count` pictures of `pixels` (a multiple of 4) uint8 RGB pixels each -> their
 * (count, 3, pixels) float32 planes in [-1, 1], each value v / 127.5 - 1 in float32 (network.ts toNetwork's,
 * lsr.core.images.to_network's), four pixels at a time (a load may read up to 4 bytes past the last picture). */
function unpackFunction(): Func {
  const [src, count, pixels, dst] = [0, 1, 2, 3];
  const [picture, k, from, into, planeBytes] = [4, 5, 6, 7, 8];
  const [BYTES] = [9];
  const ZERO = 16;  // a lane of the all-zero second operand
  return func([I32, I32, I32, I32], [], [[5, I32], [1, V128]], (emit) => {
    const t = tools(emit);
    t.get(pixels); t.i32(2); emit(op.i32Shl); t.set(planeBytes);
    t.get(src); t.set(from); t.get(dst); t.set(into);
    t.loop(picture, count, 1, () => {
      t.loop(k, pixels, 4, () => {
        t.get(from); t.load(); t.set(BYTES);
        [0, 1, 2].forEach((channel) => {  // the channel's four bytes widened to int32 lanes, then to [-1, 1]
          t.get(into);
          if (channel > 0) { t.get(planeBytes); if (channel > 1) { t.i32(2); emit(op.i32Mul); } emit(op.i32Add); }
          t.get(BYTES); emit(simd(V.const), Array(16).fill(0));
          emit(simd(V.shuffle), [0, 1, 2, 3].flatMap((p) => [3 * p + channel, ZERO, ZERO, ZERO]));
          t.v(V.f32x4ConvertI32x4S); t.splat(127.5); t.v(V.f32x4Div); t.splat(1); t.v(V.f32x4Sub);
          t.store();
        });
        t.increment(from, 12);
        t.increment(into, 16);
      });
      t.increment(into, () => { t.get(planeBytes); t.i32(2); emit(op.i32Mul); });  // past the G and B planes
    });
  });
}

/** hblur(src, dst, rows, cols, radius, weights, pad): each of `rows` rows of `cols` float32 (a multiple of 4)
 * convolved with the 2 radius + 1 `weights` (float32), its edges reflected without repeating the edge pixel (torch's
 * "reflect" padding): the row is copied padded into `pad`, then summed tap by tap, four outputs at a time. */
function hblurFunction(): Func {
  const [src, dst, rows, cols, radius, weights, pad] = [0, 1, 2, 3, 4, 5, 6];
  const [r, j, xb, tap, taps, rowBytes, row, out, last] = [7, 8, 9, 10, 11, 12, 13, 14, 15];
  const [W, PRODUCT] = [16, 17];
  return func([I32, I32, I32, I32, I32, I32, I32], [], [[9, I32], [2, V128]], (emit) => {
    const t = tools(emit);
    t.get(radius); t.i32(1); emit(op.i32Shl); t.i32(1); emit(op.i32Add); t.set(taps);
    t.get(cols); t.i32(2); emit(op.i32Shl); t.set(rowBytes);
    t.get(cols); t.i32(1); emit(op.i32Sub); t.set(last);
    t.get(src); t.set(row); t.get(dst); t.set(out);
    t.loop(r, rows, 1, () => {
      // pad[j] = row[reflect(j - radius)], j < cols + 2 radius: the row four at a time, then its reflected edges
      t.loop(j, rowBytes, 16, () => {
        t.get(pad); t.get(radius); t.i32(2); emit(op.i32Shl, op.i32Add); t.get(j); emit(op.i32Add);
        t.get(row); t.get(j); emit(op.i32Add); t.load(); t.store();
      });
      t.loop(j, radius, 1, () => {
        // pad[radius - 1 - j] = row[j + 1]; pad[cols + radius + j] = row[cols - 2 - j]
        t.get(pad); t.get(radius); t.i32(1); emit(op.i32Sub); t.get(j); emit(op.i32Sub); t.i32(2); emit(op.i32Shl, op.i32Add);
        t.get(row); t.get(j); t.i32(1); emit(op.i32Add); t.i32(2); emit(op.i32Shl, op.i32Add, op.f32Load, 2, 0, op.f32Store, 2, 0);
        t.get(pad); t.get(cols); t.get(radius); t.get(j); emit(op.i32Add, op.i32Add); t.i32(2); emit(op.i32Shl, op.i32Add);
        t.get(row); t.get(last); t.i32(1); emit(op.i32Sub); t.get(j); emit(op.i32Sub); t.i32(2); emit(op.i32Shl, op.i32Add);
        emit(op.f32Load, 2, 0, op.f32Store, 2, 0);
      });
      t.loop(tap, taps, 1, () => {
        t.get(weights); t.get(tap); t.i32(2); emit(op.i32Shl, op.i32Add); emit(simd(V.load32Splat), 2, 0); t.set(W);
        t.loop(xb, rowBytes, 16, () => {
          t.get(out); t.get(xb); emit(op.i32Add);
          t.get(W); t.get(pad); t.get(tap); t.i32(2); emit(op.i32Shl, op.i32Add); t.get(xb); emit(op.i32Add); t.load();
          t.v(V.f32x4Mul); t.set(PRODUCT);
          t.tapSum(tap, out, xb, PRODUCT);
          t.store();
        });
      });
      t.increment(row, () => t.get(rowBytes)); t.increment(out, () => t.get(rowBytes));
    });
  });
}

/** vblur(src, dst, planes, rows, cols, radius, weights): hblur down the columns of each plane, four columns at a
 * time (rows reflected as hblur's columns). */
function vblurFunction(): Func {
  const [src, dst, planes, rows, cols, radius, weights] = [0, 1, 2, 3, 4, 5, 6];
  const [p, y, k, xb, tap, taps, rowBytes, plane, out, last, from] = [7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17];
  const [W, PRODUCT] = [18, 19];
  return func([I32, I32, I32, I32, I32, I32, I32], [], [[11, I32], [2, V128]], (emit) => {
    const t = tools(emit);
    t.get(radius); t.i32(1); emit(op.i32Shl); t.i32(1); emit(op.i32Add); t.set(taps);
    t.get(cols); t.i32(2); emit(op.i32Shl); t.set(rowBytes);
    t.get(rows); t.i32(1); emit(op.i32Sub); t.set(last);
    t.get(src); t.set(plane); t.get(dst); t.set(out);
    t.loop(p, planes, 1, () => {
      t.loop(y, rows, 1, () => {
        t.loop(tap, taps, 1, () => {
          t.get(y); t.get(tap); emit(op.i32Add); t.get(radius); emit(op.i32Sub); t.set(k);
          t.get(k); t.i32(0); emit(op.i32LtS, op.if, op.void); t.i32(0); t.get(k); emit(op.i32Sub); t.set(k); emit(op.end);
          t.get(k); t.get(last); emit(op.i32GtS, op.if, op.void);
          t.get(last); t.i32(1); emit(op.i32Shl); t.get(k); emit(op.i32Sub); t.set(k);
          emit(op.end);
          t.at(plane, k, rowBytes); t.set(from);
          t.get(weights); t.get(tap); t.i32(2); emit(op.i32Shl, op.i32Add); emit(simd(V.load32Splat), 2, 0); t.set(W);
          t.loop(xb, rowBytes, 16, () => {
            t.get(out); t.get(xb); emit(op.i32Add);
            t.get(W); t.get(from); t.get(xb); emit(op.i32Add); t.load(); t.v(V.f32x4Mul); t.set(PRODUCT);
            t.tapSum(tap, out, xb, PRODUCT);
            t.store();
          });
        });
        t.increment(out, () => t.get(rowBytes));
      });
      t.increment(plane, () => { t.get(rows); t.get(rowBytes); emit(op.i32Mul); });
    });
  });
}

// Cephes' expf: x = n ln 2 + r, |r| <= ln(2) / 2, e^r by its polynomial, 2^n in the exponent bits
const EXP_LOWEST = -87.33654;  // e^x at the smallest normal float32: n >= -126
const LOG2E = 1.44269504088896341, LN2_HI = 0.693359375, LN2_LO = -2.12194440e-4;
const EXP_POLYNOMIAL = [1.9875691500e-4, 1.3981999507e-3, 8.3334519073e-3, 4.1665795894e-2, 1.6666665459e-1,
                        5.0000001201e-1];

/** blend(up, refs, masks, image, share, pixels) for `count` references: per pixel of the references' side, with
 * up = G^s's image (3 planes) then its blend logits (count + 1 planes: the references' already lowered by the
 * penalty, the image's last), all upsampled: the softmax over [logit_k + penalty mask_k ..., the image's logit],
 * image = the weighted sum of the references (count x 3 planes) and G^s's image, share = the references' total
 * weight (1 - the image's). */
function blendFunction(count: number, penalty: number): Func {
  const [up, refs, masks, image, share, pixels] = [0, 1, 2, 3, 4, 5];
  const [pb, planeBytes, imageLogit] = [6, 7, 8];
  // i32 locals from 9: per reference its logit's, mask's and three channels' plane addresses
  const logitAt = (k: number) => 9 + 5 * k, maskAt = (k: number) => 10 + 5 * k;
  const channelAt = (k: number, c: number) => 11 + 5 * k + c;
  const integers = 3 + 5 * count;
  const vectors = 6 + integers;
  const [TOP, G, E, TOTAL, X, N, R, GR, B] = [0, 1, 2, 3, 4, 5, 6, 7, 8].map((i) => vectors + i);
  const L = (k: number) => vectors + 9 + k;  // the penalised logits
  return func([I32, I32, I32, I32, I32, I32], [], [[integers, I32], [9 + count, V128]], (emit) => {
    const t = tools(emit);
    const [add, sub, mul] = [V.f32x4Add, V.f32x4Sub, V.f32x4Mul];
    // e^X (X <= 0) on the stack
    const exp = () => {
      t.get(X); t.splat(EXP_LOWEST); t.v(V.f32x4Max); t.set(X);
      t.get(X); t.splat(LOG2E); t.v(mul); t.v(V.f32x4Nearest); t.set(N);
      t.get(X); t.get(N); t.splat(LN2_HI); t.v(mul); t.v(sub); t.get(N); t.splat(LN2_LO); t.v(mul); t.v(sub); t.set(X);
      t.splat(EXP_POLYNOMIAL[0]);
      for (const c of EXP_POLYNOMIAL.slice(1)) { t.get(X); t.v(mul); t.splat(c); t.v(add); }
      t.get(X); t.get(X); t.v(mul); t.v(mul); t.get(X); t.v(add); t.splat(1); t.v(add);
      t.get(N); t.v(V.i32x4TruncSatF32x4S); t.i32(127); t.v(V.i32x4Splat); t.v(V.i32x4Add); t.i32(23); t.v(V.i32x4Shl);
      t.v(mul);
    };
    const plane = (base: number, index: number) => { t.get(base); t.get(planeBytes); t.i32(index); emit(op.i32Mul, op.i32Add); };
    const here = (address: number) => { t.get(address); t.get(pb); emit(op.i32Add); t.load(); };
    t.get(pixels); t.i32(2); emit(op.i32Shl); t.set(planeBytes);
    plane(up, 3 + count); t.set(imageLogit);
    for (let k = 0; k < count; k++) {
      plane(up, 3 + k); t.set(logitAt(k));
      plane(masks, k); t.set(maskAt(k));
      for (let c = 0; c < 3; c++) { plane(refs, 3 * k + c); t.set(channelAt(k, c)); }
    }
    t.loop(pb, planeBytes, 16, () => {
      // the image's logit, the references' penalised ones, the largest
      here(imageLogit); t.set(G);
      t.get(G); t.set(TOP);
      for (let k = 0; k < count; k++) {
        here(logitAt(k)); here(maskAt(k)); t.splat(penalty); t.v(mul); t.v(add); t.set(L(k));
        t.get(TOP); t.get(L(k)); t.v(V.f32x4Max); t.set(TOP);
      }
      // e^(image logit - top) times G^s's image, then each reference's
      t.get(G); t.get(TOP); t.v(sub); t.set(X); exp(); t.set(G);
      t.get(G); t.get(up); t.get(pb); emit(op.i32Add); t.load(); t.v(mul); t.set(R);
      t.get(G); plane(up, 1); t.get(pb); emit(op.i32Add); t.load(); t.v(mul); t.set(GR);
      t.get(G); plane(up, 2); t.get(pb); emit(op.i32Add); t.load(); t.v(mul); t.set(B);
      for (let k = 0; k < count; k++) {
        t.get(L(k)); t.get(TOP); t.v(sub); t.set(X); exp(); t.set(E);
        if (k === 0) { t.get(E); t.set(TOTAL); } else { t.get(TOTAL); t.get(E); t.v(add); t.set(TOTAL); }
        [R, GR, B].forEach((sum, c) => { t.get(sum); t.get(E); here(channelAt(k, c)); t.v(mul); t.v(add); t.set(sum); });
      }
      // normalised: 1 / (total + e^image)
      t.splat(1); t.get(TOTAL); t.get(G); t.v(add); t.v(V.f32x4Div); t.set(E);
      [R, GR, B].forEach((sum, c) => {
        plane(image, c); t.get(pb); emit(op.i32Add); t.get(sum); t.get(E); t.v(mul); t.store();
      });
      t.get(share); t.get(pb); emit(op.i32Add); t.get(TOTAL); t.get(E); t.v(mul); t.store();
    });
  });
}

/** detail(refs, lows, masks, low, share, out, pixels) for `count` (1, 3 or 5) references: per channel and pixel,
 * out = clamp(low + share * median_k((ref_k - low_k) mask_k), -1, 1) (models_def.composite.median_of's networks). */
function detailFunction(count: 1 | 3 | 5): Func {
  const [refs, lows, masks, low, share, out, pixels] = [0, 1, 2, 3, 4, 5, 6];
  const [c, pb, planeBytes, lowAt, outAt] = [7, 8, 9, 10, 11];
  // i32 locals from 12: per reference its channel's plane in refs and in lows, and its mask's
  const refAt = (k: number) => 12 + 3 * k, lowsAt = (k: number) => 13 + 3 * k, maskAt = (k: number) => 14 + 3 * k;
  const integers = 5 + 3 * count;
  const D = Array.from({ length: 5 }, (_, k) => 7 + integers + k);
  const [P, Q] = [7 + integers + 5, 7 + integers + 6];
  return func([I32, I32, I32, I32, I32, I32, I32], [], [[integers, I32], [7, V128]], (emit) => {
    const t = tools(emit);
    const [min, max] = [() => t.v(V.f32x4Min), () => t.v(V.f32x4Max)];
    const here = (address: number) => { t.get(address); t.get(pb); emit(op.i32Add); t.load(); };
    // the median of three values left by code on the stack: max(min(x, y), min(max(x, y), z))
    const median3 = (x: () => void, y: () => void, z: () => void) => {
      x(); t.set(P); y(); t.set(Q);
      t.get(P); t.get(Q); min(); t.get(P); t.get(Q); max(); z(); min(); max();
    };
    t.get(pixels); t.i32(2); emit(op.i32Shl); t.set(planeBytes);
    for (let k = 0; k < count; k++) { t.get(masks); t.get(planeBytes); t.i32(k); emit(op.i32Mul, op.i32Add); t.set(maskAt(k)); }
    t.loop(c, () => t.i32(3), 1, () => {
      for (let k = 0; k < count; k++) {  // plane 3 k + c of the references and of their low bands
        [[refs, refAt(k)], [lows, lowsAt(k)]].forEach(([base, into]) => {
          t.get(base); t.get(c); t.i32(3 * k); emit(op.i32Add); t.get(planeBytes); emit(op.i32Mul, op.i32Add); t.set(into);
        });
      }
      t.get(low); t.get(c); t.get(planeBytes); emit(op.i32Mul, op.i32Add); t.set(lowAt);
      t.get(out); t.get(c); t.get(planeBytes); emit(op.i32Mul, op.i32Add); t.set(outAt);
      t.loop(pb, planeBytes, 16, () => {
        for (let k = 0; k < count; k++) {
          here(refAt(k)); here(lowsAt(k)); t.v(V.f32x4Sub); here(maskAt(k)); t.v(V.f32x4Mul); t.set(D[k]);
        }
        const d = (k: number) => () => t.get(D[k]);
        t.get(outAt); t.get(pb); emit(op.i32Add);
        here(lowAt); t.get(share); t.get(pb); emit(op.i32Add); t.load();
        if (count === 1) t.get(D[0]);
        else if (count === 3) median3(d(0), d(1), d(2));
        else {
          // median3(e, max(min(a, b), min(c, d)), min(max(a, b), max(c, d)))
          const highOfLow = () => { t.get(D[0]); t.get(D[1]); min(); t.get(D[2]); t.get(D[3]); min(); max(); };
          const lowOfHigh = () => { t.get(D[0]); t.get(D[1]); max(); t.get(D[2]); t.get(D[3]); max(); min(); };
          median3(d(4), highOfLow, lowOfHigh);
        }
        t.v(V.f32x4Mul); t.v(V.f32x4Add);
        t.splat(-1); max(); t.splat(1); min();
        t.store();
      });
    });
  });
}

// ---- the composite -----------------------------------------------------------------------------------------

/** models_def.composite.INVALID_LOGIT_PENALTY */
const INVALID_LOGIT_PENALTY = 30.0;
/** models_def.composite.HALF_RESOLUTION_MIN_SIGMA */
const HALF_RESOLUTION_MIN_SIGMA = 2.0;

let compiled: WebAssembly.Module | null | undefined;

function module(): WebAssembly.Module | null {
  if (compiled === undefined) {
    compiled = compileModule([["hlerp", hlerpFunction()], ["vlerp", vlerpFunction()], ["pool2", poolFunction()],
                              ["unpack", unpackFunction()],
                              ["hblur", hblurFunction()], ["vblur", vblurFunction()],
                              ...([1, 3, 5] as const).flatMap((n) => [[`blend${n}`, blendFunction(n, INVALID_LOGIT_PENALTY)],
                                                                     [`detail${n}`, detailFunction(n)]] as [string, Func][])]);
  }
  return compiled;
}

/** torch's bilinear resize (align_corners=False) of `size` samples to `out`: per output (lower, upper, weights). */
function bilinearTaps(size: number, out: number): [number, number, number, number][] {
  const scale = size / out;
  return Array.from({ length: out }, (_, d) => {
    const source = Math.max(0, (d + 0.5) * scale - 0.5), lower = Math.floor(source);
    const upper = lower + (lower < size - 1 ? 1 : 0), lambda = Math.fround(source - lower);
    return [lower, upper, Math.fround(1 - lambda), lambda];
  });
}

/** models_def.composite.gaussian_blur's kernel of `sigma` pixels on a side of `side` (its float32 taps). */
function gaussianTaps(sigma: number, side: number): Float32Array {
  const radius = Math.min(Math.max(1, Math.ceil(3 * sigma)), side - 1);
  const taps = Float32Array.from({ length: 2 * radius + 1 }, (_, i) => Math.exp(-0.5 * ((i - radius) / sigma) ** 2));
  const total = taps.reduce((sum, tap) => sum + tap, 0);
  return taps.map((tap) => tap / total);
}

/** Whether a warp-guided model's composite runs here (lsr.export.graphs.page_composite_sigma says the same): 1, 3
 * or 5 references (median_of's networks), references a power of two (2, 4, ...) times the network's side, that side
 * a multiple of 4, the detail split at half resolution (or 0: no detail), WebAssembly SIMD present. It has no
 * JavaScript twin (wasm.ts useWebAssembly does not turn it off): onnxruntime-web's build needs WebAssembly SIMD too. */
export function composesInWasm(references: number, crop: number, resolution: number, sigma: number): boolean {
  const factor = crop / resolution;
  return module() !== null && [1, 3, 5].includes(references) && resolution % 4 === 0 && Number.isInteger(factor)
    && factor >= 2 && (factor & (factor - 1)) === 0 && (sigma === 0 || sigma >= HALF_RESOLUTION_MIN_SIGMA);
}

/** The composite of one site's frame generator: `references` N warped shots at `crop`² and G^s's outputs at
 * `resolution`², the detail split at `sigma` pixels of the crop (0: none). Its memory is reused frame to frame. */
export class PageComposite {
  private readonly exports: Record<string, (...args: number[]) => number>;
  private readonly memory: WebAssembly.Memory;
  private readonly at: Record<string, number> = {};
  private readonly blurRadius: number;

  private constructor(instance: WebAssembly.Instance, readonly references: number, readonly crop: number,
                      readonly resolution: number, readonly sigma: number) {
    this.exports = instance.exports as unknown as Record<string, (...args: number[]) => number>;
    this.memory = instance.exports.memory as WebAssembly.Memory;
    const n = references, big = crop * crop, small = resolution * resolution, half = crop / 2, quarter = half * half;
    const taps = sigma > 0 ? gaussianTaps(Math.sqrt(sigma ** 2 - 0.25 - 0.125) / 2, half) : new Float32Array(1);
    this.blurRadius = (taps.length - 1) / 2;
    let end = 0;
    const take = (name: string, floats: number) => { this.at[name] = end; end += Math.ceil(floats / 4) * 16; };
    take("refs", 3 * n * big); take("bytes", (3 * n * big + 16) / 4); take("masks", n * big); take("network", (n + 4) * small); take("up", (n + 4) * big);
    take("rows", Math.max((n + 4) * resolution * crop, 3 * n * half * crop, 3 * n * quarter));
    take("half", 3 * n * quarter); take("small", 4 * n * small); take("blurred", 3 * n * quarter);
    take("lows", 3 * n * big);
    take("image", 3 * big); take("share", big); take("low", 3 * big); take("out", 3 * big);
    take("pad", half + 2 * this.blurRadius + 4); take("taps", taps.length);
    take("upCols", 4 * crop); take("upRows", 4 * crop); take("halfCols", 4 * crop); take("halfRows", 4 * crop);
    reserveMemory(this.memory, end);
    const buffer = this.memory.buffer;
    new Float32Array(buffer, this.at.taps, taps.length).set(taps);
    // the tables of the bilinear upsamplings: G^s's side to the crop's, half the crop's to it
    const table = (name: string, size: number, stride: number) => {
      const ints = new Int32Array(buffer, this.at[name], 4 * crop), floats = new Float32Array(buffer, this.at[name], 4 * crop);
      bilinearTaps(size, crop).forEach(([lower, upper, a, b], d) => {
        ints[4 * d] = lower * stride * 4; ints[4 * d + 1] = upper * stride * 4; floats[4 * d + 2] = a; floats[4 * d + 3] = b;
      });
    };
    table("upCols", resolution, 1); table("upRows", resolution, crop);
    table("halfCols", half, 1); table("halfRows", half, crop);
  }

  /** null where the composite cannot run here (composesInWasm). */
  static create(references: number, crop: number, resolution: number, sigma: number): PageComposite | null {
    if (!composesInWasm(references, crop, resolution, sigma)) return null;
    try {
      return new PageComposite(new WebAssembly.Instance(module()!, {}), references, crop, resolution, sigma);
    } catch {
      return null;
    }
  }

  /** The N warped references (N, C, C, 3) uint8 and their masks (N, C, C) in: the references as `inputs()` holds
   * them, each value network.ts toNetwork's float32 (unpacked in the module, four pixels at a time). */
  loadReferences(references: Uint8Array, masks: ArrayLike<number>): void {
    const n = this.references, big = this.crop * this.crop;
    if (references.length !== 3 * n * big || masks.length !== n * big) {
      throw new Error(`the references must be (${n}, ${this.crop}, ${this.crop}, 3) and their masks (${n}, ${this.crop}, ${this.crop})`);
    }
    new Uint8Array(this.memory.buffer, this.at.bytes, references.length).set(references);
    this.exports.unpack(this.at.bytes, n, big, this.at.refs);
    new Float32Array(this.memory.buffer, this.at.masks, n * big).set(masks);
  }

  /** Where the N references (N, 3, C, C) float32 in [-1, 1] and their masks (N, C, C) go before `compose`. */
  inputs(): { references: Float32Array; masks: Float32Array } {
    const n = this.references, big = this.crop * this.crop, buffer = this.memory.buffer;
    return { references: new Float32Array(buffer, this.at.refs, 3 * n * big),
             masks: new Float32Array(buffer, this.at.masks, n * big) };
  }

  /** The network's references and masks, the ones in `inputs()` pooled to its side as the whole graph pools them
   * (2 x 2 means, halving the side until it is the network's): (N, 3, S, S) and (N, S, S) float32, new arrays. */
  pooled(): { references: Float32Array; masks: Float32Array } {
    const n = this.references, s = this.resolution, a = this.at, e = this.exports, buffer = this.memory.buffer;
    const pool = (from: number, planes: number) => {
      let side = this.crop, source = from, turn = 0;
      for (; side / 2 > s; side /= 2, turn++) {  // through the two scratch buffers in turn
        const into = turn % 2 === 0 ? a.half : a.blurred;
        e.pool2(source, into, planes * side, side);
        source = into;
      }
      e.pool2(source, a.small, planes * side, side);
      return new Float32Array(buffer, a.small, planes * s * s).slice();
    };
    return { references: pool(a.refs, 3 * n), masks: pool(a.masks, n) };
  }

  /** The face (3, C, C) float32 in [-1, 1] of G^s's `network` outputs (N + 4, S, S: its image, then the N + 1 blend
   * logits, the image's last) over the references in `inputs()`: a view of this composite's memory, valid until
   * the next call. */
  compose(network: Float32Array): Float32Array {
    const n = this.references, s = this.resolution, c = this.crop, half = c / 2, big = c * c, a = this.at;
    const e = this.exports, buffer = this.memory.buffer;
    if (network.length !== (n + 4) * s * s) throw new Error(`the network's outputs must be (${n + 4}, ${s}, ${s})`);
    const copy = new Float32Array(buffer, a.network, network.length);
    copy.set(network);
    for (let i = 3 * s * s; i < (3 + n) * s * s; i++) copy[i] -= INVALID_LOGIT_PENALTY;  // as the graph, before upsampling
    // G^s's image and logits upsampled to the crop: along the rows, then down the columns
    e.hlerp(a.network, a.rows, (n + 4) * s, s, c, a.upCols);
    e.vlerp(a.rows, a.up, n + 4, s, c, c, a.upRows);
    e[`blend${n}`](a.up, a.refs, a.masks, a.image, a.share, big);
    if (this.sigma <= 0) return new Float32Array(buffer, a.image, 3 * big);
    // the low bands: the references' and the blend's, each a 2 x 2 mean, blurred, upsampled
    const lowBand = (from: number, planes: number, into: number) => {
      e.pool2(from, a.half, planes * c, c);
      e.hblur(a.half, a.blurred, planes * half, half, this.blurRadius, a.taps, a.pad);
      e.vblur(a.blurred, a.half, planes, half, half, this.blurRadius, a.taps);
      e.hlerp(a.half, a.rows, planes * half, half, c, a.halfCols);
      e.vlerp(a.rows, into, planes, half, c, c, a.halfRows);
    };
    lowBand(a.refs, 3 * n, a.lows);
    lowBand(a.image, 3, a.low);
    e[`detail${n}`](a.refs, a.lows, a.masks, a.low, a.share, a.out, big);
    return new Float32Array(buffer, a.out, 3 * big);
  }
}


/** Node, for the tests: the page's composite of `network` (N + 4, S, S) float32 over `references` (N, 3, C, C) float32
 * in [-1, 1] and `masks` (N, C, C) -> the face (3, C, C) float32 (null where it cannot run here). */
export function composeReferences(references: Tensor, masks: Tensor, network: Tensor, sigma: number): Tensor<Float32Array> | null {
  const [n, , c] = references.shape, s = network.shape[1];
  const composite = PageComposite.create(n, c, s, sigma);
  if (composite === null) return null;
  const inputs = composite.inputs();
  inputs.references.set(references.data);
  inputs.masks.set(masks.data);
  return tensor(composite.compose(Float32Array.from(network.data)).slice(), [3, c, c]);
}

/** Node, for the tests: warped references (N, C, C, 3) uint8 as the page's composite takes them in (loadReferences)
 * -> (N, 3, C, C) float32 (null where the composite cannot run here; `resolution` and `sigma` as a site's). */
export function loadedReferences(references: Tensor<Uint8Array>, resolution: number, sigma: number): Tensor<Float32Array> | null {
  const [n, c] = references.shape;
  const composite = PageComposite.create(n, c, resolution, sigma);
  if (composite === null) return null;
  composite.loadReferences(references.data, new Float32Array(n * c * c).fill(1));
  return tensor(composite.inputs().references.slice(), [n, 3, c, c]);
}
