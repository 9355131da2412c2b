"""The minimax expert as teacher: behaviour cloning and DAgger into an SB3 policy network.

The environments' states do not depend on the actions (the trajectory is fixed; only a slip
can end an episode early), so learning the grip is, at heart, supervised regression of the
expert's map observation -> k* / k_max. This module does it at scale on the batched vector
environment:

1. Round 0, behaviour cloning: the expert drives; every state it visits is stored with its
   action.
2. Rounds 1, 2, ..., DAgger (Ross, Gordon and Bagnell 2011): the learner drives, the expert
   labels the states the learner visits, and the data set grows. Where slips end episodes
   this focuses the data on the states the learner actually reaches.
3. After each round the policy's mean action (the deterministic action SB3 plays) is fitted to
   the labels by mean squared error, Adam, a one-epoch learning-rate warm-up then cosine
   decay. Only the actor is trained; its log std (the exploration noise PPO starts from) is
   left as configured. An epoch whose mean loss spikes (5% above the fit's best epoch) marks
   a collapse under way: the fit goes back to the best epoch's weights and Adam state and
   halves its learning rate (docs/rl.md, "The main job in five minutes").
4. A round whose fit leaves the policy worse on a fixed validation set (every pose of scenes
   no training or held-out seed draws; the measure is the mean largest friction angle the
   policy's grip gives there, no label needed) is undone: the policy goes back to the
   weights it had before that fit (its data stay for the next rounds). Later fits on a
   trained network now and then drop a few per cent of states into a basin where the
   force-direction head lets a finger's force nearly vanish (seed 4 of the README's runs:
   0.22 -> 1.19 deg mean gap in its last round, worst 112 deg); the check keeps such a fit out.

Imitating k* is a proxy: what counts is the largest friction angle the action gives, which
near the optimum grows linearly with the error in k (a max of angles has a kink there). The
observation holds the whole grasp, so that angle is a differentiable function of the action
(eqs. 2 and 4, :func:`grasp_env_agents.learning.features.max_friction_angle`); with
``gap_weight`` > 0
the loss adds it, in radians: label_weight x mean squared error + gap_weight x mean
max_i theta_i. Its gradient is the exact gradient of the environment's reward.

With ``label_weight`` 0 the fit learns from that reward alone and no expert is made or
called: every round the learner drives and its states are stored without labels. Where slips
do not end episodes (``terminate_on_slip: false``) the states are every pose of the scenes'
trajectories whoever drives, so this is the main job without a teacher (docs/rl.md, "The
reward's exact gradient").

The result is an ordinary SB3 PPO model that PPO can fine-tune.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecNormalize

from grasp_env import MinimaxExpert
from grasp_env.envs.observation import ObservationLayout

from ..progress import say, status
from ..run.config import ImitationConfig
from .envs import action_scale
from .features import grasp_tensors, max_friction_angle

#: Final learning rate of each round's cosine decay, as a fraction of the initial one.
LR_FLOOR = 0.01
#: Epochs over which each round's learning rate ramps up linearly, from WARMUP_START of it.
WARMUP_EPOCHS = 1
WARMUP_START = 1e-3
#: Gradient-norm clip of the fit's Adam steps.
MAX_GRAD_NORM = 1.0
#: An epoch's mean loss this much (relative) above the fit's best is a spike: the fit goes back
#: to the best epoch's weights and halves its learning rate.
SPIKE = 0.05
#: States of the validation set, and the seed of its scenes (held-out evaluations draw from
#: 1,000,000 on, training collectors from the run's seed).
VALIDATION_STATES = 20_000
VALIDATION_SEED = 2_000_000
#: Observations per batch when computing features or the grasp of a data set.
CHUNK = 65_536


@dataclass(frozen=True)
class RoundResult:
    """One round: how many labelled states the data set holds, the final training loss, and the
    states the round added with their labels (what a resumed run needs to continue)."""

    round: int
    samples: int
    env_steps: int
    loss: float
    seconds: float
    observations: np.ndarray
    labels: np.ndarray
    validation_angle_deg: float
    kept: bool


def mean_action(policy: ActorCriticPolicy, obs: torch.Tensor) -> torch.Tensor:
    """The Gaussian policy's mean action (what ``predict(deterministic=True)`` plays, unclipped)."""
    features = policy.extract_features(obs, policy.pi_features_extractor)
    return policy.action_net(policy.mlp_extractor.forward_actor(features))


