// A user's own photos encoded in the page (issue 42): what Python does between "K photos of a person" and the
// encoded subject with its scene, so that the live session re-enacts them instead of the example person.
//
//   lsr/core/inputs.py load_subject_shots (image sources): each photo's faces with the default mesh detector
//     (landmarks.detect.mediapipe_tracker.MeshDetector: tracker.ts MeshTracker.meshes), the largest (or faceIndex-th) one's 68
//     points, cut out at the crop side C like the training data (landmarks.align.crop: cv2.warpAffine, INTER_CUBIC,
//     replicated border, INTER_AREA first when the face shrinks more than 2x), its points in crop pixels (float32);
//   landmarks/shape/expression.py pick_anchor (pose.ts): the anchor shot, its photo the scene (lsr.core.inputs.set_anchor);
//   lsr/core/engine.py ReenactorBase._encode: the shots at the model resolution S (resize_shots: INTER_AREA, points
//     (p + 0.5) S / C - 0.5), their landmark images (raster.ts), both to [-1, 1], through subject_encoder.onnx
//     (deploy/runtime.py OnnxBackend.encode_subject) -> the layout and style latents;
//   lsr/core/scene.py SourceScene (an image source): the anchor's photo, its 68 points and crop transform;
//   landmarks/scene/person_matte.py person_matte and landmarks/scene/compositing.py background_plate (segment.ts): the scene's layers,
//     the matte kept at 8 bits as `lsr export --web` writes it (lsr/export/web_site.py write_person);
//   lsr/core/finish.py shot_irises and subject_irises' anchor gaze (gaze.ts): each shot's irises by the tracker's iris
//     net, which eyes "warped" carries to the driver's gaze (iris_warp.ts);
//   lsr/core/subject.py Subject.part_banks for a photo source (eye_bank.ts buildEyeBank): the person's own eyes are
//     its shots' (crops, their points and irises), where the site banks eyes (site.json's "bank").
//
// Left out: the identity filter (landmarks.detect.same_person, dlib's face descriptor) that drops shots of another person's
// face; with more usable photos than K (default 8), Python's covering choice (landmarks.parts.coverage.choose_covering,
// with an image-based gaze measure) is replaced by the first K photos with a face (a note says so).
//
// In a page: const models = await loadPersonModels(read); const person = await encodePerson(photos, models,
// site.config); new LiveSession({ ...site, person }). photos: (H, W, 3) uint8 RGB each (photoFromImageData of a
// canvas's getImageData, the photo decoded upright: createImageBitmap(file, { imageOrientation: "from-image" });
// shrinkPhoto keeps a large one's scene, composited every frame, to a size the page can afford).

import * as ort from "onnxruntime-web";

import { folderReader } from "./files.js";
import { composeAffine, cropTransform, invertAffine, transformPoints } from "./geometry.js";
import { MESH_POINTS } from "./facemesh.js";
import { BankFace, buildEyeBank } from "./eye_bank.js";
import { findShotIrises, gazeOffsets, shotIrisCentres } from "./gaze.js";
import { FrameGenerator, generatorSizes, toNetwork } from "./network.js";
import { pickAnchor } from "./pose.js";
import { drawLandmarks } from "./raster.js";
import { openCvInverse, roundHalfEven, warpAffineCubic } from "./remap.js";
import { SEGMENTER_FILE, backgroundPlate, createSegmenter, personMatte, resizeUint8 } from "./segment.js";
import { LiveSession, Person, Reader, Site, SiteConfig, banksEyes } from "./session.js";
import { Affine, Tensor, median, tensor } from "./tensor.js";
import { MeshTracker, TrackerAssets, createTracker, loadTrackerAssets, meshTo68 } from "./tracker.js";

export const SUBJECT_ENCODER_FILE = "subject_encoder.onnx"; // deploy.runtime.SUBJECT_ENCODER_FILE, under models/
export const DEFAULT_K = 8; // lsr.core.inputs.DEFAULT_K
export const MAX_K = 32; // lsr.core.MAX_K

