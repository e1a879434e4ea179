// The live path end to end: lsr/core/live_session.py LiveSession, on the site `lsr export --web` writes (lsr/export/web_site.py).
// Per frame: camera frame -> track 68 points (and the irises: the gaze, gaze.ts) -> smooth -> crop -> retarget onto
// the person's anchor shot -> landmark image -> warp the nearest shots (their irises carried to the gaze with eyes
// "warped", iris_warp.ts) -> frame generator -> the nearest mouth -> the camera's mouth interior (interior.ts)
// -> the camera's shut eyes (eyes.ts) -> the person's own eyes from its eye bank (eye_bank.ts: chosen per frame in
// order, as lsr.core.part_tracks.PartTracks is, laid in last, as lsr.core.finish.finish_parts does, with the lids
// again over an eye shut further than the bank shows) -> composite into the person's scene. A frame without a face
// shows the last good output again (and the bank's choice starts afresh).

import { compositeFace, SceneLayers } from "./composite.js";
import { folderReader } from "./files.js";
import { Affine, Tensor, tensor } from "./tensor.js";
import { invertAffine, transformPoints } from "./geometry.js";
import { EyeBank, EyeBankTrack, EyeChoice, pasteBankEyes, readEyeBank } from "./eye_bank.js";
import { DriverEyes, EyePatch, cutEyePatch, pasteEyes, shutEyes } from "./eyes.js";
import type { FaceMesh } from "./facemesh.js";
import { DriverGaze, trackedIrises } from "./gaze.js";
import { drawLids, shotLidGaps } from "./lids.js";
import { DriverMouth, cutDriverMouth, pasteInterior } from "./interior.js";
import { finishMouthNearest } from "./mouth.js";
import { FrameGenerator, GeneratorSizes, Latents, PendingSynthesis, generatorSizes } from "./network.js";
import { drawLandmarks } from "./raster.js";
import { DriverReference, liveTarget } from "./retarget.js";
import { LiveSmoother } from "./smooth.js";
import { References, warpReferences } from "./references.js";
import { TrackerAssets, createTracker, loadTrackerAssets } from "./tracker.js";

/** site.json (lsr/export/web_site.py write_site). */
export interface SiteConfig {
  resolution: number;
  crop_size: number;
  references: number;
  latent_dim: number;
  layout: string;
  layout_palette: number[][];
  layout_legend: string[] | null;
  mouth: string;
  mouth_interior: string;
  lids: string;
  eyes?: string;  // lsr.core.finish.EYES: "warped" carries the shots' irises to the gaze; the page draws none (a site
                  // written before it has none: "blend")
  bank?: string;  // lsr.core.finish.BANKS: which of the person's frames its own eyes come from ("all": the example
                  // person's video, "shots": its shots; a user's photos either way); "none", or a site written before
                  // the bank (none), keeps the synthesis' eyes
  k: number;
  detail_sigma?: number | null;  // where the frame graph ends at G^s, the detail split of the composite the page runs
                                 // (blend_wasm.ts); null or absent: the graph composites
}

/** The example person encoded ahead of time (person/ of the site). */
export interface Person {
  shots: Tensor<Uint8Array>;  // (K, C, C, 3) crops
  shotLandmarks: Tensor<Float64Array>;  // (K, 68, 2) crop pixels
  shotIrises: Float64Array;  // (K, 2, 2) flat: each shot's iris centres, crop pixels, NaN where not found or closing
  anchorGaze: Float64Array;  // (2, 2) flat: the anchor shot's gaze (gaze.ts gazeOffsets), NaN where not found
  anchor: number;
  latents: Latents;
  scene: Tensor<Uint8Array>;  // (H, W, 3): the anchor's frame, what the face is composited into
  sceneLandmarks: Tensor<Float64Array>;  // (68, 2) its face, frame pixels
  sceneMatrix: Affine;  // frame -> crop of that face
  layers: SceneLayers;
  eyeBank?: EyeBank | null;  // the person's own eyes (eye_bank.ts): the site's person/eye_bank.*, a user's photos
}

export type Reader = (path: string) => Promise<Uint8Array>;

