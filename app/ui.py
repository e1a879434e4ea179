"""The Gradio page of ``lsr app``: K-shot source, the driver, the re-enacted video and the latent layout.

Layout only; the work happens in ``app.handlers`` (over ``lsr.pipeline``). Importing this module imports
Gradio but loads no model: ``ModelStore`` loads the weights on the first request.

    demo, store, files = build_app(AppConfig(weights=Path("runs/lsr/weights")))
    launch(demo, cfg, files)           # queue (one run at a time), upload limit, cleanup
"""

from __future__ import annotations

import json
import logging
import os
import signal
import sys
from pathlib import Path

import gradio as gr

from app import examples as ex
from app import handlers, record
from app import live_tab as live
from lsr.config import DEFAULT_FINETUNE_STEPS
from lsr.config import AppConfig

MODEL_EVENTS = "model"  # one concurrency group: the model and the face detector serve one request at a time
DELETE_CACHE = (1800, 3600)
CSS = ".lsr-warning {border: 2px solid #e8a33d; border-radius: 8px; padding: 4px 12px; background: #fff7e8}"  # every 30 min, remove Gradio's cached uploads/outputs older than an hour

INTRO = """# LSR: few-shot talking heads
Give **a few photos of one person** (the source, K shots) and **a driver video or landmarks**; the model
moves the source person like the driver. Based on *Learned Spatial Representations for Few-shot Talking-Head
Synthesis* (Meshry et al., ICCV 2021). Outputs are marked as synthetic (a visible mark and the file's metadata).

**Quick start:** click *Use the example person*, pick a *bundled driver example*, then **Re-enact**."""

AVERAGING_HELP = """Each source shot is encoded **alone** and rendered at the same target pose (the first driven
frame), next to the result of **averaging the K latents** (thesis eq. 4.3, Fig. 4.10): with more shots, details
seen in only one shot (an occluding hand, glasses, a bad frame) fade out of the average."""

LAYOUT_HELP = """Per frame: the driver frame, the landmark image the generator receives, its **latent spatial layout**
(each pixel's strongest channel in a colour of its own, the same in every frame and for every person; the legend
names the face parts each channel covers, `lsr bench layout-legend`; segmentation-stage models show class colours)
and the output.
Drag the slider to scrub through the frames."""


LIVE_HELP = f"""Your **webcam drives the person** of the first tab (the photos you gave there, or the example person
when there are none), live. Allow the camera and press its record button. Frames that arrive while the last one is
still being made are dropped, never queued, so what you see stays close to now; the line under the result shows
the rate, the time per frame and the frame count. The latent layout beside it is redrawn on every
{live.LIVE_LAYOUT_EVERY}th frame. Without a face in view the last good frame stays. The network runs
on onnxruntime (the first start exports it, a few seconds). Outputs carry the visible 'SYNTHETIC' mark unless it is
switched off in the first tab's options."""
EDIT_HELP = """**Sliders edit the person's face** (the photos of the first tab, or the example person): head yaw,
pitch and roll, mouth and eyes open, smile and brows move the landmarks of their most neutral shot, and the model
draws them in that shot's scene, with the latent layout beside it. *Save the pose* writes a landmark driver
(the neutral face, then the edit) that `lsr reenact --source SHOTS --driver pose.npy` accepts."""
LIVE_STREAM_EVERY = 0.05  # s between camera frames offered (caps the rate at 20 fps); the server keeps only the newest
LIVE_TIME_LIMIT = 600  # s a stream may run before the camera has to be started again
LIVE_STREAMS = 2  # live streams served at once (each holds a subject and a tracker)
LIVE_CAMERA_SIZE = (320, 240)  # asked of the camera: enough for a face filling a webcam frame, and a quarter of the
# pixels of 640x480 to grab, send and track
LIVE_CAMERA = {"video": {"width": {"ideal": LIVE_CAMERA_SIZE[0]}, "height": {"ideal": LIVE_CAMERA_SIZE[1]}}}


def result_columns(prefix: str, output_label: str, status: str, layout_label: str):
    """Two columns of a live or expression tab: the picture with its status line, then the latent layout;
    elem_ids ``{prefix}-output``, ``{prefix}-status``, ``{prefix}-layout`` (what the browser tests find)."""
    with gr.Column():
        output = gr.Image(label=output_label, interactive=False, elem_id=f"{prefix}-output", format="jpeg")
        status_line = gr.Markdown(status, elem_id=f"{prefix}-status")
    with gr.Column():
        layout = gr.Image(label=layout_label, interactive=False, elem_id=f"{prefix}-layout", format="jpeg")
    return output, status_line, layout