def grasp_of(obs: np.ndarray) -> tuple[torch.Tensor, ...]:
    """The world-frame F, interaction basis and normals of observations (B, size), in chunks."""
    layout = ObservationLayout.from_size(obs.shape[-1])
    parts = [
        grasp_tensors(torch.as_tensor(obs[i : i + CHUNK]), layout)[:3]
        for i in range(0, len(obs), CHUNK)
    ]
    return tuple(torch.cat(p) for p in zip(*parts, strict=True))


def make_teacher(envs: gym.vector.VectorEnv) -> MinimaxExpert:
    """The expert for ``envs``' environments (it needs their k_max / w, read from them)."""
    return MinimaxExpert(action_scale(envs))


class Validation:
    """The fixed validation set of step 4 (module docstring) and the policy's score on it.

    Its states are every pose of the trajectories of its scenes: episodes run past a slip while
    it is collected, so no expert is needed to drive (where the expert holds throughout, as on
    the expert-feasible scenes of the random environments, they are the states it would visit).
    """

    def __init__(self, env_id: str, env_kwargs: dict[str, Any], n_envs: int) -> None:
        kwargs = {**env_kwargs, "terminate_on_slip": False}
        collector = StateCollector(env_id, kwargs, n_envs, VALIDATION_SEED)
        shape = collector.envs.single_action_space.shape
        try:
            self.obs, _ = collector.collect(
                lambda obs: np.zeros((len(obs), *shape), dtype=np.float32), VALIDATION_STATES
            )
            self.k_max_ratio = action_scale(collector.envs)
        finally:
            collector.close()
        self.grasp = grasp_of(self.obs)

    def angle_deg(self, policy: ActorCriticPolicy, normalise: Callable[[Any], Any]) -> float:
        """The mean over the set of the largest friction angle of the policy's grip (deg)."""
        with torch.no_grad():
            obs = torch.as_tensor(normalise(self.obs), dtype=torch.float32)
            angles = [
                max_friction_angle(
                    mean_action(policy, obs[i : i + CHUNK]),
                    *(a[i : i + CHUNK] for a in self.grasp),
                    self.k_max_ratio,
                )
                for i in range(0, len(obs), CHUNK)
            ]
        return math.degrees(float(torch.cat(angles).double().mean()))


