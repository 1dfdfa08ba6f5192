"""The agent's configuration: every number of the paper's Table I and every choice it leaves open.

Each field's docstring is its documentation and its ``--help`` text (see `field_docs`).
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import dataclasses
import enum
import inspect
import itertools
import textwrap
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from typing import Any, NoReturn

from ur5kin import checks as gate


class Parser(argparse.ArgumentParser):
    """The parser of every command: a usage error is one line (the usage comes with --help)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (--help for the usage)\n")


@contextlib.contextmanager
def usage_errors(parser: argparse.ArgumentParser, *kinds: type[Exception]) -> Iterator[None]:
    """An exception of ``kinds`` raised in the block is a usage error: ``parser.error`` with its
    message (status 2)."""
    try:
        yield
    except kinds as err:
        parser.error(str(err))


class Exploration(str, enum.Enum):
    """How the exploration rate nu perturbs the actor's action during training."""

    GAUSSIAN = "gaussian"
    """a + N(0, nu^2) per joint and step, nu in actor units (1 = half the action range)."""
    OU = "ou"
    """a + Ornstein-Uhlenbeck noise (theta = ``ou_theta``, sigma = nu, dt = 1 step), reset per
    episode, as in Lillicrap et al. 2016."""
    EPSILON = "epsilon"
    """With probability nu per step, a uniformly random action instead of the actor's."""


class HERStrategy(str, enum.Enum):
    """Which achieved goals the relabelled copies of an episode pursue."""

    NONE = "none"
    """No relabelling: plain DDPG."""
    FINAL = "final"
    """One copy whose goal is the final achieved goal (the paper's choice)."""
    FUTURE = "future"
    """``her_k`` copies, each with the achieved goal of a uniformly drawn step of the episode."""


class Algo(str, enum.Enum):
    """The off-policy algorithm of the stacked agents (issue 25); each is a module."""

    DDPG = "ddpg"
    """DDPG (Lillicrap et al. 2016), the paper's: `ddpg_her.agent`."""
    TD3 = "td3"
    """TD3 (Fujimoto et al. 2018): twin critics, target smoothing, delayed actor; `ddpg_her.td3`."""
    SAC = "sac"
    """SAC (Haarnoja et al. 2018) with automatic entropy tuning: `ddpg_her.sac`."""


