"""The latent policy pi(o_{t-F+1..t}, id) -> z (seed C.1, Algorithm 2 lines 13-14).

A 2-layer LSTM over the F-step observation history. The dataset id (0 = target, 1 = retrieved) is a one-hot
concatenated to every step's features, so the two sources can disagree without interfering; rollouts use 0.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
from lerobot_skillret.policy.networks import ObservationEncoder, mlp

TARGET_ID = 0
RETRIEVED_ID = 1
NUM_DATASET_IDS = 2


class LatentPolicy(nn.Module):
    def __init__(self, config: SkillRetConfig, obs_encoder: ObservationEncoder) -> None:
        super().__init__()
        self.obs_encoder = obs_encoder
        self.lstm = nn.LSTM(
            obs_encoder.out_dim + NUM_DATASET_IDS, config.policy_lstm_hidden, config.lstm_layers, batch_first=True
        )
        self.head = mlp(config.policy_lstm_hidden, config.policy_mlp, config.latent_dim)

    def forward(self, history: Mapping[str, Tensor], dataset_id: Tensor) -> Tensor:
        """history: observation tensors (B, F, ...); dataset_id (B,) long -> predicted skill z (B, latent)."""
        obs = self.obs_encoder(history)
        one_hot = F.one_hot(dataset_id, NUM_DATASET_IDS).to(obs.dtype)
        features = torch.cat([obs, one_hot[:, None, :].expand(-1, obs.shape[1], -1)], dim=-1)
        outputs, _ = self.lstm(features)
        return self.head(outputs[:, -1])
