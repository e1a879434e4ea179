"""``lsr export --web OUT``: a static site that re-enacts the example person from the webcam in the browser, with no
server (issue 42). Any static host serves it; the frames never leave the machine.

What it writes (``OUT``):

* ``index.html``, ``app.js`` (the web runtime, ``deploy/web``, built with npm by ``deploy.web_build``), and
  onnxruntime-web's module and WASM files;
* ``models/``: the frame generator and the subject encoder of the model (``lsr export``'s graphs; the frame graph
  ending at G^s where the page runs the warp-guided composite itself, ``site.json``'s ``detail_sigma``), the face models
  the tracker runs (MediaPipe's detector, mesh and iris nets, and the 68-from-mesh mapping, as in
  ``landmarks/assets``) and MediaPipe's selfie segmenter: the page encodes a user's own photos with them
  (``deploy/web/src/encode.ts``);
* ``person/``: the example person encoded ahead of time, as ``lsr app``'s live tab encodes it: its K shots
  (crops) with their 68 points and iris centres (``shot_irises``, for ``eyes`` "warped"), the two latents, the
  anchor and its gaze (``anchor_gaze``, which the driver's moves; NaN, not found, written as null); its scene (the
  anchor's frame, its face and crop transform) with the person matte and background plate of the head layer
  (``landmarks.scene.compositing.background_plate``); pictures as raw uint8 files (``*.u8``, shapes in ``subject.json``);
  and the person's own eyes (``landmarks.parts.eyes.eye_bank``, issue 63), as ``Subject.part_banks`` gives them for
  the reenactor's ``bank``: for "all", every frame of the example person's video (``lsr.examples.REAL_SOURCE``), at
  most ``WEB_BANK_ENTRIES`` of them; its patches raw (``eye_bank.u8``), its index (apertures, gazes, head turns) in
  ``eye_bank.json`` (``write_eye_bank``);
* ``site.json``: the sizes and names the page needs; ``NOTICE.md``: where everything comes from.

The site is written into a temporary folder beside ``OUT`` and renamed into place: an interrupted export leaves the
old site (or none), never half of one.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from lsr.config import ExportConfig

# the tracker's assets (deploy/web/src/tracker.ts TRACKER_ASSET_FILES), relative to landmarks/assets
TRACKER_ASSETS = ("mediapipe/face_detection_short_range.onnx", "mediapipe/face_landmark.onnx",
                  "mediapipe/iris_landmark.onnx", "mediapipe/LICENSE", "mesh68.json", "mesh_canonical.json")
# what the page needs to encode a user's own photos (deploy/web/src/encode.ts, segment.ts): the bundle's subject
# encoder and the selfie segmenter of the person matte (landmarks.scene.person_matte), relative to landmarks/assets
SUBJECT_ENCODER = "subject_encoder.onnx"
SEGMENTER = "mediapipe/selfie_segmentation.onnx"
PAGE = Path(__file__).resolve().parents[2] / "deploy" / "web" / "static"
WEB_BANK_ENTRIES = 200
"""The site's eye bank holds at most this many entries, evenly spread over the video's frames (the Python default is
600): 4.5 MB of raw patches at most (22 kB an entry); the bundled example's 75 frames are all kept."""


@dataclasses.dataclass
class WebSite:
    folder: Path
    files: list[Path]
    k: int


def _write_json(path: Path, value) -> None:
    path.write_text(json.dumps(value, separators=(",", ":")))


def example_subject(bundle: Path, k: int | None = None):
    """The example person as the live tab encodes it (``lsr.examples.example_shots``, the shots of the app's example
    person): (the ``OnnxReenactor`` over ``bundle``, its encoded subject, the scene frame it is composited into)."""
    from deploy.runtime import OnnxReenactor
    from lsr.core.scene import SourceScene
    from lsr.examples import example_shots

    reenactor = OnnxReenactor(bundle, threads=1)
    shots = example_shots()
    subject = reenactor.encode_subject(shots, k=k if k is not None else len(shots), cache=False)
    return reenactor, subject, next(SourceScene(subject.shots, reenactor.crop_size))


def _nullable(values) -> list:
    """An array as nested lists, NaN as None (JSON null: JSON has no NaN; the page reads null back as NaN)."""
    def convert(item):
        return [convert(value) for value in item] if isinstance(item, list) else None if np.isnan(item) else item

    return convert(np.asarray(values, np.float64).tolist())


