// A small WebAssembly writer for the per-frame kernels written here opcode by opcode, without a toolchain
// (remap_wasm.ts: the warps' and the head layer's bicubic remaps; tps_wasm.ts: the splines on their grids;
// blend_wasm.ts: the page's composite; blur_wasm.ts: the Gaussian blurs). Each kernel does the same operations, in
// float32 or float64, in the same order as the JavaScript it stands in for, so that the bytes out are the same;
// 128-bit SIMD (in every browser since 2021, and Node 16) carries four float32 or two float64 lanes at once. Where
// WebAssembly or its SIMD is missing, `compileModule` gives null and the callers keep to their JavaScript.

export function unsigned(value: number): number[] {
  const out: number[] = [];
  do {
    let byte = value & 0x7f;
    value >>>= 7;
    if (value !== 0) byte |= 0x80;
    out.push(byte);
  } while (value !== 0);
  return out;
}

export function signed(value: number): number[] {
  const out: number[] = [];
  for (;;) {
    const byte = value & 0x7f;
    value >>= 7;
    if ((value === 0 && (byte & 0x40) === 0) || (value === -1 && (byte & 0x40) !== 0)) { out.push(byte); return out; }
    out.push(byte | 0x80);
  }
}

export function float32(value: number): number[] {
  return Array.from(new Uint8Array(new Float32Array([value]).buffer));
}

