"""The skill model (seed C.1, Algorithm 1): a VAE over H-step windows with a learned prior and temporal prediction.

- encoder q(z | o_t..t+H-1, a_t..t+H-1): 2-layer LSTM over (encoded obs, action), MLP -> mean, log-variance;
- closed-loop decoder p(a_t | o_t, z): 2-layer LSTM fed (z, o_t) at every step, MLP, then tanh for MIN_MAX actions
  (the paper; actions in [-1, 1]) or nothing for MEAN_STD ones;
- learned prior p(z | o_0, o_{H-1}) (the window's first and last observation), or p(z | o_0) as in SPiRL;
- temporal predictor m(mu, mu') -> d, the step offset between two windows of one episode.

Every tensor here is already normalised by the policy. Each module returns float32 even under bf16 autocast
(`--policy.use_amp=true`, the LSTMs' and matmuls' arithmetic in bf16): losses, distributions, the retrieval file's
latents and the actions a rollout sends stay in full precision. A window is a dict of observation tensors (B, H, ...),
`action` (B, H, A) and `valid` (B, H) bool: False on steps padded past the episode's end (a prefix is valid).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor, nn
from torch.distributions import Normal, kl_divergence

from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
from lerobot_skillret.policy.networks import (
    CellState,
    LSTMState,
    ObservationEncoder,
    lstm_steps,
    mlp,
    mlp_out_dim,
    run_lstm,
)

Window = Mapping[str, Tensor]


def last_valid(values: Tensor, valid: Tensor) -> Tensor:
    """values (B, T, ...) at each row's last valid step (valid is a prefix mask (B, T))."""
    index = (valid.sum(dim=1) - 1).clamp_min(0)
    return values[torch.arange(values.shape[0], device=values.device), index]


def valid_step_mean(values: Tensor, valid: Tensor) -> Tensor:
    """Each row of values (B, T) averaged over its valid steps (valid (B, T), bool or 0/1): (B,)."""
    return (values * valid).sum(dim=1) / valid.sum(dim=1).clamp_min(1.0)


def gaussian_kl(mean_q: Tensor, log_var_q: Tensor, mean_p: Tensor, log_var_p: Tensor) -> Tensor:
    """KL(N(mean_q, var_q) || N(mean_p, var_p)) of diagonal Gaussians, summed over the latent: (B,)."""
    q = Normal(mean_q, torch.exp(0.5 * log_var_q))
    p = Normal(mean_p, torch.exp(0.5 * log_var_p))
    return kl_divergence(q, p).sum(dim=-1)


def make_observation_encoder(
    config: SkillRetConfig, low_dim_shapes: Mapping[str, Sequence[int]], image_shapes: Mapping[str, Sequence[int]]
) -> ObservationEncoder:
    return ObservationEncoder(
        low_dim_shapes,
        image_shapes,
        config.low_dim_mlp,
        config.crop_shape,
        config.spatial_softmax_keypoints,
        config.vision_backbone,
    )


class SkillEncoder(nn.Module):
    def __init__(self, config: SkillRetConfig, obs_encoder: ObservationEncoder, action_dim: int) -> None:
        super().__init__()
        self.obs_encoder = obs_encoder
        self.lstm = nn.LSTM(
            obs_encoder.out_dim + action_dim, config.encoder_lstm_hidden, config.lstm_layers, batch_first=True
        )
        self.head = mlp(config.encoder_lstm_hidden, config.encoder_mlp, 2 * config.latent_dim)

    def forward(self, window: Window) -> tuple[Tensor, Tensor]:
        """(mean, log_var), each (B, latent). Read at the last valid step, so padded steps never shape z."""
        features = torch.cat([self.obs_encoder(window), window["action"]], dim=-1)
        outputs, _ = run_lstm(self.lstm, features)
        mean, log_var = self.head(last_valid(outputs, window["valid"])).float().chunk(2, dim=-1)
        return mean, log_var