def model_summary(weights: Path | None, random_init: bool) -> str:
    """One line about the served model, read from its config.json (no model load)."""
    if weights is None:
        return handlers.how_to_get_weights()
    try:
        config = json.loads((weights / "config.json").read_text())
    except (OSError, ValueError):
        return f"Model: `{weights}` (its config.json is unreadable; the first run will say more)"
    from lsr.weights import DEFAULT_WEIGHTS

    name = "the shipped default model" if Path(weights).resolve() == DEFAULT_WEIGHTS.resolve() else f"`{Path(weights).name}`"
    size = config.get("resolution", "?")
    line = f"Model: {name} (variant `{config.get('variant', '?')}`, {size}x{size} network)"
    if config.get("variant") == "warp_guided":
        scale = config.get("crop_scale", 2)  # models_def.config.LATER_FIELDS: older configs blend at twice the side
        output = f"{scale * size}x{scale * size}" if isinstance(size, int) and isinstance(scale, int) else "a larger side"
        line += (f". It warps the source shots nearest to each driver pose onto it and blends them with its own "
                 f"synthesis at {output}, so detail comes from your shots")
        if config.get("reference_detail"):
            line += " (the fine detail most of the warped shots agree on, not a blur of them)"
        line += "; where the driver opens the mouth wider than the shots do, it comes from the nearest warped shot"
        from models_def.part_generator import MOUTH_FOLDER

        if (Path(weights) / MOUTH_FOLDER).is_dir():
            line += ", and a small mouth generator redraws the mouth from the driver's lips (lips, dark inside, teeth)"
        line += ("; the result goes into the source's own scene (its background, body and hair), only the face is "
                 "synthesised; fine-tuning on the shots (Options) is off by default: it measured no gain")
    if name == "the shipped default model":
        line += ". Trained on real talking-face clips and synthetic heads (MODEL_CARD.md)"
    line += "."
    if random_init:
        line = ("**Untrained demo model (`--random-init`)**: the output is noise. It shows how the app works; "
                "for real results train a model (`lsr train ...`) and start `lsr app --weights DIR`.\n\n" + line)
    return line


def served_weights(cfg: AppConfig, examples_dir: Path) -> tuple[Path | None, bool]:
    """--weights, else a --random-init tiny model in the cache, else the default location (or None)."""
    if cfg.weights is not None:
        return Path(cfg.weights), False
    if cfg.random_init:
        return handlers.random_init_weights(examples_dir.parent / "app_random_tiny"), True
    return handlers.default_weights(), False


