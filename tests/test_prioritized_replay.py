"""Proportional prioritised replay (Schaul et al. 2016) against exact numpy computations of its
formulas, a duplicated-minibatch reading of the weighted critic loss, and kill/resume."""

import dataclasses

import numpy as np
import pytest
import torch
from scipy import stats
from test_ddpg_train import TINY, Crash, eval_table, train

from ddpg_her.agent import DDPG
from ddpg_her.buffer import Layout, PrioritizedBuffer, anneal_beta
from ddpg_her.config import AgentConfig
from ddpg_her.program import check
from ddpg_her.runfolder import RunFolder
from ddpg_her.trainer import Trainer

LAYOUT = Layout(in_dim=1, act_dim=1)
DRAWS = 200_000


def numbered(first: int, n: int) -> np.ndarray:
    """Rows whose every column holds the row's transition number."""
    return np.repeat(np.arange(first, first + n, dtype=np.float32)[:, None], LAYOUT.width, 1)


def filled_buffer(alpha: float, eps: float = 1e-6) -> tuple[PrioritizedBuffer, np.ndarray]:
    """Agent 0: 4 rows; agent 1: 9 rows through a ring of 6 (rows 6, 7, 8, 3, 4, 5 stored). Every
    stored row then gets a known TD error; returns the buffer and the errors (2, 6) by row
    (agent 0's rows 4, 5 unused)."""
    buf = PrioritizedBuffer(2, 6, LAYOUT, alpha=alpha, eps=eps, dtype=torch.float32,
                            device="cpu")
    buf.add(0, numbered(0, 4))
    buf.add(1, numbered(0, 9))
    td = np.array([[0.5, -2.0, 0.0, 1.0, 0, 0], [3.0, -0.1, 0.7, 0.2, -1.5, 0.05]])
    idx = torch.tensor([[0, 1, 2, 3, 0, 1], [0, 1, 2, 3, 4, 5]])
    buf.update_priorities(idx, torch.tensor(td[np.arange(2)[:, None], idx.numpy()]))
    return buf, td


def exact_p(td: np.ndarray, n: int, alpha: float, eps: float = 1e-6) -> np.ndarray:
    """Schaul et al.'s P(i) = p_i^alpha / sum_j p_j^alpha, p_i = |delta_i| + eps, in numpy."""
    p = (np.abs(td[:n]) + eps) ** alpha
    return p / p.sum()


@pytest.mark.parametrize("alpha", [0.6, 1.0])
def test_draws_follow_the_exact_proportional_distribution(alpha):
    buf, td = filled_buffer(alpha)
    gens = [torch.Generator().manual_seed(1), torch.Generator().manual_seed(2)]
    x, *_, idx, _ = buf.sample_prioritized(DRAWS, gens, beta=0.4)
    # the row read is the row drawn: agent 1's row j holds transition 6 + j or j (ring)
    assert torch.equal(x[0, :, 0].long(), idx[0])
    assert torch.equal(x[1, :, 0].long() % 6, idx[1])
    for k, n in ((0, 4), (1, 6)):
        counts = np.bincount(idx[k].numpy(), minlength=n)
        assert len(counts) == n  # never a row that is not stored
        expected = DRAWS * exact_p(td[k], n, alpha)
        assert stats.chisquare(counts, expected).pvalue > 1e-3
    # the same seeds draw the same indices
    again = buf.sample_prioritized(DRAWS, [torch.Generator().manual_seed(1),
                                           torch.Generator().manual_seed(2)], beta=0.4)[-2]
    assert torch.equal(again, idx)


@pytest.mark.parametrize("beta", [0.0, 0.4, 1.0])
def test_importance_weights_are_the_formula(beta):
    buf, td = filled_buffer(alpha=0.6)
    gens = [torch.Generator().manual_seed(3), torch.Generator().manual_seed(4)]
    *_, idx, w = buf.sample_prioritized(500, gens, beta=beta)
    for k, n in ((0, 4), (1, 6)):
        p = exact_p(td[k], n, 0.6)
        full = (n * p) ** -beta  # w_i = (N P(i))^-beta / max_j w_j, over the N stored rows
        np.testing.assert_allclose(w[k, :, 0].numpy(), (full / full.max())[idx[k].numpy()],
                                   rtol=1e-6)


