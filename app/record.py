"""Recording a person's own shots with the webcam (the first tab): the best frame of each moment a recording asks for.

Frames stream from the browser's camera; each frame's face is found (the app's detector) and given to a
``landmarks.parts.coverage.MomentKeeper``, which keeps the best frame of each of ``landmarks.parts.coverage.MOMENTS``
(straight ahead, mouth wide open, "O", eyes closed, glances and turns each way, a smile). The kept shots show in a
gallery as they change, with the moments still missing; "Use these shots" writes them as PNGs under the app's
examples folder (which the app serves) and makes them the source person, like an upload.
"""

from __future__ import annotations

import uuid
from pathlib import Path

import numpy as np

from app.handlers import ModelStore

RECORD_HELP = """**Record your own shots.** Start the camera and go through the moments, a second or two each:
{moments}. The best frame of each is kept below (a moment shows once it differs clearly from your first frames);
then press *Use these shots*."""


def record_help() -> str:
    from landmarks.parts.coverage import MOMENTS

    return RECORD_HELP.format(moments="; ".join(f"**{name}** ({what})" for name, what in MOMENTS))


def record_frame(store: ModelStore, keeper, frame: np.ndarray | None):
    """One camera frame -> (keeper, the gallery's shots or a skip, the status line or a skip): the gallery and the
    line change only when a moment gets a better frame."""
    from app.live_tab import gr_skip
    from landmarks.parts.coverage import MomentKeeper

    keeper = keeper if keeper is not None else MomentKeeper()
    if frame is None:
        return keeper, gr_skip(), gr_skip()
    frame = np.ascontiguousarray(frame[..., :3], np.uint8)
    faces = store.detector.detect(frame)
    if not faces or not keeper.add(frame, faces[0].landmarks):
        return keeper, gr_skip(), gr_skip() if faces else "No face in view."
    return keeper, [(image, name) for name, image in keeper.shots()], status(keeper)


def status(keeper) -> str:
    missing = keeper.missing()
    kept = f"{len(keeper.shots())} moment(s) kept"
    return kept + (f"; still to show: {', '.join(missing)}." if missing else "; every moment is there.")


def recorded_files(keeper, examples_dir: Path) -> list[str]:
    """Write the kept shots as PNGs into a new folder under ``examples_dir`` -> their paths (an empty recording:
    a ``gradio.Error``)."""
    import gradio as gr

    from landmarks.io.image_files import write_image

    shots = [] if keeper is None else keeper.shots()
    if not shots:
        raise gr.Error("Nothing recorded yet: start the camera above and show your face.")
    folder = Path(examples_dir) / "recorded" / uuid.uuid4().hex[:12]
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for index, (name, image) in enumerate(shots):
        path = folder / f"{index:02d}_{name.strip(chr(34)).replace(' ', '_')}.png"
        write_image(path, image)
        paths.append(str(path))
    return paths
