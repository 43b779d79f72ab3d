"""`SkillRetPolicy`: the skill VAE and the latent policy as one LeRobot policy, trained in two `lerobot-train` runs.

Stage `skills` (Algorithm 1): `--dataset.*` is the prior (play) dataset. A batch of B windows trains the skill VAE
as B/2 temporal pairs: the first half of the batch's windows and each one's pair, which the policy fetches itself
(same episode, d steps away). Every window is encoded for the temporal term anyway, so each is also reconstructed:
1.2-1.4x the windows per second of training B windows and B encoder-only pairs (configs/README.md). The latent
policy is frozen.
Stage `policy` (Algorithm 2): `--policy.path=<stage-1 pretrained_model>`, `--dataset.*` is the target dataset.
One forward computes the latent-policy loss on target windows (id 0) and on retrieved prior windows (id 1, read from
`retrieval_path`), plus the skill loss on target and prior windows (fine-tuning, line 17).

Inputs arrive RAW: the model normalises with statistics it owns as buffers (see `normalization.py`), so the
processor's normaliser steps are identities and `--policy.path` cannot rescale the pre-trained decoder's actions.

No `from __future__ import annotations` here: LeRobot resolves the policy's config class from the runtime annotation
of `__init__`'s `config` parameter, which must stay a class, not a string.
"""

import logging
import warnings
from collections import deque
from collections.abc import Mapping
from pathlib import Path
from types import EllipsisType
from typing import TYPE_CHECKING

import torch
from huggingface_hub import ModelCard
from lerobot.configs.types import FeatureType
from lerobot.policies.pretrained import PreTrainedPolicy, resolve_safetensors_device
from lerobot.utils.constants import ACTION
from safetensors import SafetensorError, safe_open
from safetensors.torch import load_file
from torch import Tensor

from lerobot_skillret.files import read_json
from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
from lerobot_skillret.policy.latent_policy import RETRIEVED_ID, TARGET_ID, LatentPolicy
from lerobot_skillret.policy.normalization import SkillNormalizer
from lerobot_skillret.policy.relative_positions import relative_stats, to_relative
from lerobot_skillret.policy.skills import SkillModel, make_observation_encoder, valid_step_mean

if TYPE_CHECKING:
    from lerobot_skillret.data.windows import EpisodeColumns
    from lerobot_skillret.policy.training_data import TrainingData
    from lerobot_skillret.policy.window_source import WindowSource

Batch = Mapping[str, Tensor]
# normalised units (standard deviations of the stage-1 data for MEAN_STD features) past which a target observation
# counts as outside everything the skills were trained on
OUTSIDE_SKILLS_RANGE = 10.0


def first_half(batch: Batch) -> Batch:
    """The first ceil(B/2) windows of a batch (tensors and per-sample lists alike): a stage-1 step's anchors, whose
    temporal pairs make up the other half of its B windows."""
    size = (len(batch["index"].reshape(-1)) + 1) // 2
    return {key: value[:size] if isinstance(value, Tensor | list) else value for key, value in batch.items()}