/** A camera frame's face: its 68 points (frame pixels), its open mouth (interior.ts cutDriverMouth), the frame
 * around its eyes (eyes.ts cutEyePatch), cut where the frame is (a tracker's worker holds it), and its irises
 * ((2, 4) flat [x, y, radius, aperture], gaze.ts trackedIrises; null: none found). */
export interface Face {
  points: Tensor<Float64Array>; mouth: DriverMouth | null; eyes: EyePatch | null; irises: Float64Array | null;
}

/** What finds the face in a camera frame: src/tracker.ts MeshTracker here (`localTracker`), or the page's worker of
 * it (remote_tracker.ts). */
export interface Tracker { update(frame: Tensor<Uint8Array>): Promise<Face | null> }

/** A tracker of 68 points as a `Tracker`: the frame's mouth and eyes cut beside its points, and its irises (the
 * tracker's own, src/tracker.ts MeshTracker's, else found with its iris net). */
export function localTracker(tracker: { update(frame: Tensor<Uint8Array>): Promise<Tensor<Float64Array> | null>;
                                        irises?: Float64Array | null; faceMesh?: FaceMesh }): Tracker {
  return {
    async update(frame) {
      const points = await tracker.update(frame);
      if (points === null) return null;
      return { points, mouth: cutDriverMouth(frame, points), eyes: cutEyePatch(frame, points),
               irises: await trackedIrises(tracker, frame, points) };
    },
  };
}

/** subject.json's NaN-able numbers (written as null) -> float64, NaN where null; `count` NaN where absent (a site
 * written before them). */
function nullable(values: unknown, count: number): Float64Array {
  if (!Array.isArray(values)) return new Float64Array(count).fill(NaN);
  const flat = (values as unknown[]).flat(2) as (number | null)[];
  if (flat.length !== count) throw new Error(`person/subject.json: ${count} values expected, got ${flat.length}`);
  return Float64Array.from(flat, (value) => (value === null ? NaN : value));
}

export interface Site { config: SiteConfig; person: Person; generator: FrameGenerator; tracker: Tracker }

/** Whether a site's person takes its own eyes from an eye bank (site.json's "bank"; a site written before it: no). */
export function banksEyes(config: SiteConfig): boolean {
  return config.bank !== undefined && config.bank !== "none";
}

/** Read a site through `read` (fetch in a browser, the file system in Node): its config, the person, the frame
 * generator (`makeGenerator` given: that one, e.g. on a GPU, network.ts createFrameGenerator; else on WASM) and the
 * face tracker (`makeTracker` given: that one, e.g. in a worker; else src/tracker.ts here). */
export async function loadSite(read: Reader,
                               makeTracker?: (assets: TrackerAssets) => Promise<Tracker>,
                               makeGenerator?: (model: Uint8Array, sizes: GeneratorSizes, latents: Latents) => Promise<FrameGenerator>
                               ): Promise<Site> {
  const text = async (path: string) => JSON.parse(new TextDecoder().decode(await read(path)));
  const config = (await text("site.json")) as SiteConfig;
  const subject = await text("person/subject.json");
  const shapes = subject.shapes as Record<string, number[]>;
  const raw = async (name: string) => tensor(await read(`person/${name}.u8`), shapes[name]);
  const [shots, scene, plate, matte8] = await Promise.all(["shots", "scene", "plate", "matte"].map(raw));
  const matte = new Float32Array(matte8.data.length);
  for (let i = 0; i < matte.length; i++) matte[i] = matte8.data[i] / 255;
  const latents = { layout: Float32Array.from(subject.layout_latent), style: Float32Array.from(subject.style_latent) };
  const sizes = generatorSizes(config);
  const model = await read("models/frame_generator.onnx");
  const generator = await (makeGenerator ? makeGenerator(model, sizes, latents) : FrameGenerator.create(model, sizes));
  const assets = await loadTrackerAssets((path) => read(`models/${path}`));
  // a live session: the iris net only where an eye changed (tracker.ts irisGate), as in the worker
  const tracker = makeTracker ? await makeTracker(assets) : localTracker(await createTracker(assets, { irisGate: true }));
  const eyeBank = banksEyes(config) ? await readEyeBank(read) : null;
  const person: Person = {
    shots: shots as Tensor<Uint8Array>,
    shotLandmarks: tensor(Float64Array.from((subject.shot_landmarks as number[][][]).flat(2)), [subject.k, 68, 2]),
    shotIrises: nullable(subject.shot_irises, subject.k * 4),
    anchorGaze: nullable(subject.anchor_gaze, 4),
    anchor: subject.anchor,
    latents,
    scene: scene as Tensor<Uint8Array>,
    sceneLandmarks: tensor(Float64Array.from((subject.scene.landmarks as number[][]).flat()), [68, 2]),
    sceneMatrix: subject.scene.matrix as Affine,
    layers: { matte: tensor(matte, matte8.shape.slice(0, 2)), plate: plate as Tensor<Uint8Array> },
    eyeBank,
  };
  return { config, person, generator, tracker };
}