/** What encoding a person needs: the face tracker (its assets, or one made already), the subject encoder and the
 * selfie segmenter (their ONNX bytes, or sessions made already). */
export interface PersonModels {
  tracker: TrackerAssets | MeshTracker;
  subjectEncoder: Uint8Array | ort.InferenceSession;
  segmenter: Uint8Array | ort.InferenceSession;
}

export interface EncodeOptions {
  k?: number; // shots to use, 1..32 (default: min(8, the photos with a face))
  anchor?: number; // which of the shots is the neutral face and the scene (default: pick_anchor's)
  faceIndex?: number; // which face of a photo with several, largest first (0)
}

/** The encoded person (session.ts Person) and what encoding it decided. */
export interface EncodedPerson extends Person {
  photos: number[]; // which photo each shot is (indices into the photos given)
  frameLandmarks: Tensor<Float64Array>; // (K, 68, 2) each shot's 68 points in its photo's pixels
  matte: Tensor<Float32Array>; // (H, W) the scene's person matte as the net gives it (layers.matte: 8-bit steps)
  notes: string[]; // what the encoder skipped or chose, for the user
}

// ---- the crop (landmarks/align.py crop, warp_to_crop) ----------------------------------------------------------

/** The frame's region under a crop's footprint, `margin` pixels around, clipped (landmarks.align._frame_roi). */
function frameRoi(matrix: Affine, size: number, height: number, width: number, margin: number
                  ): [number, number, number, number] | null {
  const corners = tensor(Float64Array.of(-0.5, -0.5, size - 0.5, -0.5, -0.5, size - 0.5, size - 0.5, size - 0.5), [4, 2]);
  const footprint = transformPoints(corners, invertAffine(matrix)).data;
  const xs = [0, 2, 4, 6].map((i) => footprint[i]), ys = [1, 3, 5, 7].map((i) => footprint[i]);
  const x0 = Math.max(Math.floor(Math.min(...xs)) - margin, 0), y0 = Math.max(Math.floor(Math.min(...ys)) - margin, 0);
  const x1 = Math.min(Math.ceil(Math.max(...xs)) + margin + 1, width);
  const y1 = Math.min(Math.ceil(Math.max(...ys)) + margin + 1, height);
  return x0 >= x1 || y0 >= y1 ? null : [x0, y0, x1, y1];
}

/** A frame (H, W, 3) uint8 warped by a frame -> crop matrix into a size x size crop (landmarks.align.warp_to_crop:
 * INTER_CUBIC, replicated border; a crop that shrinks the frame more than 2x is area-averaged first). */
export function warpToCrop(frame: Tensor<Uint8Array>, matrix: Affine, size: number): Tensor<Uint8Array> {
  const [height, width] = frame.shape;
  let source = frame, m = matrix;
  const zoom = Math.sqrt(Math.abs(m[0] * m[4] - m[1] * m[3]));
  if (zoom < 0.5) {
    const roi = frameRoi(m, size, height, width, 4);
    if (roi !== null) {
      const [x0, y0, x1, y1] = roi, factor = Math.min(1, 2 * zoom);
      const region = new Uint8Array((y1 - y0) * (x1 - x0) * 3);
      for (let y = y0; y < y1; y++) {
        region.set(frame.data.subarray((y * width + x0) * 3, (y * width + x1) * 3), (y - y0) * (x1 - x0) * 3);
      }
      const newW = Math.max(1, roundHalfEven((x1 - x0) * factor)), newH = Math.max(1, roundHalfEven((y1 - y0) * factor));
      source = resizeUint8(tensor(region, [y1 - y0, x1 - x0, 3]), newW, newH, "area");
      const fx = (x1 - x0) / newW, fy = (y1 - y0) / newH;
      m = composeAffine(m, [fx, 0, 0.5 * fx - 0.5 + x0, 0, fy, 0.5 * fy - 0.5 + y0]);
    }
  }
  const image = { data: source.data, height: source.shape[0], width: source.shape[1], channels: 3 };
  return tensor(warpAffineCubic(image, openCvInverse(m), size, size, "replicate"), [size, size, 3]);
}