@dataclass(frozen=True)
class AgentConfig:
    """DDPG + HER as in Lewis, Moll, Kavraki 2019 (Table I), with the open choices made explicit.

    The episode length T = 100 of Table I belongs to the task (the env's time limit), not here.
    Defaults marked "Table I" are the paper's; the others are our choices, each with its reason.
    """

    # --- Table I -------------------------------------------------------------------------------
    gamma: float = 0.98
    """Discount factor gamma, in [0, 1] (Table I)."""
    buffer_size: int = 1_000_000
    """Replay buffer capacity B per agent, transitions (real and relabelled together); the
    oldest are overwritten first; sampling is uniform (Table I)."""
    batch_size: int = 64
    """Minibatch size N, transitions per update (Table I)."""
    exploration_rate: float = 0.01
    """Exploration rate nu (Table I, 0.01). The paper does not define it; its meaning is set by
    --exploration: std of Gaussian noise or OU sigma in actor units (fraction of the half action
    range, so 0.01 is 0.0314 rad for joint angles in [-pi, pi]), or the per-step probability of
    a uniformly random action."""
    tau: float = 0.001
    """Target update ratio tau, in (0, 1]: target <- (1 - tau) target + tau online, after every
    update (Table I)."""
    actor_lr: float = 1e-4
    """Actor learning rate lambda_mu of Adam, > 0 (Table I)."""
    critic_lr: float = 1e-3
    """Critic learning rate lambda_Q of Adam, > 0 (Table I)."""
    episodes: int = 20_000
    """Training episodes M per agent (Table I). May be raised on --resume to extend a run."""
    eval_every: int = 100
    """Training episodes between two test sessions (paper: 100)."""
    eval_episodes: int = 100
    """Test episodes of the deterministic policy per session; the success count is out of this
    many (paper: 100)."""
    hidden_sizes: tuple[int, int] = (400, 300)
    """Units of the two hidden ReLU layers of actor and critic (Lillicrap et al. 2016: 400 300).
    The action enters the critic at its second layer; the actor's tanh output is scaled to the
    action box."""
    final_init: float = 3e-3
    """Final layers of actor and critic are initialised uniform in [-final_init, final_init],
    final_init > 0 (Lillicrap et al.); the hidden layers uniform in +-1/sqrt(fan_in)."""
    her_strategy: HERStrategy = HERStrategy.FINAL
    """Hindsight relabelling after each episode: final (paper), future, or none."""
    her_k: int = 4
    """Relabelled copies per episode for --her-strategy future (final always appends one)."""

    # --- choices the paper leaves open ---------------------------------------------------------
    exploration: Exploration = Exploration.GAUSSIAN
    """Meaning of the exploration rate: gaussian | ou | epsilon. Gaussian by default: the paper's
    actions are absolute joint angles, where temporally correlated OU noise only drifts the
    target, and Gaussian noise is what DDPG + HER (Andrychowicz et al. 2017) uses."""
    ou_theta: float = 0.15
    """Mean reversion of OU noise per step (Lillicrap et al.: 0.15); used with --exploration ou."""
    warmup_episodes: int = 100
    """Episodes of uniformly random actions (redrawn every step) before the actor acts and
    before the first update. The paper does not say. Without them, at nu = 0.01 the buffer holds
    almost one action per state, the critic's action gradient is extrapolation, and the tanh
    actor is driven into saturation (every joint commanded to +-pi) where its gradient vanishes
    for good; with them the critic first learns how the return depends on the action. 100 is
    one test interval, so the first test session scores the untrained actor."""
    updates_per_episode: int = 100
    """Gradient updates of each agent after each training episode (the paper does not say).
    100 = one per step of a full T = 100 episode; counting per episode rather than per step
    keeps K agents whose episodes end at different steps in lockstep."""
    normalize_obs: bool = True
    """Normalise the network input by running mean and std of the stored inputs, clipped to
    +-obs_clip (as in Andrychowicz et al. 2017). The paper does not say; joint angles (rad),
    velocities (rad/s), accelerations (rad/s^2) and positions (m) differ by orders of magnitude,
    and unnormalised inputs learn far slower."""
    obs_clip: float = 5.0
    """Normalised inputs are clipped to +-obs_clip, standard deviations."""
    norm_eps: float = 0.01
    """Lower bound of the normaliser's standard deviation, in the input's units."""
    critic_l2: float = 0.0
    """L2 weight decay coefficient of the critic, >= 0 (Lillicrap et al. used 1e-2; Table I lists
    none)."""
    # --- Lillicrap et al.'s low-dimensional networks beyond Table I (issue 22) ----------------
    batch_norm: bool = False
    """Batch normalisation as Lillicrap et al. 2016 had it for low-dimensional inputs: on the
    network input (actor and critic each) and on the pre-activations of every hidden layer of the
    actor and of the critic's layers before the action input (its first). Off by default: Table
    I lists none, although the paper says it used Lillicrap's networks. Which statistics each
    pass uses, how they move, and the cost of its autograd update: docs/design.md, "Agent"."""
    batch_norm_momentum: float = 0.01
    """Weight m of each minibatch in the running statistics of --batch-norm, in (0, 1]:
    running <- (1 - m) running + m batch, the variance unbiased. Lillicrap et al. do not say;
    ours 0.01 (Keras's decay 0.99): about one episode of 100 updates."""

    # --- other algorithms than the paper's DDPG (issue 25) -----------------------------------
    algo: Algo = Algo.DDPG
    """The algorithm: ddpg (the paper's) | td3 | sac. All share the replay, HER, normaliser,
    exploration noise (SAC samples its policy besides; give it --exploration-rate 0 for SAC
    alone), test protocol and Table I's gamma, tau, rates, batch and buffer; TD3 and SAC use
    two critics of Lillicrap's form and are trained by autograd. A run resumes only with its
    own algorithm."""
    td3_target_noise: float = 0.2
    """TD3's target policy smoothing: std of the Gaussian noise on the target action, actor
    units (1 = half the action range), >= 0 (Fujimoto et al. 2018: 0.2)."""
    td3_target_noise_clip: float = 0.5
    """TD3's smoothing noise is clipped to +-this, actor units, >= 0 (Fujimoto et al.: 0.5)."""
    td3_policy_delay: int = 2
    """TD3 updates the actor and the targets every this many critic updates, >= 1 (Fujimoto
    et al.: 2)."""
    sac_init_alpha: float = 1.0
    """SAC's initial temperature alpha, > 0 (Haarnoja et al.'s code: log alpha = 0). It is then
    tuned so that the policy's entropy approaches -dim(A) (Haarnoja et al. 2018)."""
    sac_alpha_lr: float = 3e-4
    """Adam learning rate of SAC's log alpha, > 0 (Haarnoja et al. 2018: 3e-4)."""

    # --- prioritised replay (Schaul et al. 2016; the paper's section III, issue 40) -----------
    prioritized_replay: bool = False
    """Proportional prioritised replay instead of uniform sampling: transition i is drawn with
    P(i) = p_i^alpha / sum_j p_j^alpha (i.i.d. draws over the stored rows, not Schaul's
    stratified segments), p_i = |TD error of its last update| + per_eps, a new transition at
    the largest stored p; the critic's squared error is weighted by w_i = (N P(i))^-beta /
    max_j w_j (the max over the N stored rows). The paper says it tended to destabilise or
    prevent learning. DDPG alone (no ensemble, no batch norm), on the host trainer."""
    per_alpha: float = 0.6
    """Prioritisation exponent alpha, in [0, 1]: 0 is uniform sampling (Schaul et al.: 0.6)."""
    per_beta: float = 0.4
    """Importance-sampling exponent beta at the start, in [0, 1], raised linearly to 1 at the
    last training episode: beta = per_beta + (1 - per_beta) (e + 1) / episodes for the updates
    after episode e (0-based) (Schaul et al.: 0.4 -> 1). An --episodes raised on --resume
    stretches the rest of the schedule."""
    per_eps: float = 1e-6
    """Added to |TD error| so that no transition's priority is 0, > 0 (Schaul et al. do not
    give it; 1e-6 as OpenAI baselines)."""

    # --- the regional ensemble (issue 25) ------------------------------------------------------
    ensemble: int = 1
    """Members M of the regional ensemble of --algo agents (1: none, a single agent). Each member
    owns one cell of a k-means partition of the task's goals and acts on the goals of its cell;
    the M members share one agent's budget (updates_per_episode / M each). Every rule, and
    why: docs/design.md, "The regional ensemble"."""

    flush_denormals: bool = True
    """Flush subnormal floats (below 1.2e-38 in float32) to zero on the CPU while training. Adam's
    second moment of a weight whose gradient has gone to zero (a dead ReLU unit) decays through
    the subnormal range, where x86 arithmetic is about 10x slower: without the flush, Adam took
    40 % of a real training run's time. No effect on the GPU; the values flushed are 30 orders
    of magnitude below the weights."""

    def __post_init__(self) -> None:
        if isinstance(self.hidden_sizes, list):
            object.__setattr__(self, "hidden_sizes", tuple(self.hidden_sizes))
        gate.check_fields(self, VALID, "agent configuration", COMBINATIONS)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready values (enums as strings, tuples as lists)."""
        return {f.name: v.value if isinstance(v := getattr(self, f.name), enum.Enum)
                else list(v) if isinstance(v, tuple) else v for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> AgentConfig:
        gate.known_fields(cls, d, "agent configuration")
        return cls(**d)


MAX_ENSEMBLE = 64
"""Most members of a regional ensemble: each acts on every input to be routed (M x the acting
cost) and needs goals in its cell; 64 is far beyond what the task's budget feeds."""

