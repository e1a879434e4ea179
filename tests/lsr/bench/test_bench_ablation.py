"""`lsr bench ablation`: ranks beside the thesis' (Table 4.2), its config errors, and a tiny resumable run."""

from __future__ import annotations

import re

import pytest

from lsr.config import BenchAblationConfig
from lsr.errors import ConfigError
from lsr.bench import bench_ablation

THESIS_RANKS = {  # Table 4.2 among the four: PSNR, SSIM, LPIPS, ID-SIM, NMKE, FID (ties share a rank)
    "baseline": (2, 4, 4, 2, 4, 4),
    "spade_landmarks": (3, 3, 3, 3, 3, 2),
    "learned_seg": (3, 2, 2, 4, 1, 3),
    "latent_layout": (1, 1, 1, 1, 1, 1),
}


def test_competition_ranks_share_ties_and_skip_missing():
    ranks = bench_ablation.competition_ranks({"a": 2.0, "b": 3.0, "c": 3.0, "d": None, "e": float("nan")}, True)
    assert ranks == {"a": 3, "b": 1, "c": 1, "d": None, "e": None}
    assert bench_ablation.competition_ranks({"a": 0.1, "b": 0.2}, False) == {"a": 1, "b": 2}


def test_thesis_ranks_follow_table_4_2():
    ranks = bench_ablation.thesis_ranks(list(bench_ablation.VARIANTS))
    for variant, expected in THESIS_RANKS.items():
        assert tuple(ranks[metric][variant] for metric in bench_ablation.METRICS) == expected


def test_ranks_table_puts_ours_beside_the_thesis():
    # made-up scores: the thesis' order reversed on PSNR, equal to it on SSIM, no LPIPS / FID computed
    scores = {
        "baseline": {"psnr": 20.0, "ssim": 0.50, "lpips": None, "idsim": 0.90, "nmke": 0.05, "fid": None},
        "spade_landmarks": {"psnr": 19.0, "ssim": 0.60, "lpips": None, "idsim": 0.80, "nmke": 0.04, "fid": None},
        "learned_seg": {"psnr": 18.0, "ssim": 0.70, "lpips": None, "idsim": 0.70, "nmke": 0.03, "fid": None},
        "latent_layout": {"psnr": 17.0, "ssim": 0.80, "lpips": None, "idsim": float("nan"), "nmke": 0.03, "fid": None},
    }
    table = bench_ablation.ranks_markdown(scores)
    rows = {line.split("`")[1]: line for line in table.splitlines() if "(`" in line}
    assert list(rows) == list(bench_ablation.VARIANTS)
    assert "| 20.00 (1 / 2) | 0.500 (4 / 4) | – (– / 4) | 0.900 (1 / 2) | 0.050 (4 / 4) | – (– / 4) |" in rows["baseline"]
    assert "| 17.00 (4 / 1) | 0.800 (1 / 1) | – (– / 1) | n/a (– / 1) | 0.030 (1 / 1) | – (– / 1) |" in rows["latent_layout"]
    # PSNR: only learned_seg keeps its thesis rank (3); SSIM and NMKE: all four; ID-SIM: none
    assert table.splitlines()[-1] == "| same rank as the thesis | 1 of 4 | 4 of 4 | – | 0 of 4 | 4 of 4 | – |"


def test_schedule_keeps_the_same_total_steps_per_variant():
    steps = bench_ablation.schedule(3000)
    assert (steps["pretrain"], steps["full"], steps["latent"], steps["decay"]) == (400, 800, 1800, 200)
    cfg = BenchAblationConfig(synthetic_identities=2, steps=3000)
    for variant in bench_ablation.VARIANTS:
        stages = bench_ablation.train_config(cfg, variant, resume=False).stages
        with_layout = variant in ("learned_seg", "latent_layout")
        assert (stages.pretrain_epochs if with_layout else 0) + stages.full_epochs + stages.latent_epochs == 3000
        assert stages.steps_per_epoch == 1