/** The training-framed crop of a face (landmarks.align.crop with its defaults): frame (H, W, 3) uint8, its face's
 * (68, 2) points -> the (size, size, 3) crop and the frame -> crop matrix. */
export function cropFace(frame: Tensor<Uint8Array>, landmarks: Tensor, size: number): { crop: Tensor<Uint8Array>; matrix: Affine } {
  const matrix = cropTransform(landmarks, size);
  return { crop: warpToCrop(frame, matrix, size), matrix };
}

// ---- the shots --------------------------------------------------------------------------------------------------

/** A picture's RGBA pixels (a canvas's ImageData) -> (H, W, 3) uint8 RGB. */
export function photoFromImageData(image: { data: ArrayLike<number>; width: number; height: number }): Tensor<Uint8Array> {
  const { width, height, data } = image, out = new Uint8Array(width * height * 3);
  for (let p = 0; p < width * height; p++) {
    out[3 * p] = data[4 * p]; out[3 * p + 1] = data[4 * p + 1]; out[3 * p + 2] = data[4 * p + 2];
  }
  return tensor(out, [height, width, 3]);
}

/** A photo no larger than `maxSide` pixels either way (INTER_AREA), else the photo itself. Not a step of Python's:
 * a page may shrink a camera roll's 12-megapixel photos before encodePerson, since the chosen photo becomes the scene
 * every frame is composited into (at its own size). */
export function shrinkPhoto(photo: Tensor<Uint8Array>, maxSide = 1280): Tensor<Uint8Array> {
  const [height, width] = photo.shape, factor = maxSide / Math.max(height, width);
  if (factor >= 1) return photo;
  return resizeUint8(photo, Math.max(1, Math.round(width * factor)), Math.max(1, Math.round(height * factor)), "area");
}

/** One photo's face as a shot. */
interface Shot { photo: number; crop: Tensor<Uint8Array>; cropLandmarks: Float64Array; frameLandmarks: Float64Array }

function f32(values: ArrayLike<number>): Float64Array {
  return Float64Array.from(values, (v) => Math.fround(v));
}

/** The face's crop side in frame pixels (landmarks.scene.compositing.face_side). */
function faceSide(landmarks: Tensor): number {
  const m = cropTransform(landmarks, 1024);
  return 1024 / Math.sqrt(Math.abs(m[0] * m[4] - m[1] * m[3]));
}


/** The shots at the model resolution with their landmark images, to [-1, 1], through the subject encoder
 * (lsr.core.engine.ReenactorBase._encode, deploy.runtime.OnnxBackend.encode_subject): shots (K, C, C, 3) uint8,
 * their (K, 68, 2) crop points -> the layout and style latents (D,) float32 each. */
export async function encodeShots(encoder: ort.InferenceSession, shots: Tensor<Uint8Array>, shotLandmarks: Tensor,
                                  resolution: number): Promise<{ layout: Float32Array; style: Float32Array }> {
  const [count, crop] = shots.shape, s = resolution, scale = s / crop;
  const small = new Uint8Array(count * s * s * 3), drawn = new Uint8Array(count * s * s * 3);
  for (let k = 0; k < count; k++) {
    const shot = tensor(shots.data.slice(k * crop * crop * 3, (k + 1) * crop * crop * 3), [crop, crop, 3]);
    small.set(crop === s ? shot.data : resizeUint8(shot, s, s, crop > s ? "area" : "linear").data, k * s * s * 3);
    const points = shotLandmarks.data.subarray(k * 136, (k + 1) * 136);
    // lsr.core.inputs.scale_points, then float32 as resize_shots keeps them
    const scaled = scale === 1 ? f32(points) : Float64Array.from(points, (v) => Math.fround((v + 0.5) * scale - 0.5));
    drawn.set(drawLandmarks(tensor(scaled, [68, 2]), s).data, k * s * s * 3);
  }
  const feed = {
    shots: new ort.Tensor("float32", toNetwork(small, count, s), [1, count, 3, s, s]),
    shot_landmark_images: new ort.Tensor("float32", toNetwork(drawn, count, s), [1, count, 3, s, s]),
  };
  const outputs = await encoder.run(feed, ["layout_latent", "style_latent"]);
  return { layout: new Float32Array(outputs.layout_latent.data as Float32Array),
           style: new Float32Array(outputs.style_latent.data as Float32Array) };
}