class StateCollector:
    """Drives a batched vector environment and returns the states where actions were taken.

    With the NEXT_STEP autoreset of Gymnasium's vector envs, the step after an episode ends
    only resets that environment, so the final observation it returned is not a state anyone
    acts in: it is left out.
    """

    def __init__(self, env_id: str, env_kwargs: dict[str, Any], n_envs: int, seed: int) -> None:
        self.envs = gym.make_vec(
            env_id, num_envs=n_envs, vectorization_mode="vector_entry_point", **env_kwargs
        )
        self.next_step_reset = (
            self.envs.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP)
            == AutoresetMode.NEXT_STEP
        )
        self.obs, _ = self.envs.reset(seed=seed)
        self.pending = np.zeros(n_envs, dtype=bool)
        self.env_steps = 0

    def collect(
        self, act: Callable[[np.ndarray], np.ndarray], samples: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """``samples`` (observation, action played) pairs with ``act`` driving (batched)."""
        observations, actions, count = [], [], 0
        while count < samples:
            valid = ~self.pending if self.next_step_reset else np.ones_like(self.pending)
            action = act(self.obs)
            observations.append(self.obs[valid])
            actions.append(action[valid])
            count += int(valid.sum())
            self.obs, _, terminated, truncated, _ = self.envs.step(action)
            self.env_steps += int(valid.sum())
            self.pending = terminated | truncated
        return np.concatenate(observations)[:samples], np.concatenate(actions)[:samples]

    def close(self) -> None:
        self.envs.close()


def fit(
    policy: ActorCriticPolicy,
    obs: np.ndarray,
    labels: np.ndarray,
    epochs: int,
    batch_size: int,
    learning_rate: float,
    generator: torch.Generator,
    grasp: tuple[torch.Tensor, ...] | None = None,
    gap_weight: float = 0.0,
    k_max_ratio: float | None = None,
    label_weight: float = 1.0,
) -> float:
    """Fit the policy's mean action on ``obs``; returns the last epoch's mean loss.

    The loss is ``label_weight`` x the mean squared error to ``labels``, plus ``gap_weight`` x
    the mean max friction angle (radians) if ``grasp`` (from :func:`grasp_of`) is given. With
    ``label_weight`` 0 the labels are not read (they may have no columns). ``k_max_ratio``
    (the environment's k_max / w, :func:`~.envs.action_scale`) scales the actions of the gap
    term.
    """
    if label_weight == 0 and (grasp is None or gap_weight == 0):
        raise ValueError("fit has nothing to fit: label_weight and gap_weight are both 0")
    if grasp is not None and gap_weight > 0 and k_max_ratio is None:
        raise ValueError("fit with a gap term needs k_max_ratio, the environment's k_max / w")
    extractor = policy.pi_features_extractor
    if any(True for _ in extractor.parameters()):
        raise ValueError("fit needs a parameter-free features extractor (flatten or grasp)")
    with torch.no_grad():  # so the features are computed once, not every epoch
        obs_t = torch.as_tensor(obs, dtype=torch.float32)
        inputs = torch.cat([extractor(obs_t[i : i + CHUNK]) for i in range(0, len(obs), CHUNK)])
    labels_t = torch.as_tensor(labels, dtype=torch.float32)
    actor = [*policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters()]
    optimizer = torch.optim.Adam(actor, lr=learning_rate)
    batches = math.ceil(len(inputs) / batch_size)
    # a fresh Adam's first steps move every weight by about the learning rate whatever its
    # gradient: from a trained network (a DAgger round) that threw 2 of 5 seeds into a basin
    # where 3% of states get a near-released finger (gap 2 deg, worst 107 deg); a ramp lets
    # Adam's moment estimates settle first
    warmup = min(WARMUP_EPOCHS, epochs - 1) * batches
    decay = epochs * batches - warmup
    scale = 1.0  # halved at each rollback

    def rate(step: int) -> float:
        """The learning rate's factor: the linear ramp, then the cosine decay to LR_FLOOR."""
        if step < warmup:
            return scale * (WARMUP_START + (1.0 - WARMUP_START) * step / warmup)
        cosine = 0.5 * (1.0 + math.cos(math.pi * min(step - warmup, decay) / decay))
        return scale * (LR_FLOOR + (1.0 - LR_FLOOR) * cosine)

    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, rate)
    policy.set_training_mode(True)
    best, kept, epoch_loss = math.inf, None, math.inf
    with status(f"fitting the policy on {len(inputs):,} states") as detail:
        for epoch in range(epochs):
            detail(f"epoch {epoch + 1}/{epochs}")
            order = torch.randperm(len(inputs), generator=generator)
            loss_sum = 0.0
            for start in range(0, len(inputs), batch_size):
                index = order[start : start + batch_size]
                action = policy.action_net(policy.mlp_extractor.forward_actor(inputs[index]))
                loss = torch.zeros(())
                if label_weight > 0:
                    loss = label_weight * torch.nn.functional.mse_loss(action, labels_t[index])
                if grasp is not None and gap_weight > 0:
                    angle = max_friction_angle(action, *(a[index] for a in grasp), k_max_ratio)
                    loss = loss + gap_weight * angle.mean()
                optimizer.zero_grad()
                loss.backward()
                # the angle's gradient is huge where a finger's force nearly vanishes: one such
                # batch must not throw Adam off (unclipped, a run at lr 1e-2 collapsed)
                torch.nn.utils.clip_grad_norm_(actor, MAX_GRAD_NORM)
                optimizer.step()
                schedule.step()
                loss_sum += float(loss.detach()) * len(index)
            # A loss spike is a collapse under way (Adam's steps at a large rate can push every
            # unit of the last layer into SiLU's flat negative tail: one grip for every state,
            # and no gradient back); go back to the best epoch's weights at half the rate.
            epoch_loss = loss_sum / len(inputs)
            if epoch_loss > best * (1.0 + SPIKE) and kept is not None:
                policy.load_state_dict(kept[0])
                optimizer.load_state_dict(kept[1])
                scale /= 2.0
                say(
                    f"fit: epoch {epoch + 1}'s loss {epoch_loss:.4g} spiked above the best"
                    f" {best:.4g}: back to that epoch's weights, at half the learning rate"
                )
                epoch_loss = best  # the loss of the weights the fit now holds
            elif epoch_loss < best:
                best = epoch_loss
                kept = (copy.deepcopy(policy.state_dict()), copy.deepcopy(optimizer.state_dict()))
    policy.set_training_mode(False)
    return epoch_loss