/** Milliseconds of each stage of one frame. */
export type Stages = Record<"track" | "retarget" | "warps" | "network" | "mouth" | "composite", number>;

export interface LiveFrame {
  image: Tensor<Uint8Array>;  // (H, W, 3) the person's scene with the re-enacted face (unmarked)
  face: boolean;  // false: no face in this camera frame; `image` is the last good output (or the scene)
  layout: Tensor<Float32Array> | null;  // (C_l, S, S) the latent layout, when asked for
  landmarkImage: Tensor<Uint8Array> | null;
  target: Tensor<Float64Array> | null;  // (68, 2) the target in the anchor's crop pixels
  ms: number;
  stages: Partial<Stages>;
}

const now = () => performance.now();

export class LiveSession {
  private readonly smoother = new LiveSmoother();
  private readonly reference = new DriverReference();
  private readonly referenceLandmarks: Tensor<Float64Array>;
  /** The subject's lids at rest (shotLidGaps), which the drawn lids are read against. */
  private readonly lidGaps: Float64Array;
  private readonly cropToScene: Affine;
  /** The target's gaze (lsr.core.live_session.LiveSession.gazes: eyes "warped" or "drawn"), relative to the anchor
   * shot's: the warps carry the irises to it ("warped"), the eye bank's choice asks for it. */
  private readonly gazes: DriverGaze | null;
  /** The person's own eyes chosen frame by frame (lsr.core.part_tracks.PartTracks' eyes), null without a bank. */
  readonly eyeTrack: EyeBankTrack | null;
  last: LiveFrame | null = null;
  frames = 0;
  faces = 0;

  constructor(readonly site: Site, readonly withLayout = true) {
    const { person } = site;
    const anchor = person.anchor * 68 * 2;
    this.referenceLandmarks = tensor(person.shotLandmarks.data.slice(anchor, anchor + 136), [68, 2]);
    this.lidGaps = shotLidGaps(person.shotLandmarks);
    this.cropToScene = invertAffine(person.sceneMatrix);
    const eyes = site.config.eyes;
    this.gazes = eyes === "warped" || eyes === "drawn" ? new DriverGaze(person.anchorGaze) : null;
    // relative motion: the targets' lids were retargeted from the driver's onto the anchor's
    this.eyeTrack = person.eyeBank && banksEyes(site.config)
      ? new EyeBankTrack(person.eyeBank, this.referenceLandmarks) : null;
  }

  /** Whether the references carry the shots' irises to the gaze (eyes "warped"; Python draws them with "drawn",
   * which the page runs as "blend"). */
  get warpsIrises(): boolean {
    return this.site.config.eyes === "warped";
  }

  /** The next face becomes the driver's neutral one (LiveSession.recentre). */
  recentre(): void {
    this.reference.reset();
    if (this.gazes !== null) this.gazes.reference = null;
  }

  /** One camera frame (H, W, 3) RGB and its capture time in seconds -> the re-enacted frame (LiveSession.step). */
  async step(frame: Tensor<Uint8Array>, timestamp: number): Promise<LiveFrame> {
    const prepared = await this.prepare(frame, timestamp);
    return "image" in prepared ? prepared : this.finish(prepared);
  }

  /** The first half of a step (LiveSession.prepare): track, smooth, retarget, the landmark image and the warped
   * shots. A frame without a face gives its LiveFrame at once. `finish` may run while the next frame is prepared. */
  async prepare(frame: Tensor<Uint8Array>, timestamp: number): Promise<Prepared | LiveFrame> {
    const started = now();
    const face = await this.site.tracker.update(frame);
    return this.fromFace(face, timestamp, started, now() - started);
  }

