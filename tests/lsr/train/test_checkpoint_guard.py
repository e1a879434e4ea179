"""Checkpoints (atomic, finite-only, pruned, RNG round trip), the NaN guard, lr schedule, EMA, sampler."""

from __future__ import annotations

import os
import random
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import torch

from lsr.train import checkpoint as ckpt
from lsr.train.distributed import DistContext, ShardedBatchSampler
from lsr.train.guard import NonFiniteGuard, TrainingDivergedError, all_finite
from lsr.train.optim import EMA, lr_factor


def _state(value: float) -> dict:
    return {"nets": {"w": torch.full((3,), value)}, "step": int(value)}


def test_save_prunes_and_loads_newest(tmp_path):
    for step in (1, 2, 3, 4):
        ckpt.save_checkpoint(_state(step), tmp_path, step, keep_last=2)
    names = [p.name for p in ckpt.list_checkpoints(tmp_path)]
    assert names == ["step_000000003.pt", "step_000000004.pt"]
    assert ckpt.load_checkpoint(tmp_path)["step"] == 4


def test_refuses_non_finite_weights(tmp_path):
    with pytest.raises(ckpt.CheckpointError, match="non-finite"):
        ckpt.save_checkpoint({"nets": {"w": torch.tensor([1.0, float("nan")])}}, tmp_path, 1)
    assert ckpt.list_checkpoints(tmp_path) == []


def test_failed_replace_keeps_previous_checkpoint(tmp_path, monkeypatch):
    ckpt.save_checkpoint(_state(1), tmp_path, 1)

    def broken_replace(src, dst):
        raise OSError("disk vanished")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError):
        ckpt.save_checkpoint(_state(2), tmp_path, 2)
    monkeypatch.undo()
    assert [p.name for p in tmp_path.iterdir()] == ["step_000000001.pt"]  # no temp left behind
    assert ckpt.load_checkpoint(tmp_path)["step"] == 1


def test_sigkill_during_save_never_corrupts_the_last_checkpoint(tmp_path):
    ckpt.save_checkpoint(_state(1), tmp_path, 1)
    # A child writes a large checkpoint and is SIGKILLed while torch.save is writing.
    script = textwrap.dedent(
        f"""
        import os, signal, torch
        from lsr.train import checkpoint as ckpt
        real_save = torch.save
        def save_then_die(obj, handle, *a, **k):
            handle.write(b"partial bytes of a checkpoint")
            handle.flush()
            os.kill(os.getpid(), signal.SIGKILL)
        torch.save = save_then_die
        ckpt.save_checkpoint({{"nets": {{"w": torch.zeros(1000)}}, "step": 2}}, {str(tmp_path)!r}, 2)
        """
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True)
    assert result.returncode == -9
    assert [p.name for p in ckpt.list_checkpoints(tmp_path)] == ["step_000000001.pt"]
    assert ckpt.load_checkpoint(tmp_path)["step"] == 1


def test_rng_state_round_trip():
    state = ckpt.capture_rng_state()
    first = (torch.rand(3), np.random.rand(3), random.random())
    ckpt.restore_rng_state(state)
    second = (torch.rand(3), np.random.rand(3), random.random())
    assert torch.equal(first[0], second[0]) and np.array_equal(first[1], second[1]) and first[2] == second[2]


def test_missing_checkpoint_is_a_typed_error(tmp_path):
    with pytest.raises(ckpt.CheckpointError, match="without --resume"):
        ckpt.load_checkpoint(tmp_path)


def test_guard_counts_recovers_and_gives_up():
    guard = NonFiniteGuard(max_consecutive=2, max_recoveries=1)
    assert not guard.record(False)
    assert not guard.record(True) and guard.consecutive == 0
    assert not guard.record(False)
    assert guard.record(False)
    guard.start_recovery(step=10)
    assert guard.recoveries == 1 and guard.skipped_total == 3
    guard.record(False)
    assert guard.record(False)
    with pytest.raises(TrainingDivergedError, match="diverged"):
        guard.start_recovery(step=20)
    restored = NonFiniteGuard()
    restored.load_state_dict(guard.state_dict())
    assert restored.state_dict() == guard.state_dict()


def test_all_finite_checks_loss_and_gradients():
    param = torch.nn.Parameter(torch.ones(2))
    assert all_finite(torch.tensor(1.0), [param])
    assert not all_finite(torch.tensor(float("inf")), [param])
    param.grad = torch.tensor([0.0, float("nan")])
    assert not all_finite(torch.tensor(1.0), [param])


def test_lr_schedule_decays_linearly_to_one_hundredth_in_the_window():
    factors = [lr_factor(step, total_steps=10, decay_steps=4) for step in range(10)]
    assert factors[:6] == [1.0] * 6
    assert factors[-1] == pytest.approx(0.01)
    assert all(a > b for a, b in zip(factors[5:], factors[6:]))


def test_ema_moves_towards_the_live_weights():
    live = torch.nn.Linear(2, 2)
    ema = EMA(live, decay=0.5)
    with torch.no_grad():
        live.weight.add_(1.0)
    before = ema.module.weight.clone()
    ema.update(live)
    assert torch.allclose(ema.module.weight, (before + live.weight) / 2)
    assert not any(p.requires_grad for p in ema.module.parameters())


def test_sharded_sampler_splits_each_global_batch_across_ranks():
    single = list(ShardedBatchSampler(20, 4, DistContext(), seed=3, epoch=1))
    rank0 = list(ShardedBatchSampler(20, 4, DistContext(0, 2), seed=3, epoch=1))
    rank1 = list(ShardedBatchSampler(20, 4, DistContext(1, 2), seed=3, epoch=1))
    assert len(single) == 5
    assert [a + b for a, b in zip(rank0, rank1)] == single
    resumed = list(ShardedBatchSampler(20, 4, DistContext(), seed=3, epoch=1, start_batch=2))
    assert resumed == single[2:]