def test_alpha_0_and_beta_0_is_uniform_sampling():
    buf, _ = filled_buffer(alpha=0.0)
    gens = [torch.Generator().manual_seed(5), torch.Generator().manual_seed(6)]
    *_, idx, w = buf.sample_prioritized(DRAWS, gens, beta=0.0)
    assert torch.equal(w, torch.ones_like(w))
    for k, n in ((0, 4), (1, 6)):
        counts = np.bincount(idx[k].numpy(), minlength=n)
        assert len(counts) == n and stats.chisquare(counts).pvalue > 1e-3


def test_new_rows_get_the_largest_stored_priority_and_beta_anneals_to_1():
    buf, _ = filled_buffer(alpha=0.6)
    buf.add(0, numbered(4, 1))  # row 4 of agent 0
    assert buf.priority[0, 4] == buf.priority[0, :4].max() == (2.0 + 1e-6) ** 0.6
    assert PrioritizedBuffer(1, 3, LAYOUT, alpha=0.6, eps=1e-6, dtype=torch.float32,
                             device="cpu").priority.sum() == 0  # empty: nothing stored
    assert anneal_beta(0.4, 0, 10) == pytest.approx(0.46)
    assert anneal_beta(0.4, 9, 10) == anneal_beta(0.4, 20, 10) == 1.0


def test_the_weighted_critic_step_is_the_step_on_a_minibatch_with_rows_repeated():
    """mean_i w_i (Q_i - y_i)^2 with integer weights summing to N is the plain loss of the
    minibatch in which row i appears w_i times: the critic after one weighted step equals the
    critic after one plain step on that minibatch (float64), and the TD errors are Q - y."""
    config = AgentConfig(hidden_sizes=(8, 8))
    g = torch.Generator().manual_seed(0)
    x, u, x2 = (torch.rand(1, 4, d, generator=g, dtype=torch.float64) for d in (3, 2, 3))
    r = -torch.rand(1, 4, 1, generator=g, dtype=torch.float64)
    term = torch.zeros(1, 4, 1, dtype=torch.float64)
    weight = torch.tensor([2.0, 0.0, 1.0, 1.0], dtype=torch.float64).view(1, 4, 1)
    rep = torch.tensor([0, 0, 2, 3])
    agents = [DDPG(config, 3, 2, init_generators=[torch.Generator().manual_seed(7)],
                   dtype=torch.float64) for _ in range(2)]
    norm = agents[0].normalizer
    q = agents[0].critic(norm(x), u)
    y = r + config.gamma * agents[0].critic_target(norm(x2), agents[0].actor_target(norm(x2)))
    agents[0].update(x, u, r, x2, term, weight=weight)
    agents[1].update(*(t[:, rep] for t in (x, u, r, x2, term)))
    torch.testing.assert_close(agents[0].td_error, (q - y).detach()[..., 0], rtol=0, atol=1e-12)
    for a, b in zip(agents[0].critic.parameters(), agents[1].critic.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-12)


PER = dataclasses.replace(TINY, prioritized_replay=True)


def test_a_prioritized_run_resumes_to_the_uninterrupted_one(tmp_path, monkeypatch):
    train([tmp_path / "whole"], config=PER)
    train([tmp_path / "uniform"])
    assert eval_table(tmp_path / "whole") != eval_table(tmp_path / "uniform")
    original = Trainer.train_episode

    def crashing(self):
        if self.episode == 7:
            raise Crash
        return original(self)

    monkeypatch.setattr(Trainer, "train_episode", crashing)
    with pytest.raises(Crash):
        train([tmp_path / "cut"], config=PER)
    monkeypatch.setattr(Trainer, "train_episode", original)
    train([tmp_path / "cut"], config=PER, resume=True)
    assert eval_table(tmp_path / "cut") == eval_table(tmp_path / "whole")
    a, b = (RunFolder(tmp_path / d).load_checkpoint(12) for d in ("whole", "cut"))
    assert torch.equal(a["priority"], b["priority"]) and len(a["priority"]) == 70
    for key in a["agent"]["critic"]:
        assert torch.equal(a["agent"]["critic"][key], b["agent"]["critic"][key])


def test_refused_where_it_is_not_implemented():
    with pytest.raises(ValueError, match=r"DDPG \+ HER only: not with --prioritized-replay$"):
        check("UR5Reach-v0", [{"region": "farbox"}], AgentConfig(prioritized_replay=True))
    for other in ({"algo": "td3"}, {"ensemble": 4}, {"batch_norm": True}):
        with pytest.raises(ValueError, match="prioritized_replay=True"):
            AgentConfig(prioritized_replay=True, **other)