def build_app(cfg: AppConfig) -> tuple[gr.Blocks, handlers.ModelStore, handlers.SessionFiles]:
    """The Blocks page, the lazily loading model store and the per-session file folders."""
    examples_dir = Path(cfg.examples_dir) if cfg.examples_dir is not None else ex.default_examples_dir()
    weights, random_init = served_weights(cfg, examples_dir)
    store = handlers.ModelStore(weights, cfg.device)
    files = handlers.SessionFiles()
    limits = handlers.Limits(cfg.max_video_seconds, cfg.max_video_frames, cfg.max_upload_mb, cfg.max_k)

    def preview_source(source_files, k):
        if not source_files:
            return [], "Upload photos or a video of the source person (or use the example person)."
        with handlers.readable_errors("read the source"):
            size = store.reenactor("torch").resolution if store.weights is not None else handlers.DISPLAY_SIDE
            shots, notes = handlers.load_shots(source_files, int(k), size, store.detector, limits)
        return handlers.shot_gallery(shots), "\n".join(f"- {note}" for note in notes)

    def use_example_person():
        with handlers.readable_errors("make the example"):
            return [str(p) for p in ex.ensure_examples(examples_dir).source_images]

    def use_example_driver(name):
        path = None
        if name and name != ex.DRIVER_EXAMPLE_NONE:
            with handlers.readable_errors("make the example"):
                path = ex.ensure_examples(examples_dir).driver(name)
        return str(path) if path is not None else gr.skip()

    def run(source_files, k, driver, motion, smooth, paste_back, finetune_steps, runtime, watermark,
            request: gr.Request, progress=gr.Progress(track_tqdm=True)):
        progress(0.0, desc="loading the model and the source shots")
        with handlers.readable_errors("re-enact"):
            run_dir = files.new_run(request.session_hash if request is not None else None)
            result = handlers.run_reenactment(
                store, limits, run_dir, source_files, int(k), driver, motion=motion, smooth=bool(smooth),
                paste_back=bool(paste_back), finetune_steps=int(finetune_steps), runtime=runtime,
                watermark=bool(watermark),
            )
        first = show_frame(0, str(result.panels_dir))
        scrubber = gr.Slider(minimum=0, maximum=max(1, result.frames - 1), value=0, step=1, interactive=True,
                             label=f"frame (0-{result.frames - 1})")
        return (str(result.video), result.summary, result.shots, result.averaging, first, scrubber,
                str(result.panels_dir), result.timing, result.coverage)

    def show_frame(index, panels_dir):
        if not panels_dir:
            return None
        path = handlers.panel_path(panels_dir, int(index or 0))
        if not path.is_file():
            return None
        from landmarks.io.image_files import read_image

        return handlers.labelled_panel(read_image(path))

    def stream_frame(frame, stream, source_files, k, in_scene, watermark):
        with handlers.readable_errors("drive the person live"):
            return live.live_frame(store, limits, stream, frame, source_files, int(k), examples_dir,
                                       paste_back=bool(in_scene), watermark=bool(watermark))

    def stop_live(stream):
        if stream is not None:
            stream.close()
        return None, "Camera stopped; the person's encoding was released."

    def recentre_live(stream):
        if stream is None or stream.session is None:
            return "Start the camera first."
        stream.session.recentre()
        return "Re-centred: your next face is the neutral one."

    def edit(state, source_files, k, watermark, *values):
        with handlers.readable_errors("edit the expression"):
            return live.edit_frame(store, limits, state, source_files, int(k), values, examples_dir,
                                       watermark=bool(watermark))

    def save_pose(state, request: gr.Request):
        with handlers.readable_errors("save the pose"):
            session = request.session_hash if request is not None else None
            return str(live.save_pose(state, files.folder(session, "pose")))

    def forget_session(request: gr.Request):
        files.drop(request.session_hash if request is not None else None)

    with gr.Blocks(title="LSR talking heads", delete_cache=DELETE_CACHE) as demo:
        gr.Markdown(INTRO)
        gr.Markdown(model_summary(weights, random_init), elem_id="model-status",
                    elem_classes=["lsr-warning"] if weights is None or random_init else None)
        panels_state = gr.State("")
        live_state = gr.State(None, delete_callback=lambda stream: stream is not None and stream.close())
        edit_state = gr.State(None)
        with gr.Tab("Upload and re-enact", id="batch"):
            with gr.Row(equal_height=False):
                with gr.Column():
                    gr.Markdown("### 1. Source person (K shots)")
                    source_files = gr.File(file_count="multiple", file_types=["image", "video"], elem_id="source-files",
                                           label="Photos of one person (1-32), or one short video")
                    example_person = gr.Button("Use the example person (GRID corpus, CC BY 4.0)", size="sm")
                    with gr.Accordion("...or record your own shots with the webcam", open=False, elem_id="record"):
                        gr.Markdown(record.record_help())
                        record_camera = gr.Image(sources=["webcam"], streaming=True, type="numpy",
                                                 label="Your camera (recording)", elem_id="record-camera",
                                                 webcam_options=gr.WebcamOptions(mirror=False, constraints=LIVE_CAMERA))
                        recorded = gr.Gallery(label="The best frame of each moment", columns=3, height=240,
                                              object_fit="contain", elem_id="recorded-shots")
                        record_status = gr.Markdown(elem_id="record-status")
                        use_recorded = gr.Button("Use these shots", size="sm", elem_id="use-recorded")
                    k = gr.Slider(1, cfg.max_k, value=min(4, cfg.max_k), step=1, label="K: shots to average",
                                  info="K shots are chosen to cover the person: spread over a video or the photos, "
                                       "with the widest mouth, closed eyes and furthest turns swapped in.")
                    shots = gr.Gallery(label="Shots used, with detected landmarks", columns=2, height=300,
                                       object_fit="contain", elem_id="shots")
                    source_notes = gr.Markdown()
                with gr.Column():
                    gr.Markdown("### 2. The driver")
                    driver = gr.File(file_types=[".mp4", ".mov", ".avi", ".mkv", ".webm", ".npy", ".json"],
                                      label="Driver video, or landmarks (.npy / .json, N x 68 x 2)",
                                      elem_id="driver-file")
                    driver_example = gr.Dropdown(list(ex.DRIVER_EXAMPLES), value=ex.DRIVER_EXAMPLE_NONE,
                                                 label="...or a bundled driver example", elem_id="driver-example")
                    with gr.Accordion("Options", open=False):
                        motion = gr.Radio(["relative", "absolute"], value="relative", label="Motion",
                                          info="relative: the driver's motion on the source's face shape; "
                                               "absolute: the driver's own landmarks")
                        smooth = gr.Checkbox(True, label="Smooth the driver's landmarks (One-Euro)")
                        paste_back = gr.Checkbox(True, label="Put the result into the source's own scene",
                                                 info="the source's frame size, background, body and hair (its anchor "
                                                      "shot, or its video's frames); otherwise the face crop")
                        finetune_steps = gr.Slider(0, 200, value=DEFAULT_FINETUNE_STEPS, step=1,
                                                   label="Fine-tuning steps on the source",
                                                   info="thesis §4.3.5; torch runtime only (ONNX skips it)")
                        runtime = gr.Radio(["auto", "torch", "onnx"], value="auto", label="Runtime",
                                           info="auto: onnx (the same frames, faster), torch when fine-tuning")
                        watermark = gr.Checkbox(True, label="Visible 'SYNTHETIC' watermark")
                    run_button = gr.Button("Re-enact" if store.weights is not None else "Re-enact (no model loaded: see the top)",
                                           variant="primary", elem_id="run", interactive=store.weights is not None)
                with gr.Column():
                    gr.Markdown("### 3. Result")
                    video = gr.Video(label="Re-enacted video (H.264, with the driver's audio)", elem_id="result-video",
                                     interactive=False, autoplay=False)
                    summary = gr.Markdown(elem_id="run-summary")
                    coverage = gr.Image(label="What the shots cover of the driver (blue: shots; red: frames beyond "
                                        "every shot)", interactive=False, elem_id="coverage", format="png")
            gr.Markdown("### The latent layout, frame by frame\n" + LAYOUT_HELP)
            panel = gr.Image(label="driver frame | landmarks | latent layout | output", show_label=False,
                             interactive=False, elem_id="layout-panel", format="png")  # titles are in the picture
            scrubber = gr.Slider(0, 1, value=0, step=1, label="frame", interactive=False, elem_id="frame-scrubber")
            gr.Markdown("### Latent averaging over the K shots\n" + AVERAGING_HELP)
            averaging = gr.Gallery(label="each shot alone | the K-shot average", columns=6, height=240,
                                   elem_id="averaging")
            with gr.Accordion("Timing per stage", open=False):
                timing = gr.Markdown()
        with gr.Tab("Live: your webcam drives the person", id="live"):
            gr.Markdown(LIVE_HELP)
            with gr.Row(equal_height=False):
                with gr.Column():
                    camera = gr.Image(sources=["webcam"], streaming=True, type="numpy", label="Your camera",
                                      elem_id="live-camera",
                                      webcam_options=gr.WebcamOptions(mirror=False, constraints=LIVE_CAMERA))
                    live_scene = gr.Checkbox(True, label="In the source's own scene (else the face crop)")
                    recentre = gr.Button("Re-centre: my face now is the neutral one", size="sm")
                live_output, live_status, live_layout = result_columns(
                    "live", "Re-enacted, live", "Start the camera to drive the person.", "Latent layout, live")
        with gr.Tab("Expression controls", id="edit"):
            gr.Markdown(EDIT_HELP)
            with gr.Row(equal_height=False):
                with gr.Column():
                    sliders = [gr.Slider(low, high, value=neutral, step=step, label=label, elem_id=f"edit-{name}")
                               for name, low, high, neutral, step, label in live.EDIT_SLIDERS]
                    with gr.Row():
                        edit_reset = gr.Button("Neutral", size="sm")
                        edit_save = gr.Button("Save the pose (.npy)", size="sm", elem_id="edit-save")
                    edit_file = gr.File(label="Landmark driver for `lsr reenact --driver`", interactive=False,
                                        elem_id="edit-file")
                edit_output, edit_status, edit_layout = result_columns(
                    "edit", "The person, edited", "Move a slider.", "Latent layout")
        preview_inputs = dict(fn=preview_source, inputs=[source_files, k], outputs=[shots, source_notes],
                              concurrency_id=MODEL_EVENTS)
        preview_inputs["show_progress_on"] = [shots]
        source_files.change(**preview_inputs)
        k.release(**preview_inputs)
        example_person.click(use_example_person, outputs=source_files, concurrency_id="examples")
        record_state = gr.State(None)
        record_camera.stream(lambda frame, keeper: record.record_frame(store, keeper, frame),
                             inputs=[record_camera, record_state], outputs=[record_state, recorded, record_status],
                             stream_every=LIVE_STREAM_EVERY, time_limit=LIVE_TIME_LIMIT, concurrency_id="record",
                             concurrency_limit=LIVE_STREAMS, show_progress="hidden")
        use_recorded.click(lambda keeper: record.recorded_files(keeper, examples_dir), inputs=record_state,
                           outputs=source_files, concurrency_id="examples")
        record_camera.clear(lambda: (None, [], ""), outputs=[record_state, recorded, record_status], queue=False)
        driver_example.change(use_example_driver, inputs=driver_example, outputs=driver, concurrency_id="examples")
        # An own upload replaces the example: show that in the dropdown too.
        driver.upload(lambda: ex.DRIVER_EXAMPLE_NONE, outputs=driver_example, queue=False)
        run_button.click(
            run,
            inputs=[source_files, k, driver, motion, smooth, paste_back, finetune_steps, runtime, watermark],
            outputs=[video, summary, shots, averaging, panel, scrubber, panels_state, timing, coverage],
            concurrency_id=MODEL_EVENTS,
            api_name="reenact",
            show_progress_on=[video],  # one progress bar / error badge, on the result, not on every panel
            scroll_to_output=True,
        )
        scrubber.change(show_frame, inputs=[scrubber, panels_state], outputs=panel, concurrency_id="scrub",
                        concurrency_limit=4, show_progress="hidden")
        slider_inputs = [edit_state, source_files, k, watermark, *sliders]
        for slider in sliders:
            slider.change(edit, inputs=slider_inputs, outputs=[edit_output, edit_layout, edit_status, edit_state],
                          concurrency_id="edit", concurrency_limit=2, show_progress="hidden")
        edit_reset.click(lambda: [spec[3] for spec in live.EDIT_SLIDERS], outputs=sliders, queue=False)
        edit_save.click(save_pose, inputs=edit_state, outputs=edit_file)
        live_inputs = [camera, live_state, source_files, k, live_scene, watermark]
        camera.stream(stream_frame, inputs=live_inputs, outputs=[live_output, live_layout, live_status, live_state],
                      stream_every=LIVE_STREAM_EVERY, time_limit=LIVE_TIME_LIMIT, concurrency_id="live",
                      concurrency_limit=LIVE_STREAMS, show_progress="hidden", api_name="live")
        camera.clear(stop_live, inputs=live_state, outputs=[live_state, live_status], queue=False)
        recentre.click(recentre_live, inputs=live_state, outputs=live_status, queue=False)
        demo.unload(forget_session)
    demo.lsr_examples_dir = examples_dir  # launch() allows serving these files
    return demo, store, files


