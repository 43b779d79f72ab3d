"""The latent policy pi(o_{t-F+1..t}, id) -> z (seed C.1, Algorithm 2 lines 13-14).

A 2-layer LSTM over the F-step observation history. The dataset id (0 = target, 1 = retrieved) is a one-hot
concatenated to every step's features, so the two sources can disagree without interfering; rollouts use 0.
The paper regresses one z (squared error); `policy_mixtures > 0` makes the head a Gaussian mixture over z instead.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.distributions import Categorical, Independent, MixtureSameFamily, Normal

from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
from lerobot_skillret.policy.networks import ObservationEncoder, mlp, run_lstm
from lerobot_skillret.policy.skills import valid_step_mean

TARGET_ID = 0
RETRIEVED_ID = 1
NUM_DATASET_IDS = 2
MIN_STD = 1e-4  # floor of the mixture's standard deviations (robomimic's GMM head uses the same)


class LatentPolicy(nn.Module):
    def __init__(self, config: SkillRetConfig, obs_encoder: ObservationEncoder) -> None:
        super().__init__()
        self.obs_encoder = obs_encoder
        self.latent_dim, self.mixtures = config.latent_dim, config.policy_mixtures
        self.lstm = nn.LSTM(
            obs_encoder.out_dim + NUM_DATASET_IDS, config.policy_lstm_hidden, config.lstm_layers, batch_first=True
        )
        # per component: a logit, and a mean and a raw scale (softplus) per latent dimension; without mixtures just z
        out_dim = self.mixtures * (1 + 2 * self.latent_dim) if self.mixtures else self.latent_dim
        self.head = mlp(config.policy_lstm_hidden, config.policy_mlp, out_dim)

    def _features(self, history: Mapping[str, Tensor], dataset_id: Tensor, every_step: bool = False) -> Tensor:
        """Head outputs at the last history step (B, out), or at every step (B, F, out); float32 under autocast."""
        obs = self.obs_encoder(history)
        one_hot = F.one_hot(dataset_id, NUM_DATASET_IDS).to(obs.dtype)
        features = torch.cat([obs, one_hot[:, None, :].expand(-1, obs.shape[1], -1)], dim=-1)
        outputs, _ = run_lstm(self.lstm, features)
        return self.head(outputs if every_step else outputs[:, -1]).float()

    def _mixture(self, out: Tensor) -> MixtureSameFamily:
        size = self.mixtures * self.latent_dim
        logits, means, scales = out.split([self.mixtures, size, size], dim=-1)
        shape = (out.shape[0], self.mixtures, self.latent_dim)
        std = F.softplus(scales.reshape(shape)) + MIN_STD
        components = Independent(Normal(means.reshape(shape), std), 1)
        return MixtureSameFamily(Categorical(logits=logits), components)

    @staticmethod
    def _most_probable(mixture: MixtureSameFamily) -> Tensor:
        """The mean of each sample's most probable component: a skill the data showed, not an average of several."""
        best = mixture.mixture_distribution.logits.argmax(dim=-1)
        return mixture.component_distribution.mean[torch.arange(len(best), device=best.device), best]

    def forward(self, history: Mapping[str, Tensor], dataset_id: Tensor) -> Tensor:
        """history: observation tensors (B, F, ...); dataset_id (B,) long -> the skill z to run (B, latent)."""
        out = self._features(history, dataset_id)
        return self._most_probable(self._mixture(out)) if self.mixtures else out

    def loss(
        self, history: Mapping[str, Tensor], dataset_id: Tensor, labels: Tensor, valid: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        """Per-window loss (B,) against the encoder's skills, and the skill `forward` picks at the last step.

        `labels` (B, latent) supervise the last history step; (B, F, latent) with `valid` (B, F) supervise every
        step (the loss averages the valid ones). Squared error summed over latent dimensions (the paper), or the
        mixture's negative log-likelihood."""
        out = self._features(history, dataset_id, every_step=labels.ndim == 3)
        if self.mixtures:
            mixture = self._mixture(out.flatten(0, -2))
            per_step, picked = -mixture.log_prob(labels.flatten(0, -2)), self._most_probable(mixture)
            per_step, picked = per_step.reshape(labels.shape[:-1]), picked.reshape(labels.shape)
        else:
            per_step, picked = (out - labels).pow(2).sum(dim=-1), out
        if labels.ndim == 2:
            return per_step, picked
        return valid_step_mean(per_step, valid.to(per_step.dtype)), picked[:, -1]