VALID: dict[str, gate.Kind] = gate.kinds(
    (gate.number(0, 1), "gamma", "ou_theta", "per_alpha", "per_beta"),
    (gate.number(0, 1, above=True), "tau", "batch_norm_momentum"),
    (gate.number(0, above=True), "actor_lr", "critic_lr", "final_init", "norm_eps",
     "sac_init_alpha", "sac_alpha_lr", "per_eps"),
    (gate.number(0), "critic_l2", "td3_target_noise", "td3_target_noise_clip"),
    (gate.number(0, above=True, finite=False, note="inf: no clipping"), "obs_clip"),
    (gate.integer(0), "episodes", "warmup_episodes", "updates_per_episode"),
    (gate.integer(1), "batch_size", "eval_every", "eval_episodes", "her_k", "td3_policy_delay",
     "buffer_size"),
    (gate.integer(1, MAX_ENSEMBLE), "ensemble"),
    (gate.FLAG, "normalize_obs", "flush_denormals", "batch_norm", "prioritized_replay"),
    (gate.choice(HERStrategy, HERStrategy), "her_strategy"),
    (gate.choice(Exploration, Exploration), "exploration"), (gate.choice(Algo, Algo), "algo"),
    (gate.Kind("two integers >= 1", lambda v: isinstance(v, tuple) and len(v) == 2
               and all(gate.is_integer(h) and h >= 1 for h in v), lambda v: tuple(map(int, v))),
     "hidden_sizes"),
    (gate.number(0), "exploration_rate"))
