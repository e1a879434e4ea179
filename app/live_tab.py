"""The callbacks of the app's live tab (the webcam drives the person) and expression tab (sliders edit the person).

Both draw one person, chosen in the first tab (the uploaded shots, else the example person), through a
``lsr.core.live_session.LiveSession`` on ``ModelStore.live_reenactor`` (one network thread), encoded once per choice; what a
browser tab holds between calls lives in its ``gr.State`` (``LiveStream``, ``EditState``). No Gradio layout here.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from app.handlers import DISPLAY_SIDE, Limits, ModelStore, load_shots, upload_paths

LIVE_FPS_SMOOTHING = 0.2  # weight of the newest frame interval in the fps shown
LIVE_TRACE: list[tuple[int, float]] | None = None
"""Set to a list by ``lsr bench live`` (which serves the app in its own process): each camera frame's (index, time in
ms since the epoch) as the live handler takes it up, to match the browser's timestamps against."""
LIVE_LAYOUT_EVERY = 5
"""The live tab redraws its latent-layout picture on every this-many-th frame shown. A second picture each frame
(its JPEG, its transfer, the browser's redraw) cost the stream 1.13x of its rate with the browser on the same two
cores: 14.0 fps against 12.4 (``lsr bench live``'s browser run, 15 s each, medians of three alternated runs)."""
EDIT_SLIDERS = (  # name, minimum, maximum, neutral, step, label (landmarks.shape.edit.edit_landmarks' keywords)
    ("yaw", -30.0, 30.0, 0.0, 1.0, "head yaw (°)"),
    ("pitch", -20.0, 20.0, 0.0, 1.0, "head pitch (°)"),
    ("roll", -25.0, 25.0, 0.0, 1.0, "head roll (°)"),
    ("mouth", 0.0, 0.5, 0.0, 0.01, "mouth open (inter-ocular distances)"),
    ("eyes", 0.0, 1.5, 1.0, 0.05, "eyes open (x the anchor's)"),
    ("smile", -0.1, 0.15, 0.0, 0.01, "smile"),
    ("brows", -0.1, 0.15, 0.0, 0.01, "brows up"),
)


class PersonView:
    """A tab's person: its ``LiveSession`` (``key`` says which choice it was encoded for) and its layout's legend."""

    def __init__(self, session, key: tuple, kind: str) -> None:
        self.session, self.key, self.kind = session, key, kind
        self.legend = None
        """The model's layout channel names (``lsr.layout_view.load_layout_legend``), set by whoever knows the folder."""

    def layout_picture(self, layout: np.ndarray | None):
        """The generator's layout as a picture (class colours, or its parts with a legend: ``lsr.writer.layout_panel``), or a skip."""
        if layout is None:
            return gr_skip()
        from lsr.writer import layout_panel

        return layout_panel(layout, self.kind, max(DISPLAY_SIDE, layout.shape[-1]), self.legend)


def person_view(view: PersonView | None, store: ModelStore, limits: Limits, source_files, k: int, examples_dir: Path,
                kind: type[PersonView], **session_options) -> PersonView:
    """``view`` when it was made for this choice of person and options, else a new ``kind`` encoded for it."""
    from lsr.core.live_session import LiveSession

    paths, key = live_person(source_files, k, examples_dir)
    key = key + tuple(sorted(session_options.items()))
    if view is not None and view.key == key and view.session is not None:
        return view
    reenactor = store.live_reenactor()
    shots, _ = load_shots(paths, int(k), reenactor.crop_size, store.detector, limits)
    subject = reenactor.encode_subject(shots, cache=False)
    session = LiveSession(reenactor, subject, with_layout=True, detector=store.detector, **session_options)
    view = kind(session, key, reenactor.backend.layout_kind)
    from lsr.layout_view import load_layout_legend

    view.legend = load_layout_legend(store.weights)
    return view


def live_person(source_files, k: int, examples_dir: Path) -> tuple[list[Path], tuple]:
    """The shots a live stream drives: the uploaded ones, else the example person; and a key that changes with them."""
    paths = upload_paths(source_files)
    if not paths:
        from app import examples as ex

        paths = list(ex.ensure_examples(examples_dir).source_images)
    return paths, (tuple(str(p) for p in paths), int(k))


# ---- live: the webcam drives the person ----------------------------------------------------------------------------