class SkillDecoder(nn.Module):
    """Closed loop: each step sees the current observation, so the skill can react to where the robot is."""

    def __init__(self, config: SkillRetConfig, obs_encoder: ObservationEncoder, action_dim: int) -> None:
        super().__init__()
        self.obs_encoder = obs_encoder
        self.lstm = nn.LSTM(
            obs_encoder.out_dim + config.latent_dim, config.decoder_lstm_hidden, config.lstm_layers, batch_first=True
        )
        self.head = mlp(config.decoder_lstm_hidden, config.decoder_mlp, action_dim)
        self.squash = nn.Tanh() if config.bounded_actions else nn.Identity()

    def forward(self, z: Tensor, observation: Window, state: LSTMState | None = None) -> tuple[Tensor, LSTMState]:
        """z (B, L), observations (B, T, ...) -> normalised actions (B, T, A) and the LSTM state after step T."""
        obs = self.obs_encoder(observation)
        features = torch.cat([z[:, None, :].expand(-1, obs.shape[1], -1), obs], dim=-1)
        outputs, state = run_lstm(self.lstm, features, state)
        return self.squash(self.head(outputs).float()), state

    def step(self, z: Tensor, observation: Window, state: CellState | None) -> tuple[Tensor, CellState]:
        """One rollout step: z (B, L), observations (B, ...) -> action (B, A) and the per-layer (h, c) state to
        pass to the next step (the same weights as `forward`, run cell by cell: see `lstm_steps`)."""
        features = torch.cat([z, self.obs_encoder(observation)], dim=-1)
        output, state = lstm_steps(self.lstm, features[:, None], state)
        return self.squash(self.head(output).float()), state


class SkillPrior(nn.Module):
    """p(z | o_0, o_{H-1}), or p(z | o_0) (`skill_prior_inputs="first"`): the KL term pulls the encoder towards what
    the window's endpoints, or its first state, predict."""

    def __init__(self, config: SkillRetConfig, obs_encoder: ObservationEncoder) -> None:
        super().__init__()
        self.obs_encoder = obs_encoder
        self.endpoints = config.skill_prior_inputs == "endpoints"
        width = (2 if self.endpoints else 1) * obs_encoder.out_dim
        self.net = mlp(width, config.prior_mlp, 2 * config.latent_dim)

    def forward(self, window: Window) -> tuple[Tensor, Tensor]:
        obs = self.obs_encoder(window)
        features = torch.cat([obs[:, 0], last_valid(obs, window["valid"])], dim=-1) if self.endpoints else obs[:, 0]
        mean, log_var = self.net(features).float().chunk(2, dim=-1)
        return mean, log_var