"""The type and range of each `AgentConfig` field: the words appear in the error message and
in ``--help``."""

COMBINATIONS: tuple[gate.Combination, ...] = (
    ("exploration_rate", "a probability (<= 1) with --exploration epsilon",
     lambda c: c.exploration != Exploration.EPSILON or c.exploration_rate <= 1.0),
    ("buffer_size", "an integer >= batch_size", lambda c: c.buffer_size >= c.batch_size),
    ("prioritized_replay", "true only with algo ddpg, ensemble 1, no batch_norm",
     lambda c: not c.prioritized_replay or (c.algo is Algo.DDPG and c.ensemble == 1
                                            and not c.batch_norm)),
    ("ensemble", "a divisor of updates_per_episode",
     lambda c: c.updates_per_episode % c.ensemble == 0),
)
"""What `AgentConfig`'s fields may be combined with."""


BEFORE: dict[str, Any] = {"batch_norm": False, "batch_norm_momentum": 0.01, "algo": "ddpg",
                          "td3_target_noise": 0.2, "td3_target_noise_clip": 0.5,
                          "td3_policy_delay": 2, "sac_init_alpha": 1.0, "sac_alpha_lr": 3e-4,
                          "ensemble": 1, "prioritized_replay": False, "per_alpha": 0.6,
                          "per_beta": 0.4, "per_eps": 1e-6}
"""Fields added after run folders existed, with the value runs written before them had (for
fields of another algorithm than ddpg, unused, the default): a ``spec.json`` without the field
reads as this value (so such runs resume)."""


@cache
def field_docs(cls: type) -> dict[str, str]:
    """The attribute docstrings of a dataclass, {field name: text}, read from its source."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body  # type: ignore[attr-defined]
    docs = {}
    for node, nxt in itertools.pairwise(body):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(nxt, ast.Expr)
            and isinstance(nxt.value, ast.Constant)
            and isinstance(nxt.value.value, str)
        ):
            docs[node.target.id] = " ".join(inspect.cleandoc(nxt.value.value).split())
    return docs
