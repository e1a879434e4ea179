"""``lsr reenact`` and ``lsr batch``: re-enact one (source, driver) pair, or many, into H.264 videos.

``lsr reenact --source S --driver D --out OUT.mp4`` runs one job. ``lsr batch`` takes its jobs from exactly one of
* ``--jobs jobs.csv`` with a header ``source,driver,output`` (relative paths are relative to the CSV's folder);
* ``--source-dir A --driver-dir B --out-dir C``: ``--pairing all`` (default) makes every source x driver job,
  written as ``C/<source stem>__<driver stem>.mp4``; ``--pairing by-name`` pairs files with the same stem
  (``A/alice.jpg`` with ``B/alice.mp4``) into ``C/<stem>.mp4``. A source is an image or a video file, or a
  sub-folder of images; a driver is a video, a sub-folder of frames, or a .npy/.json landmark file.

Outputs keep the driver video's frame count, fps and audio, and carry container metadata marking them as
synthetic (``lsr.core.provenance.provenance_metadata``); ``--watermark`` adds a visible "SYNTHETIC" mark. Each output
appears only once complete (temp file + rename), so a rerun skips finished jobs (resume) and redoes the rest.
Output paths and inputs are checked before any model loads: an output that cannot be written (a read-only or
missing-and-uncreatable folder, a parent that is a file), a ``--side-by-side`` equal to ``--out``, a missing source
or an unreadable driver is a one-line error naming the path. A driver with no face in any frame is an error; a
truncated driver video (fewer frames decode than it declares) is a warning with both counts.
``--shard i/n`` (or RANK/WORLD_SIZE under torchrun) takes every n-th job of the sorted list. A failing job leaves
no file, the others still run, and the command exits non-zero naming each failed job.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING

from landmarks.exceptions import InputFileError, LandmarksError, OutputPathError
from landmarks.io.image_files import IMAGE_SUFFIXES, check_output_path as check_writable
from lsr.core.engine import ReenactorBase, ReenactStats
from lsr.core.inputs import LANDMARK_SUFFIXES, describe_driver
from lsr.config.inference import ManyJobs, SingleJob
from lsr.core import DEFAULT_FINETUNE_LR
from lsr.errors import ConfigError, LsrError
from lsr.export.find_bundle import onnx_bundle_folder
from lsr.weights import resolve_weights
from lsr.writer import stage_table, write_reenactment

if TYPE_CHECKING:
    from lsr.config import BatchConfig, ReenactConfig


class ReenactJobsError(LsrError):
    """Some jobs of a batch failed (each is named with its problem); the finished outputs are kept."""


@dataclasses.dataclass(frozen=True)
class Job:
    source: Path
    driver: Path
    output: Path


# ---- job lists --------------------------------------------------------------------------------------------


def jobs_from_csv(path: Path) -> list[Job]:
    """Rows of a ``source,driver,output`` CSV (paths relative to the CSV's folder)."""
    if not path.is_file():
        raise ConfigError(f"jobs file not found: {path}")
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        if reader.fieldnames is None or not {"source", "driver", "output"} <= set(reader.fieldnames):
            raise ConfigError(f"{path} needs a header row with the columns source,driver,output")
        base = path.parent
        jobs = [Job(*(base / row[key].strip() for key in ("source", "driver", "output"))) for row in reader]
    if not jobs:
        raise ConfigError(f"{path} lists no jobs")
    return jobs


def _entries(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    if not folder.is_dir():
        raise ConfigError(f"folder not found: {folder}")
    return sorted(p for p in folder.iterdir() if p.is_dir() or p.suffix.lower() in suffixes)


def jobs_from_dirs(source_dir: Path, driver_dir: Path, out_dir: Path, pairing: str) -> list[Job]:
    """Every source x driver (``pairing='all'``) or same-stem pairs (``'by-name'``); see the module docstring."""
    from landmarks.io.video import VIDEO_SUFFIXES

    sources = _entries(source_dir, IMAGE_SUFFIXES + VIDEO_SUFFIXES)
    drivers = _entries(driver_dir, VIDEO_SUFFIXES + LANDMARK_SUFFIXES)
    if not sources or not drivers:
        raise ConfigError(f"no sources in {source_dir} or no drivers in {driver_dir}")
    if pairing == "by-name":
        by_stem = {d.stem: d for d in drivers}
        jobs = [Job(s, by_stem[s.stem], out_dir / f"{s.stem}.mp4") for s in sources if s.stem in by_stem]
        if not jobs:
            raise ConfigError(f"--pairing by-name found no source in {source_dir} with a same-named driver in {driver_dir}")
        return jobs
    return [Job(s, d, out_dir / f"{s.stem}__{d.stem}.mp4") for s in sources for d in drivers]


def parse_shard(shard: str | None) -> tuple[int, int]:
    """'i/n' -> (i, n); None -> torchrun's (RANK, WORLD_SIZE) when set, else (0, 1)."""
    if shard is None:
        return int(os.environ.get("RANK", 0)), int(os.environ.get("WORLD_SIZE", 1))
    try:
        index, count = (int(part) for part in shard.split("/"))
    except ValueError:
        raise ConfigError(f"--shard must look like i/n (e.g. 0/4), got {shard!r}") from None
    if not (count >= 1 and 0 <= index < count):
        raise ConfigError(f"--shard i/n needs 0 <= i < n, got {shard!r}")
    return index, count


def shard_jobs(jobs: list[Job], index: int, count: int) -> list[Job]:
    return sorted(jobs, key=lambda job: str(job.output))[index::count]


def collect_jobs(cfg: ReenactConfig | BatchConfig) -> list[Job]:
    if isinstance(cfg, SingleJob):
        return [Job(cfg.source, cfg.driver, cfg.out)]
    if cfg.jobs is not None:
        return jobs_from_csv(cfg.jobs)
    return jobs_from_dirs(cfg.source_dir, cfg.driver_dir, cfg.out_dir, cfg.pairing)


# ---- output paths -----------------------------------------------------------------------------------------


def check_output_path(path: Path, label: str = "--out") -> None:
    """Raise ``OutputPathError`` unless a video can be written at ``path`` (``landmarks.io.image_files.check_output_path``)."""
    if path.is_dir():
        raise OutputPathError(f"{label} {path} is a folder; give a file path ending in .mp4")
    check_writable(path, label)


def check_job_inputs(job: Job) -> None:
    """The job's source exists and its driver can be read (kind, frame count): before any model loads."""
    if not job.source.exists():
        raise InputFileError(f"source not found: {job.source}; give an image, a folder of images or a video")
    describe_driver(job.driver)  # raises a one-line InputFileError naming the file


def check_job_outputs(job: Job, side_by_side: Path | None, label: str) -> None:
    """The job's output (and side-by-side) are writable and distinct; see ``check_output_path``."""
    check_output_path(job.output, label)
    if side_by_side is not None:
        if side_by_side.resolve() == job.output.resolve():
            raise OutputPathError(
                f"--side-by-side and {label} are the same file ({job.output}); give the side-by-side its own path"
            )
        check_output_path(side_by_side, "--side-by-side")


# ---- runtimes ---------------------------------------------------------------------------------------------


def make_reenactor(cfg: ReenactConfig) -> ReenactorBase:
    from lsr.core.overlap import network_threads

    weights = resolve_weights(cfg.weights)
    threads = network_threads(cfg.threads)
    reenactor: ReenactorBase
    if cfg.resolved_runtime == "onnx":
        from deploy.runtime import OnnxReenactor

        reenactor = OnnxReenactor(onnx_bundle_folder(weights), threads=threads, detector=cfg.detector)
    else:
        from lsr.pipeline import Reenactor

        if threads > 0:
            import torch

            torch.set_num_threads(threads)  # process-wide: torch has no per-model thread pool
        from lsr.devices import resolve_device

        reenactor = Reenactor(weights, device=resolve_device("auto"), detector=cfg.detector)
    return reenactor  # the parts at their best measured defaults (ReenactorBase); lsr eval and lsr bench vary them


def run_job(reenactor: ReenactorBase, job: Job, cfg, *, side_by_side: Path | None = None) -> ReenactStats:
    """Re-enact one job into ``job.output`` (atomic). The subject must already be encoded."""
    written = write_reenactment(
        reenactor, job.driver, job.output, runtime=cfg.resolved_runtime,
        mode=cfg.motion, paste_back=cfg.paste_back, scene=cfg.scene, watermark=cfg.watermark, fps=cfg.fps,
        landmark_space=cfg.landmark_space, progress=cfg.progress, side_by_side=side_by_side,
    )
    for warning in written.warnings:
        print(f"lsr reenact: {warning}")
    if written.coverage:
        print(f"lsr reenact: {job.driver}: {written.coverage}")
    if written.stats.no_face:
        print(f"lsr reenact: {job.driver}: {written.stats.no_face} of {written.stats.frames} frame(s) had no face "
              "and were passed through")
    return written.stats


def _subject_for(reenactor: ReenactorBase, source: Path, cfg: ReenactConfig, cache: dict):
    """Encode (and optionally fine-tune on) a source once per batch."""
    key = str(source.resolve())
    if cache.get("key") == key:
        reenactor.subject = cache["subject"]
        if "backend_model" in cache:
            reenactor.backend.model = cache["backend_model"]
        return
    started = time.perf_counter()
    steps = cfg.resolved_finetune_steps
    if steps > 0:
        reenactor.backend.model = copy.deepcopy(cache.setdefault("base_model", reenactor.backend.model))
    subject = reenactor.encode_subject(source, k=cfg.k, face_index=cfg.face_index, anchor=cfg.anchor)
    for note in subject.shots.notes:
        print(f"lsr reenact: {source}: {note}")
    encoded = time.perf_counter()
    if steps > 0:
        from lsr.train.finetune import finetune_reenactor  # fine-tuning is composed on top of inference

        result = finetune_reenactor(reenactor, steps, lr=DEFAULT_FINETUNE_LR, progress=cfg.progress)
        print(f"fine-tuned on {len(subject.shots.frames)} shots of {source} ({steps} steps): "
              f"shot L1 {result.l1_before:.4f} -> {result.l1_after:.4f}")
        cache["backend_model"] = reenactor.backend.model
    cache.update(key=key, subject=subject, seconds=encoded - started, finetune_seconds=time.perf_counter() - encoded)


def summary_table(done: int, skipped: int, failed: int, stats: ReenactStats, wall: float) -> str:
    rows = [
        "| jobs done | skipped (finished) | failed | frames | frames without a face | end-to-end fps |",
        "|---|---|---|---|---|---|",
        f"| {done} | {skipped} | {failed} | {stats.frames} | {stats.no_face} | "
        f"{stats.frames / wall if wall > 0 else float('nan'):.2f} |",
        "",
    ]
    return "\n".join(rows) + "\n" + stage_table(stats)


def run_reenact(cfg: ReenactConfig | BatchConfig) -> ReenactStats:
    """Entry point of ``lsr reenact`` (one job, ``lsr.config.ReenactConfig``) and ``lsr batch`` (many,
    ``lsr.config.BatchConfig``). Returns the merged stats."""
    from tqdm import tqdm

    index, count = parse_shard(cfg.shard) if isinstance(cfg, ManyJobs) else (0, 1)
    side_by_side = cfg.side_by_side if isinstance(cfg, SingleJob) else None
    jobs = shard_jobs(collect_jobs(cfg), index, count)
    pending = [job for job in jobs if cfg.overwrite or not job.output.exists()]
    skipped = len(jobs) - len(pending)
    if skipped == 1 and len(jobs) == 1:
        print(f"lsr reenact: {jobs[0].output} exists, skipped; --overwrite to redo")
    elif skipped:
        print(f"lsr reenact: {skipped} of {len(jobs)} output(s) exist (finished earlier), skipped; --overwrite to redo")
    total = ReenactStats()
    failures: list[str] = []

    def fail(job: Job, exc: Exception) -> None:
        if len(jobs) == 1:  # a single job: its error is the one line the CLI prints
            if isinstance(exc, (LsrError, LandmarksError)):
                raise exc
            raise LsrError(f"{job.source} -> {job.output}: {exc}") from exc
        failures.append(f"{job.source} -> {job.output}: {exc}")
        print(f"lsr reenact: job failed: {failures[-1]}")

    runnable = []
    for job in pending:  # paths and inputs first: before the model loads, and a bad row does not stop the batch
        try:
            check_job_outputs(job, side_by_side, "--out" if isinstance(cfg, SingleJob) else "output")
            check_job_inputs(job)
            runnable.append(job)
        except (LsrError, LandmarksError) as exc:
            fail(job, exc)
    started = time.perf_counter()
    if runnable:
        reenactor = make_reenactor(cfg)
        cache: dict = {}
        quiet = not cfg.progress or len(runnable) < 2
        for job in tqdm(runnable, desc=f"jobs (shard {index}/{count})", unit="job", disable=quiet):
            try:
                _subject_for(reenactor, job.source, cfg, cache)
                if cache.get("counted") != cache["key"]:
                    total.add("subject_encoding", cache["seconds"])
                    total.add("finetune", cache["finetune_seconds"])
                    cache["counted"] = cache["key"]
                total.merge(run_job(reenactor, job, cfg, side_by_side=side_by_side))
            except (LsrError, LandmarksError, OSError) as exc:  # OSError: e.g. the disk filled while writing
                fail(job, exc)
    wall = time.perf_counter() - started
    print(summary_table(len(pending) - len(failures), skipped, len(failures), total, wall))
    if failures:
        raise ReenactJobsError(f"{len(failures)} of {len(pending)} job(s) failed: " + "; ".join(failures))
    return total