class LiveStream(PersonView):
    """One browser tab's live stream: its person, the fps meter and the worker that finishes frames.

    Lives in the tab's ``gr.State``; a new choice of person encodes again, stopping the camera or closing the tab
    drops it (``close``)."""

    def __init__(self, session, key: tuple, kind: str) -> None:
        super().__init__(session, key, kind)
        self.fps: float | None = None
        self._last_shown: float | None = None
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="lsr-live")
        self._pending = None  # the previous frame's second half, running while this frame is prepared

    def step(self, frame: np.ndarray):
        """Pipelined: prepare this frame (tracking, warps) while the worker finishes the previous one (network,
        composite), and return that previous result; the first frame (and a frame without a face) waits for its own.
        The browser sends the next frame as soon as this returns, so the two halves overlap on two cores."""
        from lsr.core.live_session import LiveFrame

        prepared = self.session.prepare(frame)
        previous, self._pending = self._pending, None
        if isinstance(prepared, LiveFrame):  # no face: the last good frame, once the one in flight is done
            if previous is None:
                return prepared
            previous.result()
            return self.session.still(prepared.note)
        self._pending = self._worker.submit(self.session.finish, prepared)
        return (previous if previous is not None else self._pending).result()

    def tick(self) -> float | None:
        """Call once per frame shown: the smoothed output rate (None until two frames)."""
        now = time.perf_counter()
        if self._last_shown is not None and now > self._last_shown:
            rate = 1.0 / (now - self._last_shown)
            self.fps = rate if self.fps is None else (1 - LIVE_FPS_SMOOTHING) * self.fps + LIVE_FPS_SMOOTHING * rate
        self._last_shown = now
        return self.fps

    def close(self) -> None:
        self._worker.shutdown(wait=True, cancel_futures=True)
        self._pending = None
        self.session = None


def live_frame(store: ModelStore, limits: Limits, stream: LiveStream | None, frame: np.ndarray | None, source_files,
               k: int, examples_dir: Path, *, paste_back: bool = True, watermark: bool = True):
    """One webcam frame -> (shown image, latent layout picture, status line, the stream state).

    The person is encoded once per choice (uploaded shots, else the example person); a frame without a face shows the
    last good output with a note."""
    arrived = time.time() * 1000
    if frame is None:
        return gr_skip(), gr_skip(), "Start the camera to drive the person.", stream
    stream = person_view(stream, store, limits, source_files, k, examples_dir, LiveStream, paste_back=bool(paste_back),
                         watermark=bool(watermark))
    shown = stream.step(np.asarray(frame, np.uint8))
    if LIVE_TRACE is not None:
        LIVE_TRACE.append((stream.session.frames, arrived))
    fps = stream.tick()
    status = (f"{'–' if fps is None else f'{fps:.1f}'} fps · {1000 * shown.seconds:.0f} ms per frame · "
              f"frame {shown.index}" + (f" · {shown.note}" if shown.note else ""))
    layout = stream.layout_picture(shown.layout) if shown.index % LIVE_LAYOUT_EVERY == 0 else gr_skip()
    return shown.image, layout, status, stream


def gr_skip():
    """Leave an output as it is (Gradio's skip, imported where a callback needs it)."""
    import gradio as gr

    return gr.skip()


# ---- expression controls: sliders edit the anchor's landmarks (landmarks.shape.edit) -------------------------------------


class EditState(PersonView):
    """One tab's expression editor: its person and the last edited landmarks (crop pixels)."""

    target: np.ndarray | None = None


def edit_frame(store: ModelStore, limits: Limits, state: EditState | None, source_files, k: int, values: Sequence[float],
               examples_dir: Path, *, watermark: bool = True):
    """Slider values (``EDIT_SLIDERS`` order) -> (image in the person's scene, latent layout picture, status, state)."""
    from landmarks.shape.edit import edit_landmarks

    started = time.perf_counter()
    state = person_view(state, store, limits, source_files, k, examples_dir, EditState, watermark=bool(watermark))
    edits = {name: float(value) for (name, *_), value in zip(EDIT_SLIDERS, values)}
    state.target = edit_landmarks(state.session.subject.reference_landmarks, **edits)
    shown = state.session.render(state.target)
    layout = state.layout_picture(shown.layout)
    return shown.image, layout, f"updated in {1000 * (time.perf_counter() - started):.0f} ms", state


def save_pose(state: EditState | None, run_dir: Path) -> Path:
    """The edited pose as a 2-frame landmark driver (N, 68, 2) .npy in the person's frame pixels: the anchor's own
    face, then the edit, so ``lsr reenact --driver pose.npy`` (relative motion) puts the edit on any source."""
    from landmarks.exceptions import InputFileError
    from landmarks.io.image_files import atomic_output

    if state is None or state.target is None:
        raise InputFileError("move a slider first: there is no edited pose to save yet")
    session = state.session
    frames = np.stack([session.in_scene(session.subject.reference_landmarks), session.in_scene(state.target)])
    path = run_dir / "pose.npy"
    with atomic_output(path) as temp:
        with open(temp, "wb") as handle:
            np.save(handle, frames.astype(np.float32))
    return path