  /** `prepare` after the tracker: its face or null -> the network's inputs, or the face-less frame. */
  fromFace(face: Face | null, timestamp: number, started = now(), track = 0): Prepared | LiveFrame {
    this.frames += 1;
    const tracked = now();
    if (face === null) {
      this.smoother.gap();
      this.eyeTrack?.reset();  // the person's eyes are chosen afresh after a gap
      const shown = this.last?.image ?? this.site.person.scene;
      return { image: shown, face: false, layout: null, landmarkImage: null, target: null, ms: now() - started,
               stages: { track } };
    }
    const { points } = face;
    const gaps = this.reference.lids(points);  // the driver's lids at rest: its shut eyes are read against them
    const gaze = this.gazes === null ? null : this.gazes.update(face.irises, points);  // the raw points, as Python
    const target = liveTarget(this.reference, points, this.smoother.step(points, timestamp), this.site.config.crop_size,
                              this.referenceLandmarks, gaps);
    const mouth = this.site.config.mouth_interior === "driver" ? face.mouth : null;
    const eyes = this.site.config.lids === "driver" ? shutEyes(face.eyes, points, gaps) : null;
    return this.inputs(target, started, { track, retarget: now() - tracked }, mouth, eyes, gaze);
  }

  /** The network's inputs for a target (68, 2) in the anchor's crop pixels: its landmark image and warped shots
   * (with eyes "warped", the shots' irises carried to `gaze` (2, 2) flat, or without one to the nearest shot's). */
  inputs(target: Tensor<Float64Array>, started = now(), stages: Partial<Stages> = {},
         mouth: DriverMouth | null = null, eyes: DriverEyes | null = null, gaze: Float64Array | null = null): Prepared {
    const { config, person } = this.site;
    const warping = now();
    const scale = config.resolution / config.crop_size;
    const small = tensor(new Float64Array(target.data.length), [68, 2]);
    for (let i = 0; i < target.data.length; i++) small.data[i] = target.data[i] * scale;
    const landmarkImage = drawLandmarks(small, config.resolution);
    const irises = this.warpsIrises ? tensor(person.shotIrises, [person.shots.shape[0], 2, 2]) : null;
    const references = warpReferences(person.shots, person.shotLandmarks, target, config.references, 4, irises,
                                      gaze === null ? null : tensor(gaze, [2, 2]));
    const eyeChoice = this.eyeTrack === null ? null : this.eyeTrack.step(target, gaze);  // in order, as frames come
    return { target, landmarkImage, references, mouth, eyes, eyeChoice, started,
             stages: { ...stages, warps: now() - warping } };
  }

  /** Target landmarks (68, 2) in the anchor's crop pixels -> the frame (LiveSession.render). */
  async render(target: Tensor<Float64Array>): Promise<LiveFrame> {
    return this.finish(this.inputs(target));
  }

  /** The second half (LiveSession.finish): the network (`synthesize`), then the nearest mouth, the camera's mouth
   * interior and shut eyes and the composite into the scene (`complete`). */
  async finish(prepared: Prepared): Promise<LiveFrame> {
    return this.complete(await this.synthesize(prepared));
  }

  /** The network of `finish`. The page's loop starts the next frame's network as soon as this one returns and
   * completes this frame on its own thread meanwhile: onnxruntime's worker never waits for the composite (on a graph
   * ending at G^s, the warp-guided blend is part of `complete`, counted in the network's ms). */
  async synthesize(prepared: Prepared): Promise<Synthesized> {
    const { person, generator } = this.site;
    const starting = now();
    const pending = await generator.runNetwork(prepared.landmarkImage, person.latents, prepared.references.warped,
                                               prepared.references.masks, this.withLayout);
    return { prepared, pending, network: now() - starting };
  }