export function float64(value: number): number[] {
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

export const I32 = 0x7f, F32 = 0x7d, F64 = 0x7c, V128 = 0x7b;
export const op = {
  block: 0x02, loop: 0x03, if: 0x04, else: 0x05, br: 0x0c, brIf: 0x0d, end: 0x0b, void: 0x40, call: 0x10,
  get: 0x20, set: 0x21, tee: 0x22,
  i32Load: 0x28, f32Load: 0x2a, f64Load: 0x2b, i32Load8U: 0x2d, i32Store: 0x36, f32Store: 0x38, f64Store: 0x39,
  i32Const: 0x41, f32Const: 0x43, f64Const: 0x44,
  i32Eqz: 0x45, i32Eq: 0x46, i32Ne: 0x47, i32GtS: 0x4a, i32GeS: 0x4e, f32Lt: 0x5d, f32Ge: 0x60, f64Lt: 0x63, f64Gt: 0x64,
  f64Ge: 0x66,
  i32Add: 0x6a, i32Sub: 0x6b, i32Mul: 0x6c, i32And: 0x71, i32Shl: 0x74, i32ShrU: 0x76, i32LtS: 0x48,
  select: 0x1b, f32Abs: 0x8b, f32Floor: 0x8e, f32Add: 0x92, f32Sub: 0x93, f32Mul: 0x94,
  f64Sub: 0xa1, f64Mul: 0xa2, f64Div: 0xa3, f64Add: 0xa0,
  i32TruncF32S: 0xa8, i32TruncF64S: 0xaa, f32ConvertI32S: 0xb2, f64ConvertI32S: 0xb7, f64PromoteF32: 0xbb,
};
/** A 128-bit SIMD instruction (prefix 0xfd). */
export const simd = (code: number) => [0xfd, ...unsigned(code)];
export const V = {
  load: 0x00, load64Splat: 0x0a, store: 0x0b, const: 0x0c, shuffle: 0x0d, f32x4Splat: 0x13, f64x2Splat: 0x14,
  f32x4Extract: 0x1f, f32x4Replace: 0x20, f64x2Replace: 0x22, f32x4Le: 0x45, f32x4Ge: 0x46, and: 0x4e,
  load32Lane: 0x56, store8Lane: 0x58, store16Lane: 0x59, store64Lane: 0x5b, load32Zero: 0x5c, load64Zero: 0x5d,
  f32x4DemoteF64x2Zero: 0x5e, f64x2Promote: 0x5f, i8x16NarrowI16x8U: 0x66, i16x8NarrowI32x4S: 0x85,
  load32Splat: 0x09, i32x4Splat: 0x11, f32x4Nearest: 0x6a, i32x4Shl: 0xab, i32x4Add: 0xae,
  f32x4Add: 0xe4, f32x4Sub: 0xe5, f32x4Mul: 0xe6, f32x4Div: 0xe7, f32x4Min: 0xe8, f32x4Max: 0xe9,
  i32x4TruncSatF32x4S: 0xf8, f32x4ConvertI32x4S: 0xfa, f64x2Add: 0xf0, f64x2Sub: 0xf1, f64x2Mul: 0xf2,
  f64x2Pmin: 0xf6, f64x2Pmax: 0xf7, f64x2Div: 0xf3, f64x2Gt: 0x4a, or: 0x50, bitselect: 0x52, i64x2ShrU: 0xcd,
};

/** One function's code: `params` then `locals` ([count, type] groups) numbered from 0, its `results`; `build` emits
 * its body. */
export interface Func { params: number[]; results: number[]; locals: [number, number][]; code: number[] }

export type Emit = (...bytes: (number | number[])[]) => void;

export function func(params: number[], results: number[], locals: [number, number][], build: (emit: Emit) => void
                     ): Func {
  const code: number[] = [];
  build((...bytes) => { for (const b of bytes) Array.isArray(b) ? code.push(...b) : code.push(b); });
  code.push(op.end);
  return { params, results, locals, code };
}

/** An imported function: env.`label` of type (params) -> (results). Imports come first in the function index space. */
export interface Import { label: string; params: number[]; results: number[] }

/** A module of `imports` and `functions` (each of its own type, exported by name) and one exported memory of one
 * page. */
function moduleBytes(functions: [string, Func][], imports: Import[]): Uint8Array {
  const signature = (params: number[], results: number[]) => [0x60, ...vector(params.map((type) => [type])),
                                                              ...vector(results.map((type) => [type]))];
  const types = [...imports.map((i) => signature(i.params, i.results)), ...functions.map(([, f]) => signature(f.params, f.results))];
  const base = imports.length;
  return Uint8Array.from([
    0x00, 0x61, 0x73, 0x6d, 0x01, 0x00, 0x00, 0x00,
    ...section(1, vector(types)),
    ...(imports.length ? section(2, vector(imports.map((i, index) => [...name("env"), ...name(i.label), 0x00, index]))) : []),
    ...section(3, vector(functions.map((_, index) => [base + index]))),
    ...section(5, vector([[0x00, 1]])),
    ...section(7, vector([...functions.map(([label], index) => [...name(label), 0x00, base + index]),
                          [...name("memory"), 0x02, 0]])),
    ...section(10, vector(functions.map(([, f]) => {
      const body = [...vector(f.locals.map(([count, type]) => [count, type])), ...f.code];
      return [...unsigned(body.length), ...body];
    }))),
  ]);
}

/** The module compiled, or null where WebAssembly or its SIMD is missing (or the bytes do not validate). */
export function compileModule(functions: [string, Func][], imports: Import[] = []): WebAssembly.Module | null {
  try {
    const bytes = moduleBytes(functions, imports) as Uint8Array<ArrayBuffer>;
    return typeof WebAssembly === "object" && WebAssembly.validate(bytes) ? new WebAssembly.Module(bytes) : null;
  } catch {
    return null;
  }
}

/** One instance of a module: its memory and its exported functions by name. */
export interface KernelInstance { memory: WebAssembly.Memory; kernels: Record<string, (...args: number[]) => void> }

/** A getter of one shared instance of the module of `functions`, compiled and instantiated on the first call, then
 * kept (null where WebAssembly or its SIMD is missing, or the instance cannot be made). */
export function sharedInstance(functions: () => [string, Func][]): () => KernelInstance | null {
  let instance: KernelInstance | null | undefined;
  return () => {
    if (instance === undefined) {
      const compiled = compileModule(functions());
      try {
        const made = compiled && new WebAssembly.Instance(compiled, {});
        instance = made ? { memory: made.exports.memory as WebAssembly.Memory,
                            kernels: made.exports as unknown as KernelInstance["kernels"] } : null;
      } catch {
        instance = null;
      }
    }
    return instance;
  };
}

let wanted = true;

/** Node, for the tests and benchmarks: whether the kernels of remap_wasm.ts, tps_wasm.ts and blur_wasm.ts run (true,
 * where WebAssembly SIMD is) or the JavaScript they stand in for (false), to compare the two. Returns the setting
 * before. */
export function useWebAssembly(on: boolean): boolean {
  const before = wanted;
  wanted = on;
  return before;
}

/** Whether the kernels may run (useWebAssembly). */
export function webAssemblyWanted(): boolean {
  return wanted;
}

export const PAGE = 65536;  // bytes in a WebAssembly memory page

/** An instance's memory grown to at least `bytes`. */
export function reserveMemory(memory: WebAssembly.Memory, bytes: number): void {
  const have = memory.buffer.byteLength;
  if (bytes > have) memory.grow(Math.ceil((bytes - have) / PAGE));
}