class SkillRetPolicy(PreTrainedPolicy):
    """Skill-based imitation with retrieval from prior data (the `skillret` policy type)."""

    config_class = SkillRetConfig
    name = "skillret"

    def __init__(
        self,
        config: SkillRetConfig,
        dataset_stats: dict[str, dict[str, Tensor]] | None = None,
        dataset_meta: object | None = None,
        **kwargs: object,
    ) -> None:
        """`dataset_stats` set the normalisation buffers (loading a checkpoint then overwrites them with the
        stage-1 ones); `dataset_meta` (LeRobotDatasetMetadata, given by lerobot-train) locates the training
        dataset on disk for the windows the policy fetches itself."""
        super().__init__(config)
        config.validate_features()
        self.config = config
        features = config.input_features
        self.low_dim_keys = sorted(k for k, f in features.items() if f.type in (FeatureType.STATE, FeatureType.ENV))
        self.image_keys = sorted(k for k, f in features.items() if f.type is FeatureType.VISUAL)
        self.observation_keys = [*self.low_dim_keys, *self.image_keys]
        low_dim_shapes = {k: features[k].shape for k in self.low_dim_keys}
        image_shapes = {k: features[k].shape for k in self.image_keys}
        action_dim = int(config.action_feature.shape[0])

        if dataset_stats is not None:
            dataset_stats = relative_stats(dataset_stats, config.relative_positions)
        self.normalizer = SkillNormalizer(
            {**features, **config.output_features},
            config.skill_normalization_mapping,
            dataset_stats,
            min_max_margin=config.min_max_margin,
        )
        self.skills = SkillModel(config, low_dim_shapes, image_shapes, action_dim)
        self.latent_policy = LatentPolicy(config, make_observation_encoder(config, low_dim_shapes, image_shapes))
        self.dataset_location = (
            (str(dataset_meta.repo_id), Path(dataset_meta.root)) if dataset_meta is not None else None
        )
        self._training_data = None  # built on the first training forward; never part of the state_dict
        self._freeze_for_stage()
        self.reset()

    # --- optimisation -----------------------------------------------------------------------------------------

    def _freeze_for_stage(self) -> None:
        """Stage 1 trains the skill model only; stage 2 the policy, plus the skills if `finetune_skills`."""
        self.latent_policy.requires_grad_(self.config.stage == "policy")
        self.skills.requires_grad_(self.config.stage == "skills" or self.config.finetune_skills)

    def get_optim_params(self) -> list[dict]:
        """Three Adam groups (Table 7): skill VAE at skill_lr, temporal predictor at tc_lr, policy at policy_lr."""
        groups = [
            (self.skills.skill_parameters(), self.config.skill_lr),
            (list(self.skills.temporal.parameters()), self.config.tc_lr),
            (list(self.latent_policy.parameters()), self.config.policy_lr),
        ]
        return [
            {"params": trainable, "lr": lr}
            for params, lr in groups
            if (trainable := [p for p in params if p.requires_grad])
        ]

    # --- inputs -----------------------------------------------------------------------------------------------

    def _observations(self, raw: Batch, steps: slice | EllipsisType) -> dict[str, Tensor]:
        """Normalised observation tensors of `raw` at time `steps` of (B, T, ...) (`...`: no time axis)."""
        device = self._device()
        missing = [key for key in self.observation_keys if key not in raw]
        hint = " (lerobot-eval: give the env the policy's cameras and size, --env.cameras=[...] --env.image_size=...)"
        if missing:
            raise KeyError(
                f"skillret needs observation key(s) {missing}; the batch has {sorted(raw)}"
                + (hint if any(key in self.image_keys for key in missing) else "")
                + "."
            )
        for key in self.observation_keys:
            shape = tuple(self.config.input_features[key].shape)
            if tuple(raw[key].shape[-len(shape) :]) != shape:
                raise ValueError(
                    f"skillret was trained on `{key}` of shape {shape}; got {tuple(raw[key].shape)}"
                    + (hint if key in self.image_keys else "")
                    + "."
                )
        return self._model_inputs(
            {key: raw[key][(slice(None), steps)].to(device, torch.float32) for key in self.observation_keys}
        )

    def _model_inputs(self, observation: dict[str, Tensor]) -> dict[str, Tensor]:
        """RAW float observations -> what every module sees: relative positions (if configured), normalised."""
        observation = to_relative(observation, self.config.relative_positions)
        return {key: self.normalizer.normalize(key, value) for key, value in observation.items()}

    def low_dim_features(self, raw: Batch) -> Tensor:
        """RAW low-dimensional observations (N, ...) as the modules see them, concatenated into (N, D): the model's
        units for a distance between two states."""
        observation = {key: raw[key].to(self._device(), torch.float32) for key in self.low_dim_keys}
        return torch.cat(list(self._model_inputs(observation).values()), dim=-1)

    def _window(self, raw: Batch) -> dict[str, Tensor]:
        """The last H steps of a raw window, normalised, with `valid` = not padded past the episode's end.

        With a tanh decoder (MIN_MAX actions) normalised actions are clipped to [-1, 1], its range (target data may
        exceed the prior's range)."""
        horizon = self.config.horizon
        actions = raw[ACTION].to(self._device(), torch.float32)
        if actions.ndim != 3 or actions.shape[1] != horizon:
            raise ValueError(f"skillret expects `action` windows (B, H={horizon}, A); got {tuple(actions.shape)}.")
        window = self._observations(raw, slice(-horizon, None))
        window[ACTION] = self.normalizer.normalize(ACTION, actions)
        if self.config.bounded_actions:
            window[ACTION] = window[ACTION].clamp(-1.0, 1.0)
        pad = raw.get(f"{ACTION}_is_pad")
        window["valid"] = (
            ~pad.to(self._device(), torch.bool)
            if pad is not None
            else torch.ones(actions.shape[:2], dtype=torch.bool, device=self._device())
        )
        return window

    def _history(self, raw: Batch) -> dict[str, Tensor]:
        """The F observations ending at the anchor, from a window with steps -(F-1)..H-1."""
        history, horizon = self.config.history, self.config.horizon
        steps = raw[self.observation_keys[0]].shape[1]
        if steps != history + horizon - 1:
            raise ValueError(
                f"stage `policy` needs observation windows of F+H-1={history + horizon - 1} steps (deltas "
                f"-(F-1)..H-1); got {steps}. Use the config's observation_delta_indices with --policy.stage=policy."
            )
        return self._observations(raw, slice(0, history))

    def _noisy_history(self, raw: Batch) -> dict[str, Tensor]:
        """The policy's training input: `_history`, its low-dim steps perturbed by `policy_obs_noise` (in
        normalised units) so that states just off the demonstrations are seen too."""
        history = self._history(raw)
        if self.config.policy_obs_noise > 0:
            for key in self.low_dim_keys:
                history[key] = history[key] + self.config.policy_obs_noise * torch.randn_like(history[key])
        return history

    def _device(self) -> torch.device:
        return self.normalizer.device_marker.device

    # --- training ---------------------------------------------------------------------------------------------

    def forward(self, batch: dict[str, Tensor], reduction: str = "mean") -> tuple[Tensor, dict[str, float]]:
        """One training step's loss and its terms (Python floats), for the configured stage.

        `reduction="none"` is what lerobot-train asks for with `--sample_weighting`; skillret's loss mixes the
        batch's windows with prior and retrieved windows the policy draws itself, so it has no per-sample form."""
        if reduction != "mean":
            raise ValueError(
                f"skillret computes one loss per batch (reduction='mean'), not reduction={reduction!r}: its loss mixes "
                "the batch's target windows with prior and retrieved windows. Train without --sample_weighting; "
                "the retrieved windows' weight is --policy.retrieved_weight."
            )
        self.normalizer.check_ready()
        if "index" not in batch:
            raise KeyError(
                "skillret training batches need `index` (each window's global frame index, as LeRobotDataset "
                "gives it): the temporal pair of every window is located from it."
            )
        data = self._data(batch["index"].reshape(-1))
        if self.config.stage == "skills":  # the anchors; their temporal pairs are the batch's other half
            batch = first_half(batch)
        if self.config.fast_windows:  # LeRobot gave anchor frames only: gather their windows (same pads)
            batch = data.own.gather(batch["index"].reshape(-1), self._device())
        if self.config.stage == "skills":
            loss, terms, _ = self._skill_loss([(batch, data.own)], decode_pairs=True)
            return loss, {name: float(value) for name, value in terms.items()}
        return self._stage2_loss(batch, data)

    def _data(self, anchors: Tensor) -> "TrainingData":
        """The extra window sources, built on the first training batch (whose `anchors` the data-parallel check
        logs)."""
        from lerobot_skillret.policy.training_data import TrainingData

        if self._training_data is None:
            keys = (self.low_dim_keys, self.image_keys)
            self._training_data = TrainingData.build(self.config, self.dataset_location, keys)
            self._training_data.check_ranks(anchors)
            if self.config.stage == "policy":
                self.warn_outside_skills_range(self._training_data.own.columns, self.dataset_location[1])
        return self._training_data

    def warn_outside_skills_range(self, target: "EpisodeColumns", root: Path) -> list[str]:
        """Log the observation dimensions of the target dataset (its `columns`, at `root`) that lie more than
        OUTSIDE_SKILLS_RANGE normalised units outside the stage-1 data; returns them, largest first. Stage 2 and
        `skillret-retrieve` call it.

        Why: the skills and the retrieval latents were never trained on such inputs, and nothing else fails. A
        prior that lacks the target's scenes, or one generated by another simulator version, shows here first
        (the bread that spun on the plate read 100 standard deviations out, and the prior's skills completed 0 %)."""
        with torch.no_grad():
            inputs = self.low_dim_features({key: target.td[key] for key in self.low_dim_keys})
        extreme = inputs.abs().amax(dim=0)
        outside = sorted(
            torch.nonzero(extreme > OUTSIDE_SKILLS_RANGE).flatten().tolist(), key=lambda i: -float(extreme[i])
        )
        if not outside:
            return []
        names = self._low_dim_names(root)
        listed = [f"{names[i]} ({float(extreme[i]):.0f})" for i in outside]
        logging.warning(
            "skillret: %d target observation dimension(s) reach more than %.0f normalised units of the skills' "
            "training data, largest first: %s. The skills never saw such inputs: check that the prior data holds "
            "the target's scenes and objects, and that both come from the same simulator version.",
            len(listed),
            OUTSIDE_SKILLS_RANGE,
            ", ".join(listed[:6]) + (", ..." if len(listed) > 6 else ""),
        )
        return listed

    def _low_dim_names(self, root: Path) -> list[str]:
        """A name per column of `low_dim_features`: the feature names of the dataset at `root` where it has them."""
        info = read_json(Path(root) / "meta" / "info.json")["features"]
        names = []
        for key in self.low_dim_keys:
            given = info.get(key, {}).get("names")
            width = int(self.config.input_features[key].shape[0])
            names += given if isinstance(given, list) and len(given) == width else [f"{key}[{i}]" for i in range(width)]
        return names

    def _skill_loss(
        self, sources: list[tuple[Batch, "WindowSource"]], decode_pairs: bool = False, stage2: bool = False
    ) -> tuple[Tensor, dict[str, Tensor], Tensor]:
        """Algorithm 1's loss over the windows of several (raw batch, its WindowSource) pairs at once.

        Each source supplies the temporal pair of its own windows (same episode); `decode_pairs` trains the pairs
        as windows too (`SkillModel.loss`). `stage2`: the first source is the target's, whose reconstruction and KL
        are reported alone too. Returns the loss, its detached terms, and the encoder means of the sources' windows (in
        order, pairs excluded), used as stage-2 labels."""
        config, device = self.config, self._device()
        windows, pairs, offsets, slow = [], [], [], []
        for raw, source in sources:
            windows.append(self._window(raw))
            anchors = raw["index"].reshape(-1)
            pair, offset = source.pair(anchors, config.tc_max_offset, device)
            pairs.append(self._window(pair))
            offsets.append(offset)
            if config.slowness_weight > 0:
                slow_pair, _ = source.pair(anchors, config.slowness_max_offset, device)
                slow.append(self._window(slow_pair))

        def join(parts: list[dict[str, Tensor]]) -> dict[str, Tensor] | None:
            return {key: torch.cat([p[key] for p in parts]) for key in parts[0]} if parts else None

        target_windows = len(windows[0][ACTION]) if stage2 else None
        loss, terms, means = self.skills.loss(
            join(windows), join(pairs), torch.cat(offsets), join(slow), decode_pairs, target_windows
        )
        return loss, {name: value.detach() for name, value in terms.items()}, means

    def _stage2_loss(self, batch: Batch, data: "TrainingData") -> tuple[Tensor, dict[str, float]]:
        """L_policy on target (id 0) and retrieved (id 1) windows, + L_skill on target and prior (or retrieved)
        windows."""
        config, device = self.config, self._device()
        size = batch[ACTION].shape[0]
        terms: dict[str, Tensor] = {}
        loss = torch.zeros((), device=device)

        if config.finetune_skills:
            sources = [(batch, data.own)]
            if data.prior is not None:
                if config.skill_finetune_windows == "retrieved":  # refused without retrieved windows
                    sources.append((data.retrieved.sample(size, device)[0], data.prior))
                else:
                    sources.append((data.prior.sample(size, device), data.prior))
            skill_loss, skill_terms, means = self._skill_loss(sources, stage2=True)
            labels = means[:size].detach()
            loss = loss + skill_loss
            terms.update(skill_terms)
        else:
            with torch.no_grad():
                labels, _ = self.skills.encoder(self._window(batch))

        target_ids = torch.full((size,), TARGET_ID, dtype=torch.long, device=device)
        target_labels = self._policy_labels(batch, data.own, labels)
        policy_loss, predicted = self.latent_policy.loss(self._noisy_history(batch), target_ids, *target_labels)
        policy_loss = policy_loss.mean()
        terms["policy_target_loss"] = policy_loss.detach()
        if config.policy_action_weight > 0:  # decoded like `imitation_error`; also trains a fine-tuned decoder
            action_loss = self.skills.window_error(predicted, self._window(batch)).mean()
            policy_loss = policy_loss + config.policy_action_weight * action_loss
            terms["policy_action_loss"] = action_loss.detach()
        if config.decoder_policy_weight > 0:  # the decoder learns to execute the policy's choices; the policy does not
            decoder_loss = self.skills.window_error(predicted.detach(), self._window(batch)).mean()
            loss = loss + config.decoder_policy_weight * decoder_loss
            terms["decoder_policy_loss"] = decoder_loss.detach()

        if data.retrieved is not None:
            retrieved, stored = data.retrieved.sample(size, device)
            if config.retrieved_latents == "stored":
                retrieved_labels = stored
            else:
                with torch.no_grad():
                    retrieved_labels, _ = self.skills.encoder(self._window(retrieved))
            retrieved_ids = torch.full((size,), RETRIEVED_ID, dtype=torch.long, device=device)
            retrieved_labels = self._policy_labels(retrieved, data.retrieved.source, retrieved_labels)
            retrieved_loss, _ = self.latent_policy.loss(
                self._noisy_history(retrieved), retrieved_ids, *retrieved_labels
            )
            retrieved_loss = retrieved_loss.mean()
            policy_loss = policy_loss + config.retrieved_weight * retrieved_loss
            terms["policy_retrieved_loss"] = retrieved_loss.detach()

        terms["policy_loss"] = policy_loss.detach()
        return loss + policy_loss, {name: float(value) for name, value in terms.items()}

    def _policy_labels(self, raw: Batch, source: "WindowSource", last: Tensor) -> tuple[Tensor, Tensor | None]:
        """The latent policy's labels for the history of `raw`: the anchor's skills `last` (B, latent), or with
        `policy_supervision="every_step"` (B, F, latent) with a valid mask (B, F): history step t is labelled with
        the current encoder's mean of the window starting at t, the anchor's with `last`. Steps padded before the
        episode's start have no window of their own and are masked."""
        history = self.config.history
        if self.config.policy_supervision == "last" or history == 1:
            return last, None
        anchors = raw["index"].reshape(-1, 1).cpu()
        padded = raw[f"{self.observation_keys[0]}_is_pad"][:, :history].cpu().bool()
        starts = torch.where(padded, anchors, anchors + torch.arange(1 - history, 1))
        with torch.no_grad():
            means, _ = self.skills.encoder(self._window(source.gather(starts[:, :-1].reshape(-1), self._device())))
        labels = torch.cat([means.reshape(len(anchors), history - 1, -1), last[:, None]], dim=1)
        return labels, ~padded.to(self._device())

    # --- retrieval --------------------------------------------------------------------------------------------

    @torch.no_grad()
    def encode_skill(self, window: Mapping[str, Tensor]) -> tuple[Tensor, Tensor]:
        """Encoder (mean, log_var), each (B, latent_dim), of RAW windows as `WindowSampler.gather` returns them.

        Observation keys may hold F+H-1 or H steps (the last H are used), `action` (B, H, A); `action_is_pad`, if
        present, marks steps past the episode's end, which the encoder ignores. Uses the stage-1 statistics."""
        self.normalizer.check_ready()
        mean, log_var = self.skills.encoder(self._window(window))
        return mean, log_var

    @torch.no_grad()
    def imitation_error(self, window: Mapping[str, Tensor]) -> dict[str, Tensor]:
        """Per-window action error, (B,), of RAW stage-2 windows (F+H-1 observation steps, H actions) of a dataset.

        `policy`: the latent policy's skill (dataset id = target, as at rollout), decoded closed-loop along the
        window's own observations; `oracle`: the encoder's skill of the window itself, the best any policy over this
        decoder can do; `shuffled`: the oracle skill of another window of the batch (a fixed permutation), how much
        the decoder's actions hang on the skill at all (a decoder that acts from the observation alone scores its
        oracle error here); `mean_action`: the windows' mean action held constant, the scale of the others (each
        checkpoint's own action statistics set its units, so compare errors across checkpoints as ratios to it).
        Squared error summed over action dimensions in the decoder's normalised units, averaged over the valid
        steps. On held-out demonstrations it compares checkpoints without the noise of a few rollouts."""
        self.normalizer.check_ready()
        target = self._window(window)
        size = target[ACTION].shape[0]
        oracle = self.skills.encoder(target)[0]
        permutation = torch.randperm(size, generator=torch.Generator().manual_seed(0)).to(oracle.device)
        skills = {
            "policy": self.latent_policy(self._history(window), torch.full((size,), TARGET_ID, device=self._device())),
            "oracle": oracle,
            "shuffled": oracle[permutation],
        }
        errors = {name: self.skills.window_error(z, target) for name, z in skills.items()}
        actions, valid = target[ACTION], target["valid"]
        errors["mean_action"] = valid_step_mean((actions - actions[valid].mean(dim=0)).pow(2).sum(dim=-1), valid)
        return errors

    # --- inference --------------------------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget the observation history and the running skill (call at every episode start)."""
        self._history_frames: deque[dict[str, Tensor]] = deque(maxlen=self.config.history)
        self._skill: Tensor | None = None
        self._decoder_state: list[tuple[Tensor, Tensor]] | None = None
        self._steps_left = 0

    def _push_observation(self, batch: Batch) -> dict[str, Tensor]:
        """Normalise the current observation (B, ...) and append it to the F-frame history.

        After `reset()` the first observation fills the whole history: the training windows were padded the
        same way at an episode's start (LeRobot repeats its first frame)."""
        frame = self._observations(batch, ...)
        if not self._history_frames:
            self._history_frames.extend([frame] * self.config.history)
        else:
            self._history_frames.append(frame)
        return frame

    def _stacked_history(self) -> dict[str, Tensor]:
        return {key: torch.stack([f[key] for f in self._history_frames], dim=1) for key in self.observation_keys}

    def _choose_skill(self) -> Tensor:
        if self.config.stage == "skills":
            warnings.warn(
                "skillret: this is a stage-1 (skills) checkpoint, whose latent policy is untrained: its rollouts "
                "say nothing about the method. Evaluate a stage-2 checkpoint (lerobot-train --policy.stage=policy).",
                stacklevel=3,
            )
        history = self._stacked_history()
        size = history[self.observation_keys[0]].shape[0]
        ids = torch.full((size,), TARGET_ID, dtype=torch.long, device=self._device())
        return self.latent_policy(history, ids)

    def execute_skill(self, skill: Tensor) -> None:
        """Decode `skill` (B, latent_dim) over the next H `select_action` calls instead of the policy's choice.

        For diagnostics: executing oracle latents encoded from demonstrations separates the skill decoder's
        closed-loop fidelity from the latent policy's accuracy (see examples/oracle_skills.py)."""
        self._skill, self._decoder_state, self._steps_left = skill.to(self._device()), None, self.config.horizon

    @torch.inference_mode()
    def select_action(self, batch: dict[str, Tensor]) -> Tensor:
        """(B, A) unnormalised action. Every H steps (`skill_steps` if set) z = pi(history, id=target); in between,
        the closed-loop decoder runs one step on the current observation, its LSTM state carried across the skill."""
        if self.training:
            self.eval()
        frame = self._push_observation(batch)
        if self._steps_left == 0:
            self.normalizer.check_ready()
            self._skill = self._choose_skill()
            self._decoder_state = None
            self._steps_left = self.config.skill_steps or self.config.horizon
        action, self._decoder_state = self.skills.decoder.step(self._skill, frame, self._decoder_state)
        self._steps_left -= 1
        return self.normalizer.unnormalize(ACTION, action)

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor]) -> Tensor:
        """(B, H, A): the skill the policy picks now (history + this observation), decoded for H steps.

        The decoder is closed-loop and needs each step's observation, which a chunk cannot know in advance; the
        chunk therefore holds the current observation for all H steps (an open-loop preview). Rollouts use
        `select_action`, which feeds the real observations. The running history and skill are not modified."""
        self.eval()
        self.normalizer.check_ready()
        saved = (self._history_frames.copy(), self._skill, self._decoder_state, self._steps_left)
        try:
            frame = self._push_observation(batch)
            skill = self._choose_skill()
        finally:
            self._history_frames, self._skill, self._decoder_state, self._steps_left = saved
        repeated = {
            key: value[:, None].expand(-1, self.config.horizon, *value.shape[1:]) for key, value in frame.items()
        }
        actions, _ = self.skills.decoder(skill, repeated)
        return self.normalizer.unnormalize(ACTION, actions)

    # --- checkpoints ------------------------------------------------------------------------------------------

    @classmethod
    def _load_as_safetensor(
        cls, model: "SkillRetPolicy", model_file: str, map_location: str, strict: bool
    ) -> "SkillRetPolicy":
        """LeRobot's loader, with errors that name the file and the fix instead of a raw size mismatch or
        `SafetensorError` (a stage-2 dataset with another layout than the checkpoint's; a truncated file)."""
        saved = Path(model_file).parent / "config.json"
        stored = read_json(saved) if saved.is_file() else None
        _check_checkpoint_features(model.config, Path(model_file).parent, stored)
        try:
            if _stage1_policy_differs(model, model_file, stored):
                return _load_without_latent_policy(model, model_file, map_location)
            return super()._load_as_safetensor(model, model_file, map_location, strict)
        except SafetensorError as error:
            raise ValueError(
                f"Cannot read the weights {model_file}: {error}. The file is truncated or corrupt (a copy or a run "
                "killed while saving); use another checkpoint (checkpoints/<step>/pretrained_model) or re-train."
            ) from error

    # --- hub --------------------------------------------------------------------------------------------------

    def generate_model_card(
        self,
        dataset_repo_id: str,
        model_type: str,
        license: str | None,
        tags: list[str] | None,
        **context: object,
    ) -> ModelCard:
        """LeRobot's card (`context`: its train config and dataset metadata), listing the prior dataset too and
        saying what the method is."""
        datasets = [dataset_repo_id, *([self.config.prior_repo_id] if self.config.prior_repo_id else [])]
        card = super().generate_model_card(
            datasets if len(datasets) > 1 else dataset_repo_id,
            model_type,
            license,
            list({*(tags or []), "skill-learning", "retrieval", "imitation-learning"}),
            **context,
        )
        method = (
            "\n## Method: skill-based imitation with retrieval from prior data (skillret)\n\n"
            "A skill VAE (LSTM encoder, closed-loop LSTM decoder, learned prior, temporal-prediction loss) is "
            "pre-trained on prior windows (stage 1); prior windows whose skill latents lie closest to the target "
            f"dataset's are retrieved, and an LSTM policy over the last F={self.config.history} observations learns "
            "to predict skill latents on target and retrieved windows while the skill model is fine-tuned (stage 2). "
            f"At rollout the policy picks a skill every H={self.config.horizon} steps and the decoder executes it "
            "closed-loop.\n\n"
        )
        if self.config.stage == "skills":
            method += (
                f"This checkpoint is stage 1: skills pre-trained on the prior dataset (`{dataset_repo_id}`). Its "
                "latent policy is untrained: train stage 2 from it (`--policy.stage=policy`) before evaluating.\n"
            )
        else:
            method += (
                f"This checkpoint is stage 2 on the target dataset (`{dataset_repo_id}`), prior dataset "
                f"`{self.config.prior_repo_id or 'none (no prior data)'}`, retrieval file "
                f"`{self.config.retrieval_path or 'none'}` (retrieval {'on' if self.config.use_retrieval else 'off'}).\n"
            )
        return ModelCard(card.content + method)


