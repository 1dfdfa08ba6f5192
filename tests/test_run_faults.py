"""Issue 23 on the trainer and its run folders: no silent wrong answer and no lost work under
every fault a resume, a disk or a second process can bring (issue 16's cases are in
test_run_errors.py)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch
from test_run_errors import TASK, TINY, eval_rows, train
from toy_goal_env import ENV_ID

from ddpg_her.config import AgentConfig
from ddpg_her.trainer import Trainer

SHORT = AgentConfig(**{**TINY.to_dict(), "episodes": 8, "eval_every": 1, "buffer_size": 60})
"""A checkpoint per episode and a buffer of about two episodes: each checkpoint's window starts
inside an older chunk."""


@pytest.fixture(autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
    torch.set_flush_denormal(False)


@pytest.fixture(scope="module")
def short_run(tmp_path_factory) -> Path:
    """A finished 8-episode run of `SHORT` (checkpoints 7 and 8, chunks 6-8)."""
    path = tmp_path_factory.mktemp("short") / "run"
    train([path], config=SHORT)
    return path


def copy_to(run: Path, dest: Path) -> Path:
    shutil.copytree(run, dest)
    return dest


def corrupt(path: Path) -> None:
    path.write_bytes(path.read_bytes()[:100])


def restored_rows(run: Path) -> torch.Tensor:
    trainer = Trainer(ENV_ID, TASK, SHORT, [0], [str(run)], resume=True, progress=False,
                      tensorboard=False)
    try:
        return trainer.buffer.rows[0, :int(min(trainer.buffer.total[0], SHORT.buffer_size))]
    finally:
        trainer.close()


# --- wrong results and lost work ---------------------------------------------------------------
def test_a_resumed_run_keeps_the_chunks_its_older_checkpoint_needs(tmp_path, short_run):
    """A resume (here of a finished run: nothing to train) used to delete the chunks before the
    latest checkpoint's window, which the older checkpoint still needed: a fallback to it then
    filled the buffer with rows never written, and training died on NaN."""
    resumed = copy_to(short_run, tmp_path / "resumed")
    train([resumed], config=SHORT, resume=True)
    pristine = copy_to(short_run, tmp_path / "pristine")
    for run in (resumed, pristine):
        corrupt(run / "checkpoints" / "episode-000008.pt")
    with pytest.warns(UserWarning, match="older checkpoint of episode 7"):
        a = restored_rows(resumed)
    with pytest.warns(UserWarning, match="older checkpoint of episode 7"):
        b = restored_rows(pristine)
    assert torch.equal(a, b) and bool(torch.isfinite(a).all())
    with pytest.warns(UserWarning, match="older checkpoint of episode 7"):
        train([resumed], config=SHORT, resume=True)
    assert eval_rows(resumed) == eval_rows(short_run)


def test_a_checkpoint_whose_buffer_has_a_gap_is_refused_naming_it(tmp_path, short_run):
    run = copy_to(short_run, tmp_path / "run")
    (run / "buffer" / "episode-000006.npz").unlink()  # the older checkpoint's window starts there
    corrupt(run / "checkpoints" / "episode-000008.pt")
    with pytest.warns(UserWarning, match="older checkpoint"), \
            pytest.raises(ValueError, match=rf"{run / 'buffer'}: the checkpoint of episode 7 "
                                            r"needs transitions \d+ to \d+, but no chunk holds"):
        Trainer(ENV_ID, TASK, SHORT, [0], [str(run)], resume=True)