function inNode(): boolean {
  return typeof process !== "undefined" && typeof process.versions?.node === "string";
}

async function sessionOf(model: Uint8Array | ort.InferenceSession): Promise<ort.InferenceSession> {
  if (!(model instanceof Uint8Array)) return model;
  if (inNode()) ort.env.wasm.numThreads = 1;
  return ort.InferenceSession.create(model, { executionProviders: ["wasm"], graphOptimizationLevel: "all" });
}

/** The person of a user's photos (module comment): photos (H, W, 3) uint8 RGB each, any sizes -> the same Person as
 * loadSite reads for the example person, with what encoding decided. Throws when no photo shows a face, or when k
 * or anchor ask for more shots than there are. */
export async function encodePerson(photos: Tensor<Uint8Array>[], models: PersonModels, config: SiteConfig,
                                   options: EncodeOptions = {}): Promise<EncodedPerson> {
  const crop = config.crop_size, faceIndex = options.faceIndex ?? 0, k = options.k;
  if (k !== undefined && !(Number.isInteger(k) && k >= 1 && k <= MAX_K)) {
    throw new Error(`K (shots) must be an integer in 1..${MAX_K}, got ${k}`);
  }
  if (!(Number.isInteger(faceIndex) && faceIndex >= 0)) throw new Error(`face index must be >= 0, got ${faceIndex}`);
  if (photos.length === 0) throw new Error("no photos given: give one or more photos of the person");
  const tracker = models.tracker instanceof MeshTracker ? models.tracker : await createTracker(models.tracker);
  const usable: Shot[] = [], notes: string[] = [];
  let crowded = 0, tooFew = 0, faceless = 0;
  for (const [number, photo] of photos.entries()) {
    if (photo.shape.length !== 3 || photo.shape[2] !== 3 || !(photo.data instanceof Uint8Array)) {
      throw new Error(`photo #${number} must be (H, W, 3) uint8 RGB, got [${photo.shape}]`);
    }
    const faces = await tracker.meshes(photo);
    if (faces.length === 0) { faceless += 1; continue; }
    crowded += faces.length > 1 ? 1 : 0;
    if (faceIndex >= faces.length) { tooFew += 1; continue; }
    // landmarks.shape.mesh68.mesh_to_68 gives float32 points
    const frameLandmarks = f32(meshTo68(tensor(faces[faceIndex].mesh, [MESH_POINTS, 3]), tracker.mapping).data);
    const points = tensor(frameLandmarks, [68, 2]);
    const { crop: image, matrix } = cropFace(photo, points, crop);
    usable.push({ photo: number, crop: image, cropLandmarks: f32(transformPoints(points, matrix).data), frameLandmarks });
  }
  if (usable.length === 0) {
    if (tooFew) throw new Error(`face index ${faceIndex} asked for, but no photo shows more than ${faceIndex} face(s)`);
    const smallest = Math.min(...photos.map((p) => Math.ceil(Math.min(p.shape[0], p.shape[1]) / 2 / 8)));
    throw new Error(`no face found in the ${photos.length} photo(s); use frontal, well-lit photos of one person, with the `
                    + `face at least about ${smallest} px wide`);
  }
  if (faceless) notes.push(`${faceless} photo(s) show no face and were not used`);
  if (crowded) {
    notes.push(`${crowded} photo(s) show more than one face: used ${faceIndex === 0 ? "the largest" : `face ${faceIndex} by size`}`);
  }
  if (tooFew) notes.push(`${tooFew} photo(s) had fewer than ${faceIndex + 1} faces and were not used`);
  if (k !== undefined && k > usable.length) {
    throw new Error(`K=${k} is larger than the photos with a face (${usable.length} of ${photos.length}); lower K or `
                    + "give more photos");
  }
  const wanted = k ?? DEFAULT_K;
  if (usable.length > wanted) {
    notes.push(`${usable.length} photos show the face: the first ${wanted} are used (the page does not choose the `
               + "shots that cover the person best, as lsr does)");
  }
  const shots = usable.slice(0, wanted), count = shots.length;
  notes.push("the photos were not checked for another person's face (the page has no face recogniser)");
  const sides = shots.map((shot) => faceSide(tensor(shot.frameLandmarks, [68, 2])));
  if (median(sides) < crop) {
    notes.push(`the face is small (${median(sides).toFixed(0)} px framed, under the ${crop} px working crop): closer or `
               + "larger photos give a sharper face");
  }
  const frames = new Uint8Array(count * crop * crop * 3), shotLandmarks = new Float64Array(count * 136);
  const frameLandmarks = new Float64Array(count * 136);
  shots.forEach((shot, i) => {
    frames.set(shot.crop.data, i * crop * crop * 3);
    shotLandmarks.set(shot.cropLandmarks, i * 136);
    frameLandmarks.set(shot.frameLandmarks, i * 136);
  });
  const landmarks = tensor(shotLandmarks, [count, 68, 2]);
  if (options.anchor !== undefined && !(Number.isInteger(options.anchor) && options.anchor >= 0 && options.anchor < count)) {
    throw new Error(`anchor ${options.anchor} is not one of the ${count} shots (0..${count - 1})`);
  }
  const anchor = options.anchor ?? pickAnchor(landmarks, crop, crop);
  const [encoder, segmenter] = await Promise.all([sessionOf(models.subjectEncoder), sessionOf(models.segmenter)]);
  const shotTensor = tensor(frames, [count, crop, crop, 3]);
  const latents = await encodeShots(encoder, shotTensor, landmarks, config.resolution);
  // each shot's irises with the tracker's iris net, for eyes "warped" (lsr.core.subject.Subject.shot_irises), and the
  // anchor's gaze that the driver's moves (Subject.irises' second)
  const irises = await findShotIrises(tracker.faceMesh, shotTensor, landmarks);
  const anchorGaze = gazeOffsets(irises.subarray(8 * anchor, 8 * anchor + 8),
                                 shotLandmarks.subarray(136 * anchor, 136 * anchor + 136));
  // the person's own eyes: its shots', as Python banks a photo source's (Subject.part_banks)
  const eyeBank = banksEyes(config) ? buildEyeBank(Array.from({ length: count }, (_, i): BankFace => [
    tensor(frames.subarray(i * crop * crop * 3, (i + 1) * crop * crop * 3), [crop, crop, 3]),
    tensor(shotLandmarks.subarray(136 * i, 136 * (i + 1)), [68, 2]), irises.subarray(8 * i, 8 * (i + 1))])) : null;
  const scene = photos[shots[anchor].photo];
  const sceneLandmarks = tensor(Float64Array.from(shots[anchor].frameLandmarks), [68, 2]);
  const matte = await personMatte(segmenter, scene);
  const layers = backgroundPlate(scene, sceneLandmarks, matte);
  // 8 bits, as lsr export --web writes the example person's matte (and loadSite reads it back)
  const stepped = Float32Array.from(layers.matte.data, (v) => Math.min(Math.max(roundHalfEven(v * 255), 0), 255) / 255);
  return {
    shots: shotTensor, shotLandmarks: landmarks, shotIrises: shotIrisCentres(irises), anchorGaze, anchor, latents, scene,
    sceneLandmarks,
    sceneMatrix: cropTransform(sceneLandmarks, crop),
    layers: { matte: tensor(stepped, layers.matte.shape), plate: layers.plate }, eyeBank,
    photos: shots.map((shot) => shot.photo), frameLandmarks: tensor(frameLandmarks, [count, 68, 2]), matte, notes,
  };
}