def _check_checkpoint_features(config: SkillRetConfig, folder: Path, stored: dict | None) -> None:
    """Refuse to load weights trained on another observation/action layout than `config` describes (stage 2 on a
    target dataset whose features differ from the prior's), naming the differing features. `stored`: the
    checkpoint's config.json, if it has one."""
    if stored is None:
        return
    trained = tuple(stored.get("relative_positions", ()))
    if trained != tuple(config.relative_positions):
        raise ValueError(
            f"The checkpoint {folder} was trained with relative_positions={list(trained)}, this run asks for "
            f"{list(config.relative_positions)}: its normalisation statistics and weights read positions one way. "
            "Drop the --policy.relative_positions override, or train stage 1 again with the new value."
        )
    before = {
        key: tuple(ft["shape"])
        for key, ft in {**stored.get("input_features", {}), **stored.get("output_features", {})}.items()
    }
    now = {key: tuple(ft.shape) for key, ft in {**config.input_features, **config.output_features}.items()}
    differ = sorted(key for key in before.keys() | now.keys() if before.get(key) != now.get(key))
    if differ:
        rows = "; ".join(
            f"{key}: checkpoint {before.get(key, 'absent')} vs now {now.get(key, 'absent')}" for key in differ
        )
        raise ValueError(
            f"The checkpoint {folder} was trained on other features than this run's dataset ({rows}). Stage 2 "
            "needs a target dataset with the prior's observation and action layout (same robot, keys and sizes): "
            "record the target like the prior, or pre-train the skills on a prior with the target's layout."
        )