class SkillModel(nn.Module):
    """Encoder, decoder, prior, temporal predictor (and the optional inverse-dynamics head); Algorithm 1's loss."""

    def __init__(
        self,
        config: SkillRetConfig,
        low_dim_shapes: Mapping[str, Sequence[int]],
        image_shapes: Mapping[str, Sequence[int]],
        action_dim: int,
    ) -> None:
        super().__init__()
        self.config = config

        def obs_encoder() -> ObservationEncoder:
            return make_observation_encoder(config, low_dim_shapes, image_shapes)

        self.encoder = SkillEncoder(config, obs_encoder(), action_dim)
        self.decoder = SkillDecoder(config, obs_encoder(), action_dim)
        self.prior = SkillPrior(config, obs_encoder())
        self.temporal = mlp(2 * config.latent_dim, config.tc_mlp, 1)
        self.inverse_dynamics = None
        if config.inverse_dynamics_weight > 0:
            # implementation-only extra: (o_t, o_{t+H-1}) -> z, on the prior's observation features
            width = 2 * self.prior.obs_encoder.out_dim
            self.inverse_dynamics = nn.Sequential(
                mlp(width, config.prior_mlp), nn.Linear(mlp_out_dim(width, config.prior_mlp), config.latent_dim)
            )

    def skill_parameters(self) -> list[nn.Parameter]:
        """Everything trained at the skill learning rate (all but the temporal predictor)."""
        temporal = {id(p) for p in self.temporal.parameters()}
        return [p for p in self.parameters() if id(p) not in temporal]

    def action_error(self, z: Tensor, window: Window) -> tuple[Tensor, Tensor]:
        """Decode `z` closed-loop along the window's observations: squared action error summed over action
        dimensions, (B, H), and the mask (B, H) of valid steps (1.0; padded steps past an episode's end are 0.0)."""
        actions, _ = self.decoder(z, window)
        squared = (actions - window["action"]).pow(2).sum(dim=-1)
        return squared, window["valid"].to(actions.dtype)

    def window_error(self, z: Tensor, window: Window) -> Tensor:
        """`action_error` averaged over each window's valid steps, (B,)."""
        return valid_step_mean(*self.action_error(z, window))

    def loss(
        self,
        window: Window,
        pair: Window | None = None,
        offset: Tensor | None = None,
        slow_pair: Window | None = None,
        decode_pairs: bool = False,
        target_windows: int | None = None,
    ) -> tuple[Tensor, dict[str, Tensor], Tensor]:
        """L_skill = ||a_hat - a||^2 + beta KL(q || prior) + alpha (d_hat - d)^2 (+ the optional extras).

        `pair` is the window shifted by `offset` (B,) raw steps in the same episode (Algorithm 1, line 3);
        `slow_pair` a window within +-slowness_max_offset steps (implementation-only slowness term).
        `decode_pairs`: the pairs are trained windows too (reconstruction and KL), not only the temporal term's
        second input. They are encoded either way, so this trains twice the windows for a third more compute.
        Reconstruction: squared error summed over action dimensions, averaged over valid steps only.
        `target_windows`: how many leading windows are the target's (stage 2 fine-tunes on target and prior windows
        at once); their reconstruction and KL are also reported alone (`target_reconstruction_loss`,
        `target_kl_loss`), since the prior's windows can dominate the joint terms.
        Returns the loss, its terms, and the encoder means of `window` (B, latent).
        """
        config = self.config
        batch = window["action"].shape[0]
        extra = [w for w in (pair, slow_pair) if w is not None]
        # one encoder pass over all windows
        joined = {key: torch.cat([window[key], *(w[key] for w in extra)]) for key in window} if extra else window
        means, log_vars = self.encoder(joined)
        trained = 2 * batch if decode_pairs and pair is not None else batch
        decoded = {key: value[:trained] for key, value in joined.items()}
        mean, log_var = means[:trained], log_vars[:trained]

        z = mean + torch.randn_like(mean) * torch.exp(0.5 * log_var) if self.training else mean
        squared, valid = self.action_error(z, decoded)
        masked = squared * valid
        reconstruction = masked.sum() / valid.sum().clamp_min(1.0)

        prior_mean, prior_log_var = self.prior(decoded)
        kl_per_window = gaussian_kl(mean, log_var, prior_mean, prior_log_var)
        kl = kl_per_window.mean()
        total = reconstruction + config.kl_weight * kl
        terms = {"reconstruction_loss": reconstruction, "kl_loss": kl}
        if target_windows is not None:
            target = slice(0, target_windows)
            terms["target_reconstruction_loss"] = masked[target].sum() / valid[target].sum().clamp_min(1.0)
            terms["target_kl_loss"] = kl_per_window[target].mean()

        if pair is not None:
            if offset is None:
                raise ValueError("SkillModel.loss: a temporal pair needs its offset d.")
            pair_mean = means[batch : 2 * batch]
            predicted = self.temporal(torch.cat([means[:batch], pair_mean], dim=-1)).float().squeeze(-1)
            tc = (predicted - offset.to(predicted.dtype)).pow(2).mean()
            total = total + config.tc_weight * tc
            terms["tc_loss"] = tc
        if slow_pair is not None:
            slow_mean = means[-batch:]
            slowness = (means[:batch] - slow_mean).pow(2).sum(dim=-1).mean()
            total = total + config.slowness_weight * slowness
            terms["slowness_loss"] = slowness
        if self.inverse_dynamics is not None:
            obs = self.prior.obs_encoder(decoded)
            endpoints = torch.cat([obs[:, 0], last_valid(obs, decoded["valid"])], dim=-1)
            inverse = (self.inverse_dynamics(endpoints).float() - mean.detach()).pow(2).sum(dim=-1).mean()
            total = total + config.inverse_dynamics_weight * inverse
            terms["inverse_dynamics_loss"] = inverse
        return total, terms, means[:batch]