def imitate(
    policy: ActorCriticPolicy,
    config: ImitationConfig,
    env_id: str,
    env_kwargs: dict[str, Any],
    seed: int,
    normalizer: VecNormalize | None = None,
    after_round: Callable[[RoundResult], None] | None = None,
    done: list[tuple[np.ndarray, np.ndarray]] | None = None,
    env_steps: int = 0,
) -> list[RoundResult]:
    """Behaviour cloning then DAgger rounds (see the module docstring) into ``policy``.

    Args:
        policy: the SB3 actor-critic policy to train in place.
        config: rounds, samples, epochs, batch size, learning rate, collector envs.
        env_id, env_kwargs: the environment (it must have a batched vector entry point).
        seed: seeds the collector's environments and the minibatch order.
        normalizer: the training run's VecNormalize, if observations are normalised: its
            statistics are updated with the collected states and applied to them.
        after_round: called after each round (to evaluate, log and checkpoint).
        done, env_steps: to continue a run: the (observations, labels) of the rounds it has
            completed, and the environment steps they took. The collector then draws fresh
            scenes (seeds shifted by the rounds done), so a continued run is not bit-for-bit
            an uninterrupted one.
    """
    done = done or []
    # with label_weight 0 the fit learns from the reward alone: no expert is made or called
    collector = StateCollector(env_id, env_kwargs, config.n_envs, seed + len(done) * config.n_envs)
    teacher = make_teacher(collector.envs) if config.label_weight > 0 else None
    k_max_ratio = action_scale(collector.envs)
    collector.env_steps = env_steps
    generator = torch.Generator().manual_seed(seed + len(done))

    def normalise(obs: np.ndarray) -> np.ndarray:
        return obs if normalizer is None else normalizer.normalize_obs(obs)

    def learner(obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            mean = mean_action(policy, torch.as_tensor(normalise(obs), dtype=torch.float32))
        return np.clip(mean.numpy(), -1.0, 1.0)

    data_obs = [obs for obs, _ in done]
    data_labels = [labels for _, labels in done]
    data_grasp = [grasp_of(obs) for obs in data_obs] if config.gap_weight > 0 else []
    results = []
    validation = Validation(env_id, env_kwargs, config.n_envs)
    # a resumed run's policy is the one its last round kept
    best = validation.angle_deg(policy, normalise) if done else math.inf
    try:
        for round_ in range(len(done), config.rounds):
            start = time.perf_counter()
            if teacher is None:
                driver = "the learner drives (no expert)"
            elif round_ == 0:
                driver = "the expert drives"
            else:
                driver = "the learner drives, the expert labels"
            with status(f"imitation round {round_}: {config.samples_per_round:,} states, {driver}"):
                if teacher is None:  # the reward alone: states, no labels
                    obs, _ = collector.collect(learner, config.samples_per_round)
                    labels = np.zeros((len(obs), 0), dtype=np.float32)
                elif round_ == 0:  # behaviour cloning: the expert drives and labels
                    obs, labels = collector.collect(teacher.actions, config.samples_per_round)
                else:  # DAgger: the learner drives, the expert labels what it visits
                    obs, _ = collector.collect(learner, config.samples_per_round)
                    labels = teacher.actions(obs)
            if normalizer is not None:
                normalizer.obs_rms.update(obs)
            data_obs.append(obs)
            data_labels.append(labels)
            if config.gap_weight > 0:
                data_grasp.append(grasp_of(obs))
            all_obs = normalise(np.concatenate(data_obs))
            before = copy.deepcopy(policy.state_dict())
            loss = fit(
                policy,
                all_obs,
                np.concatenate(data_labels),
                config.epochs,
                config.batch_size,
                config.learning_rate,
                generator,
                [torch.cat(a) for a in zip(*data_grasp, strict=True)] if data_grasp else None,
                config.gap_weight,
                k_max_ratio,
                config.label_weight,
            )
            angle = validation.angle_deg(policy, normalise)
            kept = angle <= best
            if kept:
                best = angle
            else:
                policy.load_state_dict(before)
            result = RoundResult(
                round_,
                len(all_obs),
                collector.env_steps,
                loss,
                time.perf_counter() - start,
                obs,
                labels,
                angle,
                kept,
            )
            results.append(result)
            if after_round is not None:
                after_round(result)
    finally:
        collector.close()
    return results