def launch(demo: gr.Blocks, cfg: AppConfig, files: handlers.SessionFiles, *, block: bool = True) -> str:
    """Queue (one model run at a time, ``cfg.queue_size`` waiting), upload limit, then serve on host:port; returns the URL."""
    demo.queue(default_concurrency_limit=1, max_size=cfg.queue_size)
    examples_dir = Path(demo.lsr_examples_dir)
    examples_dir.mkdir(parents=True, exist_ok=True)
    _, url, _ = demo.launch(
        css=CSS,
        server_name=cfg.host, server_port=cfg.port, max_file_size=int(cfg.max_upload_mb * 1e6),
        allowed_paths=[str(files.root), str(examples_dir)], prevent_thread_lock=not block, share=False,
        quiet=not block, footer_links=["api"],
    )
    return url


def run_app(cfg: AppConfig) -> None:
    """Entry point of ``lsr app`` (blocks until interrupted; removes the app's temp files on exit)."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("httpx").setLevel(logging.WARNING)  # Gradio's own startup requests
    os.environ.setdefault("GRADIO_ANALYTICS_ENABLED", "False")
    demo, _, files = build_app(cfg)
    # SIGTERM (a service manager, `kill`) exits through the finally below, so temp files go too.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        launch(demo, cfg, files, block=True)
    finally:
        files.drop_all()

