"""``lsr demo``: the README's main job on a fresh machine, with nothing to download.

By default it re-enacts the bundled real example (``lsr/examples``: two GRID corpus speakers, CC BY 4.0, their
attribution in ``lsr/examples/NOTICE.md``; both were among the default model's training people); with
``synthetic=True`` (``lsr demo --synthetic``) it renders two procedural people the default model never saw
(``lsr.data.synth``) instead, whose exact ground truth the tests use. Either pair is written as H.264 videos and
``lsr reenact`` runs with the shipped default model: the source person is re-enacted with the driver's head
motion and expression (relative motion, K source shots averaged), composited into the source's own video
(``--paste-back``: its background, body and hair stay; its frames play back and forth). ``--finetune-steps``
fine-tunes on the K shots first (thesis §4.3.5; the default, 0, shows the meta-learned output).

    out/inputs/source.mp4          person A (the K shots are sampled from it)
    out/inputs/driver.mp4          person B (the driving motion)
    out/demo.mp4                   person A re-enacted by B
    out/demo_side_by_side.mp4      driver | landmarks | latent layout | output
    out/demo_side_by_side.png      a few frames of it as one still
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from lsr.examples import REAL_DRIVER, REAL_EXAMPLE, REAL_SOURCE

# Identity seeds of the demo people. Training identities come from ``identity_seed_of(seed, index)`` hashes,
# so these plain seeds are people the default model has not seen.
SOURCE_SEED, DRIVER_SEED = 31, 32
SOURCE_FRAMES = 48
INPUT_SIZE = 256  # rendered larger than the model (128^2): the pipeline detects, crops and aligns like real video
FPS = 25
STILL_FRAMES = 4


def write_real_inputs(folder: Path, frames: int) -> tuple[Path, Path]:
    """Copy the bundled real example into ``folder`` (the driver cut to its first ``frames`` frames); returns the
    source's and the driver's paths."""
    import shutil

    from landmarks.io.image_files import atomic_output
    from landmarks.io.video import probe_video, trim_clip

    folder.mkdir(parents=True, exist_ok=True)
    source, driver = folder / "source.mp4", folder / "driver.mp4"
    with atomic_output(source) as temp:
        shutil.copyfile(REAL_SOURCE, temp)
    if frames < probe_video(REAL_DRIVER).frames:
        trim_clip(REAL_DRIVER, driver, frames)
    else:
        with atomic_output(driver) as temp:
            shutil.copyfile(REAL_DRIVER, temp)
    return source, driver


def write_inputs(folder: Path, frames: int) -> tuple[Path, Path]:
    """Render the procedural source and driver clips into ``folder``; returns their paths."""
    from landmarks.io.video import VideoWriter
    from lsr.data.synth import render_video

    folder.mkdir(parents=True, exist_ok=True)
    paths = folder / "source.mp4", folder / "driver.mp4"
    clips = render_video(SOURCE_SEED, SOURCE_FRAMES, INPUT_SIZE, fps=FPS), render_video(DRIVER_SEED, frames, INPUT_SIZE, fps=FPS)
    for path, clip in zip(paths, clips):
        with VideoWriter(path, FPS, metadata={"comment": "lsr demo input: procedural synthetic person"}) as writer:
            for frame in clip.frames:
                writer.write(frame)
    return paths


def write_still(video: Path, out: Path, count: int = STILL_FRAMES) -> Path:
    """``count`` evenly spaced frames of ``video`` stacked vertically into one PNG (atomic)."""
    from landmarks.io.image_files import write_image
    from landmarks.io.video import iter_frames, probe_video

    total = probe_video(video).frames
    wanted = set(np.linspace(0, max(total - 1, 0), count).round().astype(int).tolist())
    rows = [frame for index, frame in enumerate(iter_frames(video)) if index in wanted]
    write_image(out, np.concatenate(rows, axis=0))
    return out


def run_demo(out: Path, *, weights: Path | None = None, frames: int = 100, k: int = 8, finetune_steps: int | None = None,
             threads: int = 0, progress: bool = True, synthetic: bool = False) -> dict[str, Path]:
    """Write the inputs (the bundled real example, or two procedural people when ``synthetic``), re-enact, write
    the side-by-side still; returns the output paths."""
    from lsr.config import ReenactConfig
    from lsr.commands.reenact import run_reenact
    from lsr.weights import resolve_weights

    out = Path(out)
    weights = resolve_weights(weights)
    started = time.perf_counter()
    if synthetic:
        source, driver = write_inputs(out / "inputs", frames)
        print(f"demo: rendered a source person ({SOURCE_FRAMES} frames) and a driver ({frames} frames) into {out / 'inputs'}")
    else:
        source, driver = write_real_inputs(out / "inputs", frames)
        print(f"demo: the real example: {REAL_EXAMPLE}; copied into {out / 'inputs'} ('lsr demo --synthetic': two "
              "procedural people instead)")
    paths = {"video": out / "demo.mp4", "side_by_side": out / "demo_side_by_side.mp4"}
    cfg = ReenactConfig(weights=weights, source=source, driver=driver, out=paths["video"], k=k,
                        finetune_steps=finetune_steps, side_by_side=paths["side_by_side"], overwrite=True, paste_back=True,
                        threads=threads, progress=progress)
    cfg.validate()
    run_reenact(cfg)
    paths["still"] = write_still(paths["side_by_side"], out / "demo_side_by_side.png")
    print(f"demo: model {weights} (see MODEL_CARD.md for its training data and metrics)")
    print(f"demo: re-enacted video  -> {paths['video']}")
    print(f"demo: side-by-side      -> {paths['side_by_side']} (driver | landmarks | latent layout | output)")
    print(f"demo: still of it       -> {paths['still']}")
    print(f"demo: done in {time.perf_counter() - started:.0f} s")
    return paths