def example_eye_bank(reenactor, subject, scope: str):
    """The example person's eye bank of scope ``scope`` (``lsr.core.finish.BANKS``), as ``Subject.part_banks`` gives it
    for a video source, bounded by ``WEB_BANK_ENTRIES``: "all", every frame of its video (``lsr.examples.REAL_SOURCE``,
    whose frames its shots are); "shots", its shots; "none": None (None too where no frame shows a face)."""
    from lsr.core.subject import video_part_banks
    from lsr.examples import REAL_SOURCE

    if scope == "none":
        return None
    if scope == "all":
        return video_part_banks(REAL_SOURCE, reenactor.detector, max_entries=WEB_BANK_ENTRIES)[0]
    return subject.part_banks(scope, reenactor.detector)[0]


def write_eye_bank(folder: Path, bank) -> None:
    """An ``EyeBank`` as ``folder/eye_bank.u8`` (its patches (N, 2, h, w, 3), raw uint8) and ``folder/eye_bank.json``
    (its count, patch size (w, h), apertures, gazes and head turns; NaN written as null): what the page reads
    (``deploy/web/src/eye_bank.ts`` readEyeBank)."""
    from landmarks.parts.eyes.eye_bank import PATCH

    (folder / "eye_bank.u8").write_bytes(np.ascontiguousarray(bank.patches, np.uint8).tobytes())
    _write_json(folder / "eye_bank.json", {"count": len(bank), "patch": list(PATCH),
                                           "apertures": _nullable(bank.apertures), "gazes": _nullable(bank.gazes),
                                           "poses": _nullable(bank.poses)})


def read_eye_bank(folder: Path):
    """``write_eye_bank``'s files back -> the ``EyeBank``."""
    from landmarks.parts.eyes.eye_bank import PATCH, EyeBank

    folder = Path(folder)
    index = json.loads((folder / "eye_bank.json").read_text())
    count, shape = int(index["count"]), (int(index["count"]), 2, PATCH[1], PATCH[0], 3)
    raw = (folder / "eye_bank.u8").read_bytes()
    if list(index["patch"]) != list(PATCH) or len(raw) != int(np.prod(shape)):
        raise ValueError(f"{folder}: eye_bank.u8 must hold {count} entries of {PATCH[0]} x {PATCH[1]} patches "
                         f"({int(np.prod(shape))} bytes), got {len(raw)} bytes of {index['patch']} patches: "
                         "export the site again")
    patches = np.frombuffer(raw, np.uint8).reshape(shape)

    def values(name: str, shape: tuple[int, ...]) -> np.ndarray:
        return np.array(index[name], np.float64).reshape(shape)  # null -> NaN

    return EyeBank(patches.copy(), values("apertures", (count, 2)), values("gazes", (count, 2, 2)),
                   values("poses", (count, 2)))


def write_person(folder: Path, reenactor, subject, scene) -> dict:
    """The encoded person and its scene as files under ``folder`` (module docstring); returns subject.json's content."""
    from landmarks.io.image_files import write_image
    from landmarks.scene.person_matte import scene_layers

    folder.mkdir(parents=True, exist_ok=True)
    shots = subject.shots
    layers = scene_layers(scene.image, scene.landmarks)
    matte = np.clip(np.rint(layers.matte * 255), 0, 255).astype(np.uint8)  # 8 bits: what the page reads back
    # raw uint8 (H, W[, 3]) files, their shapes in subject.json: the page and Node read them without a decoder
    pictures = {"shots": shots.frames, "scene": scene.image, "plate": layers.plate, "matte": matte}
    for name, picture in pictures.items():
        (folder / f"{name}.u8").write_bytes(np.ascontiguousarray(picture, np.uint8).tobytes())
    write_image(folder / "scene.png", scene.image)  # the page's poster before the camera starts
    person = {
        "shapes": {name: list(picture.shape) for name, picture in pictures.items()},
        "k": len(shots.frames), "anchor": int(shots.anchor), "crop_size": int(reenactor.crop_size),
        "shot_landmarks": np.asarray(shots.landmarks, np.float64).tolist(),
        "shot_irises": _nullable(subject.shot_irises), "anchor_gaze": _nullable(subject.anchor_gaze),
        "layout_latent": np.asarray(subject.layout_latent, np.float32).ravel().tolist(),
        "style_latent": np.asarray(subject.style_latent, np.float32).ravel().tolist(),
        "scene": {"width": int(scene.image.shape[1]), "height": int(scene.image.shape[0]),
                  "landmarks": np.asarray(scene.landmarks, np.float64).tolist(),
                  "matrix": np.asarray(scene.matrix, np.float64).ravel().tolist()},
    }
    _write_json(folder / "subject.json", person)
    return person


