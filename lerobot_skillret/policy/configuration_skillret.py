"""Configuration of the `skillret` policy: skill VAE + retrieval + latent policy.

Defaults are the paper's (Table 7 of the seed appendix; GPU-scale, as in `configs/policy/paper.json`);
`configs/policy/cpu.json` holds one small enough for a 2-core CPU. Batch size (16 in the paper) and step counts are
`lerobot-train` options, not policy ones.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from itertools import pairwise

from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, NormalizationMode
from lerobot.optim.optimizers import AdamConfig, OptimizerConfig

STAGES = ("skills", "policy")
RETRIEVAL_METRICS = ("l2", "kl")
RETRIEVED_LATENTS = ("stored", "reencode")
SKILL_PRIOR_INPUTS = ("endpoints", "first")
POLICY_SUPERVISION = ("last", "every_step")
SKILL_FINETUNE_WINDOWS = ("prior", "retrieved")
RESNETS = ("resnet18", "resnet34", "resnet50", "resnet101", "resnet152")  # torchvision's, each with a 64-channel stem
SKILL_NORMALIZATION_MODES = (NormalizationMode.IDENTITY, NormalizationMode.MEAN_STD, NormalizationMode.MIN_MAX)


@OptimizerConfig.register_subclass("skillret_adam")
@dataclass
class SkillRetAdamConfig(AdamConfig):
    """LeRobot's Adam with torch's fused kernel (`fused`): one pass over every parameter instead of a loop of small
    ops per tensor. Why: the skill model has ~40 small tensors, and on one CPU core the per-tensor loop took 11 % of
    a stage-1 step (6.5 ms; fused 1.7 ms, `benchmarks/policy_speed.py`). Same update rule, same state dict."""

    fused: bool = True


@PreTrainedConfig.register_subclass("skillret")
@dataclass
class SkillRetConfig(PreTrainedConfig):
    """Skill-based imitation with retrieval from prior data.

    Stage `skills` (Algorithm 1) trains the skill VAE on windows of the prior dataset (`--dataset.*` = prior): a
    batch of `--batch_size` B windows is B/2 temporal pairs (the batch's first half and a window d steps away in
    each one's episode).
    Stage `policy` (Algorithm 2) starts from a stage-1 checkpoint (`--policy.path`), trains the latent policy on
    target windows (`--dataset.*` = target) plus retrieved prior windows, and keeps fine-tuning the skill model on
    prior and target windows.
    """

    # --- Which algorithm `lerobot-train` runs.
    stage: str = "skills"  # "skills": pre-train the skill VAE (Alg. 1); "policy": latent policy + fine-tune (Alg. 2)

    # --- Windows (sub-trajectories).
    horizon: int = 10  # H: steps per skill window; the decoder runs H steps per policy query at rollout
    history: int = 10  # F: observations the policy sees before a window (frame stack, the anchor included)
    skill_steps: int | None = None  # rollout: steps a skill runs before the policy picks the next one. None = H
    # (the paper: no pre-emption); fewer re-plan more often, each new skill decoded from a fresh decoder state

    # --- Observation encoder (shared shape by the skill encoder/decoder/prior and the policy).
    low_dim_mlp: tuple[int, ...] = (256,)  # MLP over the concatenated low-dim observations (state, env state)
    vision_backbone: str = "resnet18"  # per-camera torchvision ResNet, trained from scratch; resnet18 is the seed's C.1
    crop_shape: tuple[int, int] | None = (76, 76)  # random crop during training, centre crop at inference
    spatial_softmax_keypoints: int = 32  # keypoints of the spatial-softmax pooling after each backbone
    relative_positions: tuple[int, ...] = ()  # not in the paper: start indices of (x, y, z) triples in
    # `observation.environment_state` that every module sees minus the end effector (`observation.state[:3]`), so a
    # skill reads "the bread is 10 cm ahead" the same in every scene (see policy/relative_positions.py); () keeps
    # absolute positions (the paper). configs/README.md gives the kitchen's list (its eleven movables)

    # --- Skill model (Table 7).
    latent_dim: int = 64  # dimension of the skill latent z
    lstm_layers: int = 2  # layers of every LSTM (skill encoder, decoder, policy)
    encoder_lstm_hidden: int = 1000  # skill encoder: LSTM hidden units
    encoder_mlp: tuple[int, ...] = (1024, 1024)  # skill encoder: MLP hidden sizes -> (mean, log-variance)
    decoder_lstm_hidden: int = 1000  # closed-loop skill decoder: LSTM hidden units, input (z, o_t) each step
    decoder_mlp: tuple[int, ...] = (1024, 1024)  # skill decoder: MLP hidden sizes -> action (tanh if MIN_MAX)
    prior_mlp: tuple[int, ...] = (1024, 1024)  # learned prior (see skill_prior_inputs): hidden sizes
    skill_prior_inputs: str = "endpoints"  # what the learned prior sees: "endpoints" o_0 and o_{H-1} (the paper's
    # code), or "first" o_0 only (SPiRL's state-conditioned prior: with a larger kl_weight the skill keeps only what
    # the current state does not already tell, which is what the latent policy has to predict)
    tc_mlp: tuple[int, ...] = (128, 128)  # temporal-prediction MLP on two encoder means: hidden sizes

    # --- Latent policy (Table 7).
    policy_lstm_hidden: int = 1000  # policy: LSTM hidden units over the F-step observation history
    policy_mlp: tuple[int, ...] = ()  # policy: MLP hidden sizes after the LSTM (the seed names none)

    # --- Losses.
    kl_weight: float = 1e-5  # beta: weight of KL(q(z|window) || learned prior), the prior as skill_prior_inputs says
    tc_weight: float = 1e-6  # alpha: weight of the temporal-prediction loss (offset in raw steps)
    tc_max_offset: int = 50  # the paired window is shifted by d in [-tc_max_offset, tc_max_offset] steps
    retrieved_weight: float = 1.0  # gamma: weight of the retrieved windows' policy loss (0.15 for real tasks)
    slowness_weight: float = 0.0  # implementation-only extra: means of windows within +-slowness_max_offset agree
    slowness_max_offset: int = 5  # implementation-only extra: offset range of the slowness pair
    inverse_dynamics_weight: float = 0.0  # implementation-only extra: (o_t, o_{t+H-1}) -> z head (code used 0.1)
    policy_action_weight: float = 0.0  # not in the paper: adds the target windows' action error of the policy's
    # skill, decoded along the window, to its latent loss (latent errors weighted by what they do to the actions)
    decoder_policy_weight: float = 0.0  # not in the paper: stage 2's fine-tuned decoder also learns to execute the
    # latent policy's own (detached) skills on the target windows, so it tolerates the policy's misses; the policy
    # itself is still trained on latents only (needs finetune_skills)
    policy_mixtures: int = 0  # not in the paper: 0 regresses one z (the paper); k > 0 fits a k-component Gaussian
    # mixture over z by its likelihood (robomimic's GMM head), so a state that admits several skills is not answered
    # by their average; rollouts take the most probable component's mean
    policy_obs_noise: float = 0.0  # not in the paper: std of Gaussian noise on the policy's normalised low-dim
    # history during training, so states just off the demonstrations map to nearby skills
    policy_supervision: str = "last"  # which of the policy's F history steps are supervised: "last", the anchor
    # (the paper: one z per history), or "every_step": step t is also labelled with the current encoder's z of the
    # window starting at t (the public implementation; F times the labels, and histories as short as one step)

    # --- Optimisation (Table 7; batch size 16 is `--batch_size`).
    skill_lr: float = 5e-4  # Adam learning rate of the skill VAE (encoder, decoder, prior)
    tc_lr: float = 1e-4  # Adam learning rate of the temporal-prediction network
    policy_lr: float = 1e-3  # Adam learning rate of the latent policy
    grad_clip_norm: float = 10.0  # gradient clipping of all parameters

    # --- Retrieval (Algorithm 2, lines 1-7; Table 7).
    retrieval_num_prior: int | None = 250_000  # N: prior windows scored (None = every prior window)
    retrieval_num_target: int = 2_500  # M: target windows encoded
    retrieval_fraction: float = 0.10  # r: share of scored prior windows retrieved (0.05 for real tasks)
    retrieval_metric: str = "l2"  # "l2" on encoder means, or "kl": symmetric KL of the Gaussians (A.2)

    # --- Stage-2 data sources (the target dataset is `--dataset.*`).
    prior_repo_id: str | None = None  # prior (play) dataset; None = the "no prior data" ablation
    prior_root: str | None = None  # local folder of the prior dataset
    retrieval_path: str | None = None  # retrieval file written by `skillret-retrieve`
    use_retrieval: bool = True  # False = the paper's "no retrieval" ablation (target windows only)
    finetune_skills: bool = True  # keep training the skill model in stage 2 (Alg. 2, line 17)
    skill_finetune_windows: str = "prior"  # the windows the skills fine-tune on beside the target's: "prior", any
    # prior window (Alg. 2, line 17), or "retrieved" (not in the paper): only the retrieved ones, near the task
    retrieved_latents: str = "stored"  # labels z' of retrieved windows: "stored" in the retrieval file (paper,
    # Alg. 2 line 7) or "reencode" with the current, fine-tuned encoder (public implementation)
    video_backend: str | None = None  # decoder of the camera windows the policy fetches itself (pairs, prior,
    # retrieved); set it like --dataset.video_backend, e.g. "pyav" where torchcodec cannot load FFmpeg (None: LeRobot's)
    fast_windows: bool = False  # low-dim only: lerobot-train loads single frames and the policy gathers each
    # window by `index` from the memory-mapped column cache (same windows and pads, ~1000x cheaper per window)
    skills_checkpoint_fingerprint: str | None = None  # set by stage 2 from --policy.path; checked against the
    # retrieval file, kept in config.json so resumed runs check the same stage-1 checkpoint

    # --- Normalisation. The skill model normalises inside the policy with statistics it stores as buffers (set
    # from the stage-1 dataset, saved with the weights), because `lerobot-train --policy.path` swaps the
    # processor's statistics for the new dataset's, which would silently rescale a pre-trained decoder's actions.
    skill_normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.MEAN_STD,
            "ENV": NormalizationMode.MEAN_STD,
            # MIN_MAX: the decoder ends in tanh, actions live in [-1, 1] (the paper). MEAN_STD: it ends in a linear
            # layer, as robomimic's BC-RNN does (configs/policy/cpu.json: it executed 8 of 30 held-out
            # bread_and_butter demos' oracle skills where tanh executed 1; configs/README.md). Set in stage 1: a
            # checkpoint refuses to load under another mode.
            "ACTION": NormalizationMode.MIN_MAX,
        }
    )
    # MIN_MAX maps the data's range onto [-(1 - margin), 1 - margin]. With 0 (the paper) actions a scripted expert
    # saturates at the clip bound sit where tanh's gradient vanishes and the decoder undershoots them. Stage 1 only:
    # the scale is stored with the weights, so later stages keep the stage-1 checkpoint's margin
    min_max_margin: float = 0.0
    # What LeRobot's processor normaliser steps apply: identity everywhere, so they stay no-ops even when
    # lerobot-train/eval override their statistics (they pass this mapping as `norm_map`).
    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.IDENTITY,
            "ENV": NormalizationMode.IDENTITY,
            "ACTION": NormalizationMode.IDENTITY,
        }
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        self._validate_values()

    def _validate_values(self) -> None:
        """Reject values that would silently train something else than the method."""

        def fail(name: str, value: object, why: str) -> None:
            message = f"skillret config: `{name}`={value!r} is invalid: {why}."
            # lerobot-train's parser (draccus) replaces a config's ValueError by "Couldn't instantiate class
            # SkillRetConfig", so the reason is logged too: without it a command-line user never sees it
            logging.getLogger(__name__).error(message)
            raise ValueError(message)

        if self.stage not in STAGES:
            fail("stage", self.stage, f"choose one of {STAGES}")
        if self.retrieved_latents not in RETRIEVED_LATENTS:
            fail("retrieved_latents", self.retrieved_latents, f"choose one of {RETRIEVED_LATENTS}")
        for mode in self.normalization_mapping.values():
            if NormalizationMode(mode) is not NormalizationMode.IDENTITY:
                fail(
                    "normalization_mapping",
                    self.normalization_mapping,
                    "skillret normalises inside the model "
                    "(see skill_normalization_mapping); the processor's mapping must stay IDENTITY",
                )
        if not 0.0 <= self.min_max_margin < 1.0:
            fail("min_max_margin", self.min_max_margin, "use a value in [0, 1), e.g. 0.05")
        if "ACTION" not in self.skill_normalization_mapping:
            fail("skill_normalization_mapping", self.skill_normalization_mapping, "it needs an ACTION entry")
        for kind, mode in self.skill_normalization_mapping.items():
            if NormalizationMode(mode) not in SKILL_NORMALIZATION_MODES:
                fail("skill_normalization_mapping", {kind: mode}, f"supported modes: {SKILL_NORMALIZATION_MODES}")
        if self.vision_backbone not in RESNETS:
            fail("vision_backbone", self.vision_backbone, f"choose one of torchvision's ResNets {RESNETS}")
        if self.prior_root is not None and self.prior_repo_id is None:
            fail(
                "prior_repo_id",
                None,
                f"`prior_root`={self.prior_root!r} is set, so a prior was meant: pass --policy.prior_repo_id=<its repo "
                "id> as well, or --policy.prior_root=null for the 'no prior data' ablation",
            )
        if self.retrieval_metric not in RETRIEVAL_METRICS:
            fail("retrieval_metric", self.retrieval_metric, f"choose one of {RETRIEVAL_METRICS}")
        for name in (
            "horizon",
            "history",
            "latent_dim",
            "lstm_layers",
            "encoder_lstm_hidden",
            "decoder_lstm_hidden",
            "policy_lstm_hidden",
            "retrieval_num_target",
        ):
            if getattr(self, name) < 1:
                fail(name, getattr(self, name), "it must be >= 1")
        if self.policy_mixtures < 0:
            fail("policy_mixtures", self.policy_mixtures, "use 0 (regress z, the paper) or a number of components >= 1")
        if self.skill_prior_inputs not in SKILL_PRIOR_INPUTS:
            fail("skill_prior_inputs", self.skill_prior_inputs, f"use one of {SKILL_PRIOR_INPUTS}")
        if self.policy_supervision not in POLICY_SUPERVISION:
            fail("policy_supervision", self.policy_supervision, f"use one of {POLICY_SUPERVISION}")
        if not self.policy_obs_noise >= 0:  # written so that NaN fails too
            fail("policy_obs_noise", self.policy_obs_noise, "a noise standard deviation must be >= 0")
        if self.skill_steps is not None and not 1 <= self.skill_steps <= self.horizon:
            fail("skill_steps", self.skill_steps, f"use None (= H) or a value in [1, H = {self.horizon}]")
        if self.tc_max_offset < 0 or self.slowness_max_offset < 0:
            name = "tc_max_offset" if self.tc_max_offset < 0 else "slowness_max_offset"
            fail(name, getattr(self, name), "an offset range must be >= 0")
        for name in (
            "kl_weight",
            "tc_weight",
            "retrieved_weight",
            "slowness_weight",
            "inverse_dynamics_weight",
            "policy_action_weight",
            "decoder_policy_weight",
            "grad_clip_norm",
        ):
            if not getattr(self, name) >= 0:
                fail(name, getattr(self, name), "loss weights and clipping norms must be >= 0")
        if self.skill_finetune_windows not in SKILL_FINETUNE_WINDOWS:
            fail("skill_finetune_windows", self.skill_finetune_windows, f"use one of {SKILL_FINETUNE_WINDOWS}")
        if self.skill_finetune_windows == "retrieved" and not self.use_retrieval:
            fail("skill_finetune_windows", "retrieved", 'there are no retrieved windows: use "prior"')
        if self.decoder_policy_weight > 0 and not self.finetune_skills:
            fail("decoder_policy_weight", self.decoder_policy_weight, "it trains the decoder: set finetune_skills=true")
        for name in ("skill_lr", "tc_lr", "policy_lr"):
            if not 0 < getattr(self, name) < math.inf:
                fail(name, getattr(self, name), "a learning rate must be a finite number > 0")
        if not 0.0 < self.retrieval_fraction <= 1.0:
            fail("retrieval_fraction", self.retrieval_fraction, "r is a share of the candidates, in (0, 1]")
        if self.retrieval_num_prior is not None and self.retrieval_num_prior < 1:
            fail("retrieval_num_prior", self.retrieval_num_prior, "N must be >= 1, or None for every window")
        for name in ("low_dim_mlp", "encoder_mlp", "decoder_mlp", "prior_mlp", "tc_mlp", "policy_mlp"):
            if any(width < 1 for width in getattr(self, name)):
                fail(name, getattr(self, name), "every hidden size must be >= 1")
        if self.crop_shape is not None and min(self.crop_shape) < 1:
            fail("crop_shape", self.crop_shape, "crop sizes must be >= 1 (or None for no crop)")

    # --- LeRobot contract -------------------------------------------------------------------------------------

    @property
    def observation_delta_indices(self) -> list[int] | None:
        """Stage `policy`: the F observations up to the anchor, then the window's H (the decoder needs o_t).

        Stage `skills` needs no history (Algorithm 1 only sees the window), so it loads only the H window steps:
        with cameras that halves the frames decoded per sample. The policy accepts either layout.
        With `fast_windows` LeRobot loads the anchor frame only (None) and the policy gathers the window itself.
        """
        if self.fast_windows:
            return None
        start = 0 if self.stage == "skills" else -(self.history - 1)
        return list(range(start, self.horizon))

    @property
    def action_delta_indices(self) -> list[int] | None:
        return None if self.fast_windows else list(range(self.horizon))

    @property
    def reward_delta_indices(self) -> None:
        return None

    @property
    def bounded_actions(self) -> bool:
        """Whether the decoder squashes its actions with tanh: only for MIN_MAX-normalised actions."""
        return NormalizationMode(self.skill_normalization_mapping["ACTION"]) is NormalizationMode.MIN_MAX

    def get_optimizer_preset(self) -> SkillRetAdamConfig:
        return SkillRetAdamConfig(lr=self.skill_lr, grad_clip_norm=self.grad_clip_norm)

    def get_scheduler_preset(self) -> None:
        return None

    def validate_features(self) -> None:
        """The method needs actions and at least one observation stream; cameras must share one shape."""
        if self.action_feature is None:
            raise ValueError("skillret needs an `action` feature in the dataset (the skill VAE reconstructs actions).")
        if len(self.action_feature.shape) != 1:
            raise ValueError(
                f"skillret needs a flat action vector; the dataset's `action` has shape "
                f"{tuple(self.action_feature.shape)}."
            )
        if self.fast_windows and self.image_features:
            raise ValueError(
                f"`fast_windows`=True gathers windows from the low-dim column cache, which holds no camera frames, "
                f"but the inputs include cameras {sorted(self.image_features)}. Set --policy.fast_windows=false."
            )
        if not (self.robot_state_feature or self.env_state_feature or self.image_features):
            raise ValueError(
                "skillret needs at least one observation feature: `observation.state`, "
                "`observation.environment_state` or `observation.images.*`."
            )
        self._validate_relative_positions()
        shapes = {tuple(ft.shape) for ft in self.image_features.values()}
        if len(shapes) > 1:
            raise ValueError(f"skillret expects all cameras to share one image shape; got {sorted(shapes)}.")
        for key, ft in self.input_features.items():
            if (
                ft.type is FeatureType.VISUAL
                and self.crop_shape is not None
                and (self.crop_shape[0] > ft.shape[-2] or self.crop_shape[1] > ft.shape[-1])
            ):
                raise ValueError(
                    f"`crop_shape`={self.crop_shape} is larger than camera `{key}` {tuple(ft.shape)}; set "
                    "--policy.crop_shape to at most the image size (or null to disable cropping)."
                )

    def _validate_relative_positions(self) -> None:
        """Each triple must lie inside the environment state, once, next to a state that starts with the gripper."""
        if not self.relative_positions:
            return
        state, env = self.robot_state_feature, self.env_state_feature
        if state is None or env is None or state.shape[0] < 3:
            raise ValueError(
                f"`relative_positions`={list(self.relative_positions)} needs `observation.state` (the end effector "
                "position first) and `observation.environment_state`; the inputs have "
                f"{sorted(self.input_features)}. Set --policy.relative_positions=[] for absolute positions."
            )
        starts = sorted(self.relative_positions)
        bad = [s for s in starts if not 0 <= s <= env.shape[0] - 3]
        overlapping = [b for a, b in pairwise(starts) if b - a < 3]
        if bad or overlapping:
            raise ValueError(
                f"`relative_positions`={list(self.relative_positions)}: each start index must leave an (x, y, z) "
                f"triple inside `observation.environment_state` (size {env.shape[0]}, so 0..{env.shape[0] - 3}) and "
                f"triples must not overlap ({f'out of range: {bad}' if bad else f'overlapping: {overlapping}'})."
            )