/** What encodePerson needs from a site (`lsr export --web`'s models/): the tracker's assets, the subject encoder and
 * the selfie segmenter, through `read` (fetch in a page, the file system in Node). */
export async function loadPersonModels(read: Reader): Promise<PersonModels> {
  const [tracker, subjectEncoder, segmenter] = await Promise.all([
    loadTrackerAssets((path) => read(`models/${path}`)), read(`models/${SUBJECT_ENCODER_FILE}`),
    read(`models/${SEGMENTER_FILE}`)]);
  return { tracker, subjectEncoder, segmenter };
}

// ---- Node, for the tests ----------------------------------------------------------------------------------------

function splitPhotos(photos: Tensor<Uint8Array>): Tensor<Uint8Array>[] {
  const [count, height, width] = photos.shape, size = height * width * 3;
  return Array.from({ length: count }, (_, t) => tensor(photos.data.slice(t * size, (t + 1) * size), [height, width, 3]));
}

async function siteParts(siteFolder: string) {
  const read = await folderReader(siteFolder);
  const config = JSON.parse(new TextDecoder().decode(await read("site.json"))) as SiteConfig;
  return { read, config, models: await loadPersonModels(read) };
}

/** Node: the photos (K, H, W, 3) encoded with the models of the site in `siteFolder` -> every part of the person. */
export async function encodePhotosFromFolder(siteFolder: string, photos: Tensor<Uint8Array>, options: EncodeOptions = {}) {
  const { config, models } = await siteParts(siteFolder);
  const person = await encodePerson(splitPhotos(photos), models, config, options);
  return {
    shots: person.shots, shotLandmarks: person.shotLandmarks, anchor: person.anchor, photos: person.photos,
    shotIrises: tensor(person.shotIrises, [person.shots.shape[0], 2, 2]), anchorGaze: tensor(person.anchorGaze, [2, 2]),
    frameLandmarks: person.frameLandmarks, layoutLatent: person.latents.layout, styleLatent: person.latents.style,
    scene: person.scene, sceneLandmarks: person.sceneLandmarks, sceneMatrix: tensor(Float64Array.from(person.sceneMatrix), [2, 3]),
    matte: person.matte, layerMatte: person.layers.matte, plate: person.layers.plate, notes: person.notes,
    eyeBank: person.eyeBank ?? null,
  };
}