def write_site(weights: Path, out: Path, k: int | None = None) -> WebSite:
    """Build the web runtime and write the site for the model folder ``weights`` into ``out`` (module docstring)."""
    from deploy.web_build import ensure_built, onnxruntime_files
    from landmarks.io.image_files import atomic_folder
    from lsr.export.bundle import cached_bundle
    from lsr.export.bundle_cache import FRAME_GENERATOR_FILE, FRAME_NETWORK_FILE
    from lsr.layout_view import LAYOUT_PALETTE, load_layout_legend

    dist = ensure_built()
    bundle = cached_bundle(weights)
    reenactor, subject, scene = example_subject(bundle, k)
    backend = reenactor.backend
    out = Path(out)
    with atomic_folder(out) as temp:
        for path in [*PAGE.iterdir(), *(dist / name for name in ("app.js", "app.js.map", "tracker.worker.js",
                                                                   "tracker.worker.js.map")), *onnxruntime_files()]:
            shutil.copy2(path, temp / path.name)
        models = temp / "models"
        (models / "mediapipe").mkdir(parents=True)
        # the page's frame generator: the graph ending at G^s where the page composites itself (blend_wasm.ts)
        composes = (bundle / FRAME_NETWORK_FILE).is_file()
        shutil.copy2(bundle / (FRAME_NETWORK_FILE if composes else FRAME_GENERATOR_FILE), models / "frame_generator.onnx")
        shutil.copy2(bundle / SUBJECT_ENCODER, models / SUBJECT_ENCODER)  # the page encodes a user's own photos
        assets = Path(__file__).resolve().parents[2] / "landmarks" / "assets"
        for name in (*TRACKER_ASSETS, SEGMENTER):
            shutil.copy2(assets / name, models / name)
        person = write_person(temp / "person", reenactor, subject, scene)
        scope = reenactor.bank if reenactor.bank_parts in ("eyes", "both") else "none"  # the page banks eyes only
        eye_bank = example_eye_bank(reenactor, subject, scope)
        if eye_bank is not None:
            write_eye_bank(temp / "person", eye_bank)
        legend = load_layout_legend(weights)
        _write_json(temp / "site.json", {
            "resolution": int(backend.resolution), "crop_size": int(reenactor.crop_size),
            "references": int(reenactor.warp_references), "latent_dim": len(person["layout_latent"]),
            "layout": backend.layout_kind, "layout_palette": LAYOUT_PALETTE.tolist(), "layout_legend": legend,
            "mouth": reenactor.mouth, "mouth_interior": reenactor.mouth_interior, "lids": reenactor.lids,
            "eyes": reenactor.eyes, "bank": scope if eye_bank is not None else "none", "k": person["k"],
            # the detail split (pixels of the crop) of the composite the page runs, or null: the graph's own
            "detail_sigma": (float(backend.config["reference_detail"]) * int(reenactor.crop_size) if composes else None),
        })
        (temp / "NOTICE.md").write_text(_notice())
        for path in temp.rglob("*"):  # readable by any static server
            path.chmod(0o755 if path.is_dir() else 0o644)
    return WebSite(out, sorted(path for path in out.rglob("*") if path.is_file()), person["k"])


def run_export(cfg: ExportConfig):
    """Entry point of ``lsr export``: ``--web OUT`` writes the site, otherwise the bundle
    (``lsr.export.bundle.run_export``)."""
    from landmarks.io.image_files import check_output_path
    from lsr.export.bundle import ExportResult, run_export as export_bundle
    from lsr.weights import resolve_weights

    if cfg.web is None:
        return export_bundle(cfg)
    check_output_path(cfg.web, "--web", folder=True)
    site = write_site(resolve_weights(cfg.weights), cfg.web)
    size = sum(path.stat().st_size for path in site.files) / 2**20
    print(f"wrote the web site to {site.folder} ({len(site.files)} files, {size:.1f} MiB; the example person, K = "
          f"{site.k}): serve it with any static server, e.g. python -m http.server -d {site.folder}")
    return ExportResult(site.folder, site.files, {})


def _notice() -> str:
    from lsr.examples import REAL_EXAMPLE

    return (
        "# What this site holds\n\n"
        f"- The example person: {REAL_EXAMPLE} (lsr/examples/NOTICE.md).\n"
        "- The face detector, face mesh, iris and selfie segmentation nets: MediaPipe (Apache-2.0, "
        "models/mediapipe/LICENSE), converted to ONNX by `lsr face-models convert` "
        "(landmarks/assets/mediapipe/SOURCES.json).\n"
        "- onnxruntime-web (MIT, Microsoft): ort.wasm.min.mjs and its WASM build; ort.min.mjs and its JSEP build, "
        "fetched only where the frame generator runs on WebGPU or WebNN.\n"
        "- The frame generator and the subject encoder: this project's model (MODEL_CARD.md).\n\n"
        "Every frame it shows is synthetic and marked so.\n"
    )