@pytest.mark.parametrize(("changes", "message"), [
    ({}, "--data DATASET_ROOT and/or --synthetic-identities"),
    ({"data": "no/such/folder"}, "--data no/such/folder is not a folder"),
    ({"synthetic_identities": 2, "steps": 2}, "--steps must be >= 3"),
    ({"synthetic_identities": 2, "batch_size": 0}, "--batch-size, --k and --checkpoint-every"),
    ({"synthetic_identities": 2, "threads": -1}, "--threads"),
    ({"synthetic_identities": 2, "holdouts": 0}, "--inputs and --holdouts"),
    ({"synthetic_identities": 2, "fsth_root": "no/such/fsth"}, "--fsth-root no/such/fsth is not a folder"),
    ({"synthetic_identities": 2, "fid_weights": "no/such.pt"}, "--fid-weights no/such.pt is not a file"),
])
def test_bad_options_are_one_clear_line(changes, message, tmp_path):
    from pathlib import Path

    changes = {key: Path(value) if isinstance(value, str) else value for key, value in changes.items()}
    with pytest.raises(ConfigError, match=re.escape(message)) as raised:
        BenchAblationConfig(out=tmp_path / "out", **changes).validate()
    assert "\n" not in str(raised.value)


@pytest.mark.slow
def test_tiny_ablation_trains_resumes_and_ranks(tmp_path, monkeypatch, capsys, no_face_detector):
    import dataclasses
    import shutil
    from pathlib import Path

    import landmarks.detect.registry
    from lsr.train import trainer
    from lsr.train.checkpoint import list_checkpoints

    monkeypatch.setattr(landmarks.detect.registry, "make_detector", no_face_detector)
    monkeypatch.setenv("LSR_SHARED_DATA", str(tmp_path / "no_shared_data"))  # the FSTH part is skipped, with a reason
    benchmarks = tmp_path / "BENCHMARKS.md"
    shutil.copy(Path(__file__).resolve().parents[3] / "BENCHMARKS.md", benchmarks)
    cfg = BenchAblationConfig(synthetic_identities=2, out=tmp_path / "ablation", preset="tiny", steps=3, batch_size=2,
                              k=2, checkpoint_every=1, inputs=4, holdouts=2, max_identities=2, out_md=benchmarks,
                              progress=False)
    cfg.validate()
    # a session killed after one step of latent_layout: the bench resumes it from that checkpoint
    half = dataclasses.replace(bench_ablation.train_config(cfg, "latent_layout", resume=False), stop_at_step=1)
    trainer.run_train(half)
    capsys.readouterr()

    results = bench_ablation.run_bench_ablation(cfg)
    printed = capsys.readouterr().out
    assert "latent_layout: resuming at step 1 to step 3" in printed and "baseline: training to step 3" in printed
    assert "FSTH sample: skipped" in printed and "| no face / frames |" in printed
    for variant in bench_ablation.VARIANTS:
        assert (cfg.out / variant / "weights" / "model.safetensors").is_file()
        assert bench_ablation.trained_step(cfg.out / variant) == 3
    assert list(results) == ["Held-out synthetic identities"]
    assert set(results["Held-out synthetic identities"]) == set(bench_ablation.VARIANTS)
    for variant, ranks in THESIS_RANKS.items():  # our row of each variant with the thesis' PSNR and SSIM ranks
        label = bench_ablation.THESIS_TABLE_4_2[variant][0]
        row = next(line for line in printed.splitlines() if line.startswith(f"| {label} (`") and " / " in line)
        assert f" / {ranks[0]}) | " in row and f" / {ranks[1]}) | " in row
    section = benchmarks.read_text()
    assert section.count("<!-- eval:ablation:start -->") == 1 and "lsr bench ablation --synthetic-identities 2" in section
    assert "<!-- bench:speed:start -->" in section  # the other sections are kept

    def no_training(*args, **kwargs):
        raise AssertionError("a trained variant was trained again")

    monkeypatch.setattr(trainer, "run_train", no_training)
    checkpoints = {v: list_checkpoints(cfg.out / v / "checkpoints") for v in bench_ablation.VARIANTS}
    bench_ablation.run_bench_ablation(cfg)
    assert capsys.readouterr().out.count("already trained (3 steps), skipped") == 4
    assert checkpoints == {v: list_checkpoints(cfg.out / v / "checkpoints") for v in bench_ablation.VARIANTS}
    with pytest.raises(ConfigError, match="was started with --steps 3"):
        bench_ablation.run_bench_ablation(dataclasses.replace(cfg, steps=4))