/** Node: the photos (K, H, W, 3) encoded as the person of the site in `siteFolder`, drawn at given crop targets
 * (T, 68, 2) by its live session (session.ts renderTargets, on this person) -> the composited frames (T, H, W, 3). */
export async function renderEncodedTargets(siteFolder: string, photos: Tensor<Uint8Array>, targets: Tensor<Float64Array>,
                                           options: EncodeOptions = {}) {
  const { read, config, models } = await siteParts(siteFolder);
  const person = await encodePerson(splitPhotos(photos), models, config, options);
  const generator = await FrameGenerator.create(await read("models/frame_generator.onnx"), generatorSizes(config));
  const site: Site = { config, person, generator, tracker: { update: async () => null } };
  const session = new LiveSession(site, false);
  const count = targets.shape[0], [height, width] = person.scene.shape, size = height * width * 3;
  const frames = new Uint8Array(count * size);
  for (let t = 0; t < count; t++) {
    const target = tensor(targets.data.slice(t * 136, (t + 1) * 136), [68, 2]);
    frames.set((await session.render(target)).image.data, t * size);
  }
  return tensor(frames, [count, height, width, 3]);
}

/** Node: landmarks.align.crop of one frame (H, W, 3) at its (68, 2) points -> { crop, matrix }. */
export function cropFaceTensor(frame: Tensor<Uint8Array>, landmarks: Tensor<Float64Array>, size: number) {
  const { crop, matrix } = cropFace(frame, landmarks, size);
  return { crop, matrix: tensor(Float64Array.from(matrix), [2, 3]) };
}

/** Node: person_matte then background_plate of a scene with the segmenter of a site -> { matte, plate }. */
export async function sceneLayersFromFolder(siteFolder: string, scene: Tensor<Uint8Array>, landmarks: Tensor<Float64Array>) {
  const read = await folderReader(siteFolder);
  const segmenter = await createSegmenter(await read(`models/${SEGMENTER_FILE}`));
  const matte = await personMatte(segmenter, scene);
  return { matte, plate: backgroundPlate(scene, landmarks, matte).plate };
}