def _stage1_policy_differs(model: SkillRetPolicy, model_file: str, stored: dict | None) -> bool:
    """Whether a stage-2 model is loading a stage-1 checkpoint (`stored`: its config.json) whose never trained
    latent policy has other shapes, e.g. stage 2 asks for a mixture head (`policy_mixtures`) or another width."""
    if model.config.stage != "policy" or stored is None or stored.get("stage") != "skills":
        return False
    own = model.latent_policy.state_dict()
    with safe_open(model_file, framework="pt") as file:
        names = file.keys()
        stored = {key.removeprefix("latent_policy."): key for key in names if key.startswith("latent_policy.")}
        return stored.keys() != own.keys() or any(
            tuple(file.get_slice(key).get_shape()) != tuple(own[name].shape) for name, key in stored.items()
        )


def _load_without_latent_policy(model: SkillRetPolicy, model_file: str, map_location: str) -> SkillRetPolicy:
    """Load a stage-1 checkpoint's skills and statistics, keeping the stage-2 model's own latent policy: stage 1
    never trains it, so nothing is lost."""
    state = load_file(model_file, device=resolve_safetensors_device(map_location))
    missing, unexpected = model.load_state_dict(
        {key: value for key, value in state.items() if not key.startswith("latent_policy.")}, strict=False
    )
    if unexpected or any(not key.startswith("latent_policy.") for key in missing):
        raise ValueError(f"{model_file} does not hold a skillret model: missing {missing}, unexpected {unexpected}.")
    logging.info("Stage 1 checkpoint %s: skills loaded; the latent policy starts fresh (another head).", model_file)
    return model