  /** The rest of `finish` after the network, for the frame `synthesize` gave. */
  complete({ prepared, pending, network }: Synthesized): LiveFrame {
    const { config, person } = this.site;
    const { target, landmarkImage, references } = prepared;
    const blending = now();
    const synthesis = pending.finish();
    const generated = now();
    network += generated - blending;
    const mouthed = config.mouth === "nearest"
      ? finishMouthNearest(synthesis.image, references.warped, references.masks, references.indices, target,
                           person.shotLandmarks, true) as Tensor<Uint8Array>
      : synthesis.image;
    const interior = pasteInterior(mouthed, target, prepared.mouth, true);
    // the shut lids as config.lids says (lsr.core.finish.finish_lids): the camera's, else the subject's drawn
    const lids = (image: Tensor, which: [boolean, boolean]) => (prepared.eyes !== null && config.lids === "driver"
      ? pasteEyes(image, target, prepared.eyes, true)
      : config.lids !== "shots" ? drawLids(image, target, this.lidGaps, true, which) : image);
    let face = pasteBankEyes(lids(interior, [true, true]), target, null, prepared.eyeChoice, true);  // last
    const shut = prepared.eyeChoice?.shut;
    if (shut && (shut[0] || shut[1])) face = lids(face, shut);  // shut further than the bank shows: lids over its eye
    const interiored = now();
    const composite = compositeFace(person.scene, person.sceneLandmarks, transformPoints(target, this.cropToScene),
                                    face as Tensor<Uint8Array>, person.sceneMatrix, person.layers);
    const done = now();
    this.faces += 1;
    const stages = { ...prepared.stages, network, mouth: interiored - generated, composite: done - interiored };
    const frame: LiveFrame = {
      image: composite.frame, face: true, layout: synthesis.layout, landmarkImage, target,
      ms: Object.values(stages).reduce((a, b) => a + (b ?? 0), 0), stages,
    };
    this.last = frame;
    return frame;
  }
}

/** A frame out of the network, between LiveSession.synthesize and LiveSession.complete: its ms in the network. */
export interface Synthesized { prepared: Prepared; pending: PendingSynthesis; network: number }

/** A frame's network inputs, between LiveSession.prepare and LiveSession.finish. */
export interface Prepared {
  target: Tensor<Float64Array>;
  landmarkImage: Tensor<Uint8Array>;
  references: References;
  mouth: DriverMouth | null;  // the camera frame's open mouth, whose interior the synthesis takes
  eyes: DriverEyes | null;  // the camera frame's shut eyes, which the synthesis takes
  eyeChoice: EyeChoice | null;  // the person's own eyes from its bank, laid in last
  started: number;
  stages: Partial<Stages>;
}

/** Node, for the tests: the site in `folder` driven by frames (T, H, W, 3) at `fps` -> the composited frames
 * (T, H', W', 3), the (T, 68, 2) targets (NaN: no face) and each frame's ms. */
export async function reenactFrames(folder: string, frames: Tensor<Uint8Array>, fps = 25) {
  const site = await loadSite(await folderReader(folder));
  const session = new LiveSession(site, false);
  const [count, height, width] = frames.shape;
  const size = height * width * 3;
  const outputs: Uint8Array[] = [];
  const targets = new Float64Array(count * 136).fill(NaN);
  const ms: number[] = [];
  const stages: Partial<Stages>[] = [];
  for (let t = 0; t < count; t++) {
    const frame = tensor(frames.data.slice(t * size, (t + 1) * size) as Uint8Array, [height, width, 3]);
    const result = await session.step(frame, t / fps);
    outputs.push(result.image.data);
    if (result.target) targets.set(result.target.data, t * 136);
    ms.push(result.ms);
    stages.push(result.stages);
  }
  const shape = site.person.scene.shape;
  const stacked = new Uint8Array(count * shape[0] * shape[1] * 3);
  outputs.forEach((output, t) => stacked.set(output, t * output.length));
  return { frames: tensor(stacked, [count, ...shape]), targets: tensor(targets, [count, 68, 2]), ms, stages };
}

/** Node, for the tests: the site's person drawn at given crop targets (T, 68, 2) -> the composited frames. */
export async function renderTargets(folder: string, targets: Tensor<Float64Array>) {
  const site = await loadSite(await folderReader(folder));
  const session = new LiveSession(site, false);
  const count = targets.shape[0];
  const shape = site.person.scene.shape;
  const stacked = new Uint8Array(count * shape[0] * shape[1] * 3);
  for (let t = 0; t < count; t++) {
    const target = tensor(targets.data.slice(t * 136, (t + 1) * 136), [68, 2]);
    stacked.set((await session.render(target)).image.data, t * shape[0] * shape[1] * 3);
  }
  return tensor(stacked, [count, ...shape]);
}
