"""SkillRetPolicy: shapes, masks, losses and their gradients, both stages' forward, inference, normalisation."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from policy_fixtures import (
    PRIOR_REPO,
    TARGET_REPO,
    batch_at,
    build_policy,
    tiny_config,
    training_batch,
    write_retrieval,
)
from synthetic import make_synthetic_dataset

from lerobot_skillret.data.fingerprint import checkpoint_fingerprint
from lerobot_skillret.data.windows import EpisodeColumns, WindowSampler
from lerobot_skillret.policy import networks
from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
from lerobot_skillret.policy.latent_policy import RETRIEVED_ID, TARGET_ID
from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy, first_half
from lerobot_skillret.policy.networks import ObservationEncoder, center_crop, random_crop
from lerobot_skillret.policy.normalization import SkillNormalizer
from lerobot_skillret.policy.processor_skillret import make_skillret_pre_post_processors
from lerobot_skillret.policy.skills import make_observation_encoder

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def prior_root(tmp_path_factory) -> Path:
    return make_synthetic_dataset(tmp_path_factory.mktemp("prior") / "ds", PRIOR_REPO, num_episodes=6, seed=0)


@pytest.fixture(scope="module")
def target_root(tmp_path_factory) -> Path:
    # Scaled differently from the prior (other seed, other statistics): catches any use of the wrong stats.
    return make_synthetic_dataset(tmp_path_factory.mktemp("target") / "ds", TARGET_REPO, num_episodes=3, seed=1)


@pytest.fixture(scope="module")
def stage1_dir(prior_root, tmp_path_factory) -> Path:
    torch.manual_seed(0)
    policy = build_policy(tiny_config(), PRIOR_REPO, prior_root)
    folder = tmp_path_factory.mktemp("stage1") / "pretrained_model"
    policy.save_pretrained(folder)
    return folder


def stage2_policy(stage1_dir: Path, target_root: Path, **overrides) -> SkillRetPolicy:
    """Stage 2 as lerobot-train builds it from --policy.path: the target's stats are handed in, then weights load."""
    config = tiny_config(stage="policy", **overrides)
    config.pretrained_path = stage1_dir
    meta = LeRobotDatasetMetadata(TARGET_REPO, root=target_root)
    stage1 = SkillRetPolicy.from_pretrained(stage1_dir)
    config.input_features, config.output_features = stage1.config.input_features, stage1.config.output_features
    return SkillRetPolicy.from_pretrained(stage1_dir, config=config, dataset_stats=meta.stats, dataset_meta=meta)


def test_stage1_forward_shapes_and_terms(prior_root):
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root)
    batch = training_batch(config, PRIOR_REPO, prior_root)
    assert batch["observation.state"].shape[1] == config.horizon  # stage 1 loads no history
    loss, info = policy.forward(batch)
    assert loss.ndim == 0 and torch.isfinite(loss)
    assert set(info) == {"reconstruction_loss", "kl_loss", "tc_loss"}
    assert all(isinstance(v, float) and v > 0 for v in info.values())
    # stage 1 trains the skill model only
    assert not any(p.requires_grad for p in policy.latent_policy.parameters())
    lrs = sorted(group["lr"] for group in policy.get_optim_params())
    assert lrs == sorted([config.skill_lr, config.tc_lr])


def test_stage1_trains_batch_size_windows_as_temporal_pairs(prior_root):
    """A stage-1 batch of B windows is B/2 anchors and their pairs, each one encoded once and decoded once (the
    pairs are not encoder-only extras: that cost a third more compute for half the trained windows)."""
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root)
    batch = training_batch(config, PRIOR_REPO, prior_root)
    rows = {}
    for name in ("encoder", "decoder"):
        lstm = getattr(policy.skills, name).lstm
        lstm.register_forward_pre_hook(lambda _, inputs, name=name: rows.__setitem__(name, inputs[0].shape[0]))
    policy.forward(batch)
    assert rows == {"encoder": len(batch["index"]), "decoder": len(batch["index"])}


def test_overfitting_one_batch_reduces_reconstruction(prior_root):
    """Training on one batch fits its anchors (the first half; their pairs are drawn afresh every step)."""
    torch.manual_seed(0)
    config = tiny_config(skill_lr=3e-3)
    policy = build_policy(config, PRIOR_REPO, prior_root)
    batch = training_batch(config, PRIOR_REPO, prior_root)
    anchors = policy._window(first_half(batch))

    def reconstruction() -> float:
        policy.eval()
        with torch.no_grad():
            _, terms, _ = policy.skills.loss(anchors)
        policy.train()
        return float(terms["reconstruction_loss"])

    optimizer = torch.optim.Adam(policy.get_optim_params())
    first = reconstruction()
    for _ in range(150):
        loss, _ = policy.forward(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert reconstruction() < 0.3 * first


def _grad_norm(module: torch.nn.Module) -> float:
    return sum(float(p.grad.norm()) for p in module.parameters() if p.grad is not None)


def test_pair_loss_terms_equal_the_modules_called_one_by_one(prior_root):
    """With `decode_pairs`, reconstruction averages the valid steps of windows and pairs alike, and the temporal
    term predicts each offset d from the window's and its own pair's encoder means (eval mode: z is the mean)."""
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root).eval()
    batch = training_batch(config, PRIOR_REPO, prior_root)
    window = policy._window(batch)
    pair_raw, offset = policy._data(batch["index"]).own.pair(batch["index"], config.tc_max_offset, "cpu")
    pair = policy._window(pair_raw)
    skills = policy.skills
    with torch.no_grad():
        _, terms, _ = skills.loss(window, pair, offset, decode_pairs=True)
        means = [skills.encoder(w)[0] for w in (window, pair)]
        errors = [skills.action_error(mean, w) for mean, w in zip(means, (window, pair), strict=True)]
        reconstruction = sum((e * v).sum() for e, v in errors) / sum(v.sum() for _, v in errors)
        predicted = skills.temporal(torch.cat(means, dim=-1)).squeeze(-1)
    torch.testing.assert_close(terms["reconstruction_loss"], reconstruction)
    torch.testing.assert_close(terms["tc_loss"], (predicted - offset.float()).pow(2).mean())


def test_kl_and_temporal_terms_reach_the_encoder(prior_root):
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root)
    batch = training_batch(config, PRIOR_REPO, prior_root)
    window = policy._window(batch)
    pair_raw, offset = policy._data(batch["index"]).own.pair(batch["index"], config.tc_max_offset, "cpu")
    _, terms, _ = policy.skills.loss(window, policy._window(pair_raw), offset)
    assert float(terms["kl_loss"]) > 0 and float(terms["tc_loss"]) > 0
    for name in ("kl_loss", "tc_loss"):
        policy.zero_grad()
        terms[name].backward(retain_graph=True)
        assert _grad_norm(policy.skills.encoder) > 0, f"{name} does not reach the skill encoder"
    assert _grad_norm(policy.skills.temporal) > 0


@pytest.mark.parametrize("inputs", ["endpoints", "first"])
def test_the_skill_prior_sees_the_configured_observations(prior_root, inputs):
    """The prior sees o_0 and o_{H-1} ("endpoints", the paper's code) or o_0 alone ("first", SPiRL)."""
    torch.manual_seed(0)
    config = tiny_config(skill_prior_inputs=inputs)
    policy = build_policy(config, PRIOR_REPO, prior_root).eval()
    window = policy._window(training_batch(config, PRIOR_REPO, prior_root))
    later = {key: value.clone() for key, value in window.items()}
    later["observation.state"][:, 1:] += 1.0  # every observation after o_0
    first = {key: value.clone() for key, value in window.items()}
    first["observation.state"][:, 0] += 1.0
    mean = policy.skills.prior(window)[0]
    assert not torch.allclose(policy.skills.prior(first)[0], mean)
    assert torch.allclose(policy.skills.prior(later)[0], mean) == (inputs == "first")


def test_padded_steps_do_not_contribute(prior_root):
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root).eval()  # eval: z = mean, deterministic
    columns = EpisodeColumns.from_dataset(PRIOR_REPO, prior_root)
    ends = torch.unique(columns.td["episode_end"]).tolist()
    batch = batch_at(config, PRIOR_REPO, prior_root, [end - 2 for end in ends] + [ends[0] - 1])
    assert batch["action_is_pad"].any()
    pad = batch["action_is_pad"]
    changed = dict(batch)
    changed["action"] = torch.where(pad[..., None], torch.full_like(batch["action"], 0.9), batch["action"])
    for key in ("observation.state", "observation.environment_state"):
        changed[key] = torch.where(pad[..., None], batch[key] + 5.0, batch[key])
    pair_raw, offset = policy._data(batch["index"]).own.pair(batch["index"], config.tc_max_offset, "cpu")
    pair = policy._window(pair_raw)
    total, terms, mean = policy.skills.loss(policy._window(batch), pair, offset)
    total2, terms2, mean2 = policy.skills.loss(policy._window(changed), pair, offset)
    assert torch.equal(mean, mean2)
    assert torch.allclose(total, total2) and all(torch.allclose(terms[k], terms2[k]) for k in terms)
    # and the change is visible when the steps are NOT marked padded
    unmasked = dict(changed)
    unmasked["action_is_pad"] = torch.zeros_like(pad)
    total3, _, _ = policy.skills.loss(policy._window(unmasked), pair, offset)
    assert not torch.allclose(total, total3)


def test_encode_skill_takes_history_or_window_only(prior_root):
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root).eval()
    sampler = WindowSampler(EpisodeColumns.from_dataset(PRIOR_REPO, prior_root), history=3, horizon=4)
    window = sampler.gather(torch.tensor([0, 5, 17, 40]))
    mean, log_var = policy.encode_skill(window)
    assert mean.shape == log_var.shape == (4, config.latent_dim)
    cut = {k: (v[:, -config.horizon :] if k.startswith("observation.") else v) for k, v in window.items()}
    assert torch.allclose(policy.encode_skill(cut)[0], mean)


def test_dataset_id_changes_the_policy_output(prior_root):
    config = tiny_config(stage="policy")
    policy = build_policy(config, PRIOR_REPO, prior_root)
    history = policy._history(training_batch(config, PRIOR_REPO, prior_root))
    size = history["observation.state"].shape[0]
    z_target = policy.latent_policy(history, torch.full((size,), TARGET_ID))
    z_retrieved = policy.latent_policy(history, torch.full((size,), RETRIEVED_ID))
    assert z_target.shape == (size, config.latent_dim)
    assert not torch.allclose(z_target, z_retrieved)


def test_stage2_forward_with_retrieval_and_ablations(stage1_dir, prior_root, target_root, tmp_path):
    retrieval = write_retrieval(tmp_path / "ret.safetensors", stage1_dir, prior_root, target_root, [1, 9, 30, 77])
    prior = dict(prior_repo_id=PRIOR_REPO, prior_root=str(prior_root))
    policy = stage2_policy(stage1_dir, target_root, retrieval_path=str(retrieval), **prior).train()
    batch = training_batch(policy.config, TARGET_REPO, target_root)
    assert batch["observation.state"].shape[1] == policy.config.history + policy.config.horizon - 1
    loss, info = policy.forward(batch)
    assert {"policy_target_loss", "policy_retrieved_loss", "reconstruction_loss", "tc_loss"} <= set(info)
    assert len(policy.get_optim_params()) == 3
    loss.backward()
    assert _grad_norm(policy.latent_policy) > 0 and _grad_norm(policy.skills.decoder) > 0
    assert policy.config.skills_checkpoint_fingerprint == checkpoint_fingerprint(stage1_dir)
    policy.config.policy_supervision = "every_step"  # retrieved histories are labelled at every step too
    _, every_step = policy.forward(batch)
    assert every_step["policy_retrieved_loss"] > 0 and every_step["policy_target_loss"] > 0

    no_retrieval = stage2_policy(stage1_dir, target_root, use_retrieval=False, **prior)
    _, info = no_retrieval.forward(batch)
    assert "policy_retrieved_loss" not in info and "policy_target_loss" in info
    no_prior = stage2_policy(stage1_dir, target_root, use_retrieval=False)
    _, info = no_prior.forward(batch)
    assert "reconstruction_loss" in info and no_prior._training_data.prior is None
    frozen = stage2_policy(stage1_dir, target_root, use_retrieval=False, finetune_skills=False)
    _, info = frozen.forward(batch)
    assert "reconstruction_loss" not in info and not any(p.requires_grad for p in frozen.skills.parameters())


def test_skills_fine_tune_on_the_retrieved_windows_when_asked(stage1_dir, prior_root, target_root, tmp_path):
    """`skill_finetune_windows="retrieved"`: the skill loss's second half of windows are retrieved ones, not any
    prior window (Alg. 2, line 17, the default)."""
    chosen = [1, 9, 30, 77]
    retrieval = write_retrieval(tmp_path / "ret.safetensors", stage1_dir, prior_root, target_root, chosen)
    prior = dict(prior_repo_id=PRIOR_REPO, prior_root=str(prior_root), retrieval_path=str(retrieval))

    def skill_anchors(**settings) -> set[int]:
        policy = stage2_policy(stage1_dir, target_root, **prior, **settings).train()
        seen: list = []
        skill_loss = policy._skill_loss
        policy._skill_loss = lambda sources, **kw: seen.append(sources) or skill_loss(sources, **kw)
        policy.forward(training_batch(policy.config, TARGET_REPO, target_root))
        (_, own), (extra, source) = seen[0]
        assert own is policy._training_data.own and source is policy._training_data.prior
        return set(extra["index"].reshape(-1).tolist())

    assert skill_anchors(skill_finetune_windows="retrieved") <= set(chosen)
    assert not skill_anchors() <= set(chosen)
    with pytest.raises(ValueError, match="`skill_finetune_windows`"):
        stage2_policy(stage1_dir, target_root, use_retrieval=False, skill_finetune_windows="retrieved")
    empty = write_retrieval(tmp_path / "empty.safetensors", stage1_dir, prior_root, target_root, [])
    policy = stage2_policy(stage1_dir, target_root, **prior, skill_finetune_windows="retrieved")
    policy.config.retrieval_path = str(empty)  # a retrieval that kept nothing: the option must not fall back
    with pytest.raises(ValueError, match=r"selects no window.*skill_finetune_windows=prior"):
        policy.forward(training_batch(policy.config, TARGET_REPO, target_root))


def test_retrieved_labels_and_their_weight(stage1_dir, prior_root, target_root, tmp_path):
    """`stored` labels ignore later encoder updates, `reencode` follows them; gamma scales the retrieved loss only."""
    retrieval = write_retrieval(tmp_path / "ret.safetensors", stage1_dir, prior_root, target_root, [1, 9, 30, 77])
    policy = stage2_policy(
        stage1_dir, target_root, retrieval_path=str(retrieval), prior_repo_id=PRIOR_REPO, prior_root=str(prior_root)
    ).train()
    batch = training_batch(policy.config, TARGET_REPO, target_root)
    policy.forward(batch)  # the first forward builds the training data (and draws random numbers doing so)

    def forward(**settings) -> tuple[float, dict[str, float]]:
        for name, value in settings.items():
            setattr(policy.config, name, value)
        torch.manual_seed(0)  # the same retrieved windows and latent samples on every call
        for source in (policy._training_data.own, policy._training_data.prior):
            source.sampler.generator.manual_seed(0)  # the same prior windows and temporal pairs
        with torch.no_grad():
            loss, info = policy.forward(batch)
        return float(loss), info

    # the file's latents were encoded by this very encoder: both label sources agree before any update
    _, stored = forward(retrieved_latents="stored")
    _, reencoded = forward(retrieved_latents="reencode")
    assert stored["policy_retrieved_loss"] == pytest.approx(reencoded["policy_retrieved_loss"], rel=1e-5)
    with torch.no_grad():  # stands in for stage 2's fine-tuning of the skill encoder
        for parameter in policy.skills.encoder.parameters():
            parameter.add_(0.5 * torch.randn_like(parameter))
    _, stored_after = forward(retrieved_latents="stored")
    _, reencoded_after = forward(retrieved_latents="reencode")
    assert stored_after["policy_retrieved_loss"] == pytest.approx(stored["policy_retrieved_loss"], rel=1e-5)
    assert reencoded_after["policy_retrieved_loss"] != pytest.approx(reencoded["policy_retrieved_loss"], rel=1e-3)

    loss_1, info = forward(retrieved_weight=1.0)
    loss_3, _ = forward(retrieved_weight=3.0)
    assert loss_3 - loss_1 == pytest.approx(2.0 * info["policy_retrieved_loss"], rel=1e-4)


def test_policy_action_weight_adds_the_decoded_action_error(stage1_dir, target_root):
    """The optional action term is the policy skill's decoded error on the batch's windows (as `imitation_error`
    scores it), scaled by its weight, with a gradient that reaches the latent policy through the frozen decoder."""
    policy = stage2_policy(stage1_dir, target_root, use_retrieval=False, finetune_skills=False).train()
    batch = training_batch(policy.config, TARGET_REPO, target_root)
    latent_only, info = policy.forward(batch)
    assert "policy_action_loss" not in info

    policy.config.policy_action_weight = 2.0
    loss, info = policy.forward(batch)
    reference = float(policy.imitation_error(batch)["policy"].mean())
    assert info["policy_action_loss"] == pytest.approx(reference, rel=1e-5)
    assert float(loss - latent_only) == pytest.approx(2.0 * reference, rel=1e-4)

    def policy_gradient(weight: float) -> list[torch.Tensor]:
        policy.zero_grad()
        policy.config.policy_action_weight = weight
        policy.forward(batch)[0].backward()
        return [p.grad.clone() for p in policy.latent_policy.parameters()]

    assert any(not torch.allclose(a, b) for a, b in zip(policy_gradient(0.0), policy_gradient(1.0), strict=True))


def test_decoder_policy_weight_trains_the_decoder_on_the_policy_skills_not_the_policy(stage1_dir, target_root):
    """The optional decoder term is the policy skill's decoded error on the target windows (as `imitation_error`
    scores it), scaled by its weight; its gradient reaches the decoder but not the latent policy."""
    # tc_weight 0: the temporal pairs come from the sampler's own generator, so they differ between forwards
    policy = stage2_policy(stage1_dir, target_root, use_retrieval=False, prior_repo_id=None, tc_weight=0.0).train()
    batch = training_batch(policy.config, TARGET_REPO, target_root)
    policy.forward(batch)  # builds the training data, which draws its sampler seed from the global RNG
    torch.manual_seed(0)
    without, info = policy.forward(batch)
    assert "decoder_policy_loss" not in info

    policy.config.decoder_policy_weight = 2.0
    torch.manual_seed(0)  # the same posterior samples as `without`
    loss, info = policy.forward(batch)
    reference = float(policy.imitation_error(batch)["policy"].mean())
    assert info["decoder_policy_loss"] == pytest.approx(reference, rel=1e-5)
    assert float((loss - without).detach()) == pytest.approx(2.0 * reference, rel=1e-4)

    def gradients(weight: float, module: torch.nn.Module) -> list[torch.Tensor]:
        policy.zero_grad()
        policy.config.decoder_policy_weight = weight
        torch.manual_seed(0)
        policy.forward(batch)[0].backward()
        return [p.grad.clone() for p in module.parameters() if p.grad is not None]

    for a, b in zip(gradients(0.0, policy.latent_policy), gradients(1.0, policy.latent_policy), strict=True):
        torch.testing.assert_close(a, b)
    decoder_0, decoder_1 = gradients(0.0, policy.skills.decoder), gradients(1.0, policy.skills.decoder)
    assert any(not torch.allclose(a, b) for a, b in zip(decoder_0, decoder_1, strict=True))


def test_mixture_head_is_the_gaussian_mixture_likelihood(stage1_dir, target_root):
    """`policy_mixtures=k`: the policy loss is the mixture's negative log-likelihood of the encoder's skills, written
    out here by hand, and the skill it runs is the mean of its most probable component. Stage 2 starts from a
    stage-1 checkpoint whose (untrained) policy has the plain head."""
    policy = stage2_policy(stage1_dir, target_root, use_retrieval=False, finetune_skills=False, policy_mixtures=3)
    policy.train()
    batch = training_batch(policy.config, TARGET_REPO, target_root)
    history = policy._history(batch)
    ids = torch.full((batch["action"].shape[0],), TARGET_ID)
    labels, _ = policy.skills.encoder(policy._window(batch))
    nll, chosen = policy.latent_policy.loss(history, ids, labels)

    k, d = 3, policy.config.latent_dim
    out = policy.latent_policy._features(history, ids)
    logits, means, scales = out[:, :k], out[:, k : k + k * d].reshape(-1, k, d), out[:, k + k * d :].reshape(-1, k, d)
    std = torch.nn.functional.softplus(scales) + 1e-4
    per_component = (-0.5 * ((labels[:, None] - means) / std) ** 2 - std.log() - 0.5 * math.log(2 * math.pi)).sum(-1)
    reference = -torch.logsumexp(per_component + torch.log_softmax(logits, dim=-1), dim=-1)
    torch.testing.assert_close(nll, reference, rtol=1e-4, atol=1e-4)
    best = means[torch.arange(len(logits)), logits.argmax(-1)]
    torch.testing.assert_close(chosen, best)
    torch.testing.assert_close(policy.latent_policy(history, ids), best)
    _, info = policy.forward(batch)
    assert info["policy_target_loss"] == pytest.approx(float(nll.detach().mean()), rel=1e-4)
    # the stage-1 checkpoint's policy head has another shape: its skills load, its untrained policy is left out
    stage1 = SkillRetPolicy.from_pretrained(stage1_dir).skills.state_dict()
    for key, value in policy.skills.state_dict().items():
        torch.testing.assert_close(value, stage1[key])


@pytest.mark.parametrize("mixtures", [0, 2])
def test_every_step_supervision_labels_each_history_step_with_its_own_window(stage1_dir, target_root, mixtures):
    """`policy_supervision="every_step"`: history step t is supervised with the encoder's skill of the window that
    starts at t (LeRobot's own window there) and the LSTM's output after steps ..t (the policy run on the history cut
    at t); steps padded before the episode's start are left out. Anchors at an episode's first frames included."""
    torch.manual_seed(0)  # the fresh head is drawn from the global RNG: independent of the tests run before
    policy = stage2_policy(
        stage1_dir, target_root, use_retrieval=False, finetune_skills=False, policy_mixtures=mixtures
    ).train()
    config, history = policy.config, policy.config.history
    episodes = LeRobotDataset(TARGET_REPO, root=target_root).hf_dataset["episode_index"]
    episodes = torch.as_tensor([int(e) for e in episodes])
    second_start = int((episodes == 1).nonzero()[0])
    anchors = [0, 1, 7, second_start, second_start + 1, second_start + 9]
    batch = batch_at(config, TARGET_REPO, target_root, anchors)
    ids = torch.full((len(anchors),), TARGET_ID)

    config.policy_supervision = "every_step"
    info = policy.forward(batch)[1]
    config.policy_supervision = "last"
    last_only = policy.forward(batch)[1]

    with torch.no_grad():
        full = policy._history(batch)
        per_sample = []
        for b, anchor in enumerate(anchors):
            terms = []
            for t in range(history):
                start = anchor - (history - 1) + t
                if start < 0 or episodes[start] != episodes[anchor]:
                    continue
                label, _ = policy.encode_skill(batch_at(config, TARGET_REPO, target_root, [start]))
                cut = {key: value[b : b + 1, : t + 1] for key, value in full.items()}
                terms.append(policy.latent_policy.loss(cut, ids[:1], label)[0])
            per_sample.append(torch.cat(terms).mean())
    assert info["policy_target_loss"] == pytest.approx(float(torch.stack(per_sample).mean()), rel=1e-4)
    # an untrained mixture's likelihood hardly depends on the step, so the two differ by ~5e-4: checked at the
    # precision of the equality above
    assert info["policy_target_loss"] != pytest.approx(last_only["policy_target_loss"], rel=1e-4)


def test_policy_obs_noise_perturbs_only_the_training_history(stage1_dir, target_root):
    """The noise reaches the low-dim history at the configured scale (normalised units); rollouts and the held-out
    score see clean observations."""
    policy = stage2_policy(stage1_dir, target_root, use_retrieval=False, finetune_skills=False, policy_obs_noise=0.5)
    batch = training_batch(policy.config, TARGET_REPO, target_root)
    clean = policy._history(batch)
    for key in policy.low_dim_keys:  # 20 draws of the batch's history: the std estimate is within ~1.5 %, not ~6 %
        noise = torch.stack([policy._noisy_history(batch)[key] - clean[key] for _ in range(20)])
        assert float(noise.std()) == pytest.approx(0.5, rel=0.1)
    policy.train()
    assert policy.forward(batch)[1]["policy_loss"] != policy.forward(batch)[1]["policy_loss"]
    policy.eval()
    torch.testing.assert_close(policy.imitation_error(batch)["policy"], policy.imitation_error(batch)["policy"])
    policy.config.policy_obs_noise = 0.0
    policy.train()
    assert policy.forward(batch)[1]["policy_loss"] == policy.forward(batch)[1]["policy_loss"]


def test_imitation_error_scores_the_policy_against_the_oracle_skill(stage1_dir, target_root, monkeypatch):
    policy = stage2_policy(stage1_dir, target_root, use_retrieval=False, finetune_skills=False).eval()
    frames = LeRobotDatasetMetadata(TARGET_REPO, root=target_root).total_frames
    window = batch_at(policy.config, TARGET_REPO, target_root, [0, 5, frames - 2])  # the last one runs past its end
    assert window["action_is_pad"][2].any()
    errors = policy.imitation_error(window)
    assert errors["policy"].shape == errors["oracle"].shape == (3,)
    assert (errors["policy"] >= 0).all() and (errors["oracle"] >= 0).all()
    assert not torch.allclose(errors["policy"], errors["oracle"])  # an untrained latent policy is not the oracle

    # padded steps past the episode's end do not count
    changed = dict(window, action=window["action"].clone())
    changed["action"][window["action_is_pad"]] += 5.0
    torch.testing.assert_close(policy.imitation_error(changed)["oracle"], errors["oracle"])
    torch.testing.assert_close(policy.imitation_error(changed)["mean_action"], errors["mean_action"])
    # `mean_action`: the valid steps' mean normalised action held constant, checked against numpy
    normalised = policy._window(window)
    actions, valid = normalised["action"].numpy(), normalised["valid"].numpy()
    mean = actions[valid].mean(axis=0)
    expected = [((actions[i][valid[i]] - mean) ** 2).sum(axis=-1).mean() for i in range(3)]
    np.testing.assert_allclose(errors["mean_action"].numpy(), expected, rtol=1e-5)
    # a policy that picked exactly the oracle's skills would score the oracle's error
    monkeypatch.setattr(policy.latent_policy, "forward", lambda history, ids: policy.encode_skill(window)[0])
    torch.testing.assert_close(policy.imitation_error(window)["policy"], errors["oracle"])

    # `shuffled` decodes other windows' oracle skills: it scores the oracle's error only if the decoder ignores z
    assert not torch.allclose(errors["shuffled"], errors["oracle"])
    with torch.no_grad():
        policy.skills.decoder.lstm.weight_ih_l0[:, : policy.config.latent_dim] = 0.0  # z's input weights
    blind = policy.imitation_error(window)
    torch.testing.assert_close(blind["shuffled"], blind["oracle"])


def test_stage2_refuses_bad_retrieval_setups(stage1_dir, prior_root, target_root, tmp_path):
    batch = training_batch(tiny_config(stage="policy"), TARGET_REPO, target_root)
    with pytest.raises(ValueError, match="prior_repo_id"):
        stage2_policy(stage1_dir, target_root).forward(batch)
    with pytest.raises(ValueError, match="retrieval_path"):
        stage2_policy(stage1_dir, target_root, prior_repo_id=PRIOR_REPO, prior_root=str(prior_root)).forward(batch)
    wrong = write_retrieval(tmp_path / "wrong.safetensors", stage1_dir, prior_root, prior_root, [1, 2])
    with pytest.raises(ValueError, match="different target dataset"):
        stage2_policy(
            stage1_dir, target_root, prior_repo_id=PRIOR_REPO, prior_root=str(prior_root), retrieval_path=str(wrong)
        ).forward(batch)


def test_bf16_autocast_keeps_losses_latents_and_actions_float32(stage1_dir, prior_root, target_root, tmp_path):
    """`--policy.use_amp=true` runs the forward under CPU bf16 autocast (LeRobot's Accelerator in lerobot-train,
    torch.autocast in lerobot-eval): the arithmetic is bf16, but the losses, the latents that labels and the
    retrieval file are made of, and the actions sent to the env (numpy has no bf16) must be float32."""
    retrieval = write_retrieval(tmp_path / "ret.safetensors", stage1_dir, prior_root, target_root, [1, 9, 30, 77])
    policy = stage2_policy(
        stage1_dir, target_root, retrieval_path=str(retrieval), prior_repo_id=PRIOR_REPO, prior_root=str(prior_root)
    ).train()
    batch = training_batch(policy.config, TARGET_REPO, target_root)
    torch.manual_seed(0)  # the window samplers seed from torch's RNG: the same windows in both passes
    _, full_info = policy.forward(batch)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        torch.manual_seed(0)
        policy._training_data = None
        loss, info = policy.forward(batch)
        lstm = policy.skills.decoder.lstm
        # the autocast really runs the LSTMs in bf16, where this CPU's oneDNN can (run_lstm: float32 where not)
        expected = torch.bfloat16 if networks._onednn_runs_bf16() else torch.float32
        assert networks.run_lstm(lstm, torch.zeros(1, 2, lstm.input_size))[0].dtype == expected
        mean, _ = policy.encode_skill(batch)
        policy.reset()
        action = policy.select_action({key: batch[key][:, -1] for key in policy.observation_keys})
    assert loss.dtype == mean.dtype == action.dtype == torch.float32
    assert set(info) == set(full_info)
    for name, value in info.items():  # the same losses up to bf16's rounding
        assert value == pytest.approx(full_info[name], rel=0.1, abs=1e-3), name
    loss.backward()
    assert all(p.grad.dtype == torch.float32 for p in policy.parameters() if p.grad is not None)
    assert _grad_norm(policy.latent_policy) > 0 and _grad_norm(policy.skills.encoder) > 0


def test_use_amp_trains_on_a_cpu_without_onednn_bf16(stage1_dir, target_root, monkeypatch):
    """CPU autocast hands nn.LSTM to oneDNN, which has no bf16 LSTM without AVX-512: `--policy.use_amp=true` crashed
    there ("could not create a primitive descriptor"). Such a CPU's LSTMs run in float32, the rest in bf16."""
    monkeypatch.setattr(networks, "_onednn_runs_bf16", lambda: False)
    policy = stage2_policy(stage1_dir, target_root, use_retrieval=False).train()
    batch = training_batch(policy.config, TARGET_REPO, target_root)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        loss, _ = policy.forward(batch)
        lstm = policy.skills.decoder.lstm
        state = (torch.zeros(2, 1, lstm.hidden_size, dtype=torch.bfloat16),) * 2
        outputs, (h, c) = networks.run_lstm(lstm, torch.zeros(1, 2, lstm.input_size, dtype=torch.bfloat16), state)
    assert outputs.dtype == h.dtype == c.dtype == torch.float32
    loss.backward()
    assert torch.isfinite(loss) and _grad_norm(policy.skills.decoder) > 0


@pytest.mark.parametrize("skill_steps", [None, 3])
def test_select_action_runs_skills_closed_loop(prior_root, skill_steps):
    config = tiny_config(skill_steps=skill_steps)
    policy = build_policy(config, PRIOR_REPO, prior_root)
    batch = training_batch(config, PRIOR_REPO, prior_root, size=2)
    policy.reset()
    calls = []
    original = policy.latent_policy.forward
    policy.latent_policy.forward = lambda *a: calls.append(1) or original(*a)
    actions = []
    for step in range(2 * config.horizon + 1):
        observation = {key: batch[key][:, 0] + 0.01 * step for key in policy.observation_keys}
        actions.append(policy.select_action(observation))
    assert actions[0].shape == (2, 7)
    every = skill_steps or config.horizon  # a new skill at steps 0, H, 2H (by default)
    assert len(calls) == -(-(2 * config.horizon + 1) // every)
    chunk = policy.predict_action_chunk(observation)
    assert chunk.shape == (2, config.horizon, 7)
    assert len(policy._history_frames) == config.history
    assert policy._steps_left == -(2 * config.horizon + 1) % every
    with pytest.raises(ValueError, match="skill_steps"):
        tiny_config(skill_steps=config.horizon + 1)


def test_rollout_steps_reproduce_the_decoders_training_pass(prior_root):
    """Rollouts run the decoder cell by cell (`lstm_steps`), training runs `nn.LSTM` over the whole window: given the
    same skill and the window's own observations, the H actions must agree, or rollouts execute other skills than
    the trained ones (and the oracle diagnostics would blame the wrong stage)."""
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root).eval()
    sampler = WindowSampler(EpisodeColumns.from_dataset(PRIOR_REPO, prior_root), config.history, config.horizon)
    raw = sampler.gather(torch.arange(0, 40, 7))
    with torch.no_grad():
        skill = policy.encode_skill(raw)[0]
        trained, _ = policy.skills.decoder(skill, policy._window(raw))
    policy.reset()
    policy.execute_skill(skill)
    steps = [
        policy.select_action({key: raw[key][:, t - config.horizon] for key in policy.observation_keys})
        for t in range(config.horizon)
    ]
    rolled = policy.normalizer.normalize("action", torch.stack(steps, dim=1))
    torch.testing.assert_close(rolled, trained, atol=1e-5, rtol=0)


def test_execute_skill_decodes_the_given_skill_like_the_policy_path(prior_root):
    """Oracle-skill diagnostics go through the same decoder path as the policy's own choice."""
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root)
    batch = training_batch(config, PRIOR_REPO, prior_root, size=2)
    observation = {key: batch[key][:, 0] for key in policy.observation_keys}
    policy.reset()
    own = policy.select_action(observation)
    chosen = policy._skill.clone()
    policy.reset()
    policy.execute_skill(chosen)
    assert torch.equal(policy.select_action(observation), own)
    policy.reset()
    policy.execute_skill(chosen + 1.0)
    assert not torch.allclose(policy.select_action(observation), own)
    assert policy._steps_left == config.horizon - 1


def test_decoder_scaling_is_the_stage1_one(stage1_dir, target_root):
    """A stage-2 policy built with the TARGET stats (as lerobot-train does) acts exactly like the stage-1 one,
    and the processors LeRobot rebuilds with target stats stay identities."""
    stage1 = SkillRetPolicy.from_pretrained(stage1_dir)
    stage2 = stage2_policy(stage1_dir, target_root, use_retrieval=False).eval()
    meta = LeRobotDatasetMetadata(TARGET_REPO, root=target_root)
    assert not torch.allclose(
        torch.as_tensor(meta.stats["action"]["max"]).float(),
        stage1.normalizer.action_scale + stage1.normalizer.action_shift,
    )
    observation = {key: torch.randn(3, *stage1.config.input_features[key].shape) for key in stage1.observation_keys}
    stage1.reset()
    stage2.reset()
    with pytest.warns(UserWarning, match="stage-1 .* latent policy is untrained"):  # evaluating it measures nothing
        for _ in range(6):
            assert torch.equal(stage1.select_action(observation), stage2.select_action(observation))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        stage2.reset()
        stage2.select_action(observation)  # a stage-2 policy picks its skills without a warning

    config = stage2.config
    pre, post = make_skillret_pre_post_processors(config, dataset_stats=meta.stats)
    # what lerobot-train does with --policy.path: override the normaliser steps with the new dataset's stats
    folder = stage1_dir.parent / "processors"
    pre.save_pretrained(folder)
    post.save_pretrained(folder)
    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.processor.converters import policy_action_to_transition, transition_to_policy_action

    features = {**config.input_features, **config.output_features}
    pre = PolicyProcessorPipeline.from_pretrained(
        folder,
        "policy_preprocessor.json",
        overrides={
            "normalizer_processor": {
                "stats": meta.stats,
                "features": features,
                "norm_map": config.normalization_mapping,
            },
            "device_processor": {"device": "cpu"},
            "rename_observations_processor": {"rename_map": {}},
        },
    )
    post = PolicyProcessorPipeline.from_pretrained(
        folder,
        "policy_postprocessor.json",
        overrides={
            "unnormalizer_processor": {
                "stats": meta.stats,
                "features": config.output_features,
                "norm_map": config.normalization_mapping,
            }
        },
        to_transition=policy_action_to_transition,
        to_output=transition_to_policy_action,
    )
    processed = pre(dict(observation))
    for key, value in observation.items():
        assert torch.equal(processed[key], value)
    action = torch.randn(3, 7)
    assert torch.equal(post(action), action)


@pytest.mark.parametrize("change", [{"ACTION": NormalizationMode.MEAN_STD}, {"STATE": NormalizationMode.IDENTITY}])
def test_a_checkpoint_refuses_another_normalisation_mode(stage1_dir, target_root, change):
    """Stage 1 fixes each feature's mode; a stage-2 override of it (same buffer names, or buffers left unused)
    must fail at load instead of swapping the decoder's head or feeding raw states silently."""
    stage1 = SkillRetPolicy.from_pretrained(stage1_dir)
    mapping = {**stage1.config.skill_normalization_mapping, **change}
    assert mapping != stage1.config.skill_normalization_mapping
    with pytest.raises(RuntimeError, match=r"the checkpoint normalises .* but the config asks for"):
        stage2_policy(stage1_dir, target_root, skill_normalization_mapping=mapping)


def test_a_checkpoint_without_recorded_modes_still_loads_and_checks_its_features():
    """Checkpoints saved before the modes were recorded load (assuming the config's modes), but one whose
    normalised features differ from the config's is still refused."""
    features = {
        "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(2,)),
        "action": PolicyFeature(type=FeatureType.ACTION, shape=(2,)),
    }
    stats = {key: {"mean": [0.0, 1.0], "std": [1.0, 2.0], "min": [-1.0, 0.0], "max": [1.0, 4.0]} for key in features}
    mapping = {"STATE": NormalizationMode.MEAN_STD, "ACTION": NormalizationMode.MEAN_STD}
    legacy = {k: v for k, v in SkillNormalizer(features, mapping, stats).state_dict().items() if "_mode" not in k}
    loaded = SkillNormalizer(features, mapping)
    loaded.load_state_dict(legacy, strict=False)
    assert torch.equal(loaded.action_scale, torch.tensor([1.0, 2.0]))
    with pytest.raises(RuntimeError, match="unrecorded"):
        SkillNormalizer(features, {**mapping, "STATE": NormalizationMode.IDENTITY}).load_state_dict(
            legacy, strict=False
        )


def test_cameras_train_both_stages_and_act(tmp_path):
    """With a camera, the windows the policy fetches itself (temporal pairs, prior windows) carry its frames too,
    and both stages train and act (8x8 images: the encoder itself is tested on larger ones below)."""
    root = make_synthetic_dataset(tmp_path / "ds", PRIOR_REPO, num_episodes=2, max_len=20, with_images=True)
    config = tiny_config(crop_shape=(6, 6))
    policy = build_policy(config, PRIOR_REPO, root)
    assert policy.image_keys == ["observation.images.agentview"]
    loss, info = policy.forward(training_batch(config, PRIOR_REPO, root, size=2))
    loss.backward()
    assert info["tc_loss"] > 0 and _grad_norm(policy.skills.encoder.obs_encoder.low_dim_net) > 0

    two = build_policy(
        tiny_config(
            crop_shape=(6, 6),
            stage="policy",
            use_retrieval=False,
            prior_repo_id=PRIOR_REPO,
            prior_root=str(root),
            video_backend="pyav",
        ),
        PRIOR_REPO,
        root,
    )
    loss, info = two.forward(training_batch(two.config, PRIOR_REPO, root, size=2))
    assert "policy_target_loss" in info and torch.isfinite(loss)
    for source in (
        two._training_data.own,
        two._training_data.prior,
    ):  # --policy.video_backend reaches the frames it decodes
        assert source.sampler.frames.dataset._video_backend == "pyav"
    two.reset()
    batch = training_batch(two.config, PRIOR_REPO, root, size=2)
    observation = {key: batch[key][:, 0] for key in two.observation_keys}
    assert two.select_action(observation).shape == (2, 7)


def test_rollout_decoder_step_matches_the_training_decoder(prior_root):
    """select_action's single-step decoder (lstm_cell, state carried) computes what training's nn.LSTM computes."""
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root).eval()
    window = policy._window(training_batch(config, PRIOR_REPO, prior_root, size=3))
    z = torch.randn(3, config.latent_dim)
    with torch.no_grad():
        expected, _ = policy.skills.decoder(z, window)
        state = None
        for t in range(config.horizon):
            action, state = policy.skills.decoder.step(z, {k: window[k][:, t] for k in policy.observation_keys}, state)
            assert torch.allclose(action, expected[:, t], atol=1e-6)


def test_observation_encoder_cameras_crop_and_learn():
    """ResNet-18 + spatial softmax per camera, concatenated after the low-dim MLP; random crop in training,
    centre crop at inference; gradients reach the backbone."""
    encoder = ObservationEncoder({"observation.state": (6,)}, {"cam": (3, 64, 64)}, (16,), (56, 56), 8, "resnet18")
    assert encoder.out_dim == 16 + 2 * 8
    observation = {"observation.state": torch.randn(2, 3, 6), "cam": torch.rand(2, 3, 3, 64, 64)}
    out = encoder(observation)
    assert out.shape == (2, 3, 32)
    out.pow(2).sum().backward()
    assert _grad_norm(encoder.cameras[0].trunk) > 0
    encoder.eval()
    assert torch.equal(encoder(observation), encoder(observation))  # centre crop: deterministic
    images = torch.arange(2 * 3 * 10 * 10, dtype=torch.float32).reshape(2, 3, 10, 10)
    crops = random_crop(images, (4, 4), torch.Generator().manual_seed(0))
    assert crops.shape == (2, 3, 4, 4)
    for crop, image in zip(crops, images, strict=True):  # each crop is a contiguous window of its own image
        top, left = divmod(int(crop[0, 0, 0] - image[0, 0, 0]), 10)
        assert torch.equal(crop, image[:, top : top + 4, left : left + 4])
    assert torch.equal(center_crop(images, (4, 4)), images[..., 3:7, 3:7])


def test_configured_vision_backbone_is_the_one_built():
    """`vision_backbone` picks the torchvision ResNet each camera trains (ResNet-50's bottleneck trunk ends in 2048
    channels, ResNet-18's in 512)."""
    shapes = ({"observation.state": (6,)}, {"cam": (3, 64, 64)})
    for backbone, channels in (("resnet18", 512), ("resnet50", 2048)):
        encoder = make_observation_encoder(SkillRetConfig(device="cpu", vision_backbone=backbone), *shapes)
        assert encoder.cameras[0].trunk.eval()(torch.rand(1, 3, 64, 64)).shape[1] == channels


def test_implementation_only_extras_add_their_terms(prior_root):
    """Slowness (nearby windows' means agree) and the inverse-dynamics head, off by default, are real losses."""
    config = tiny_config(slowness_weight=1e-3, inverse_dynamics_weight=0.1)
    policy = build_policy(config, PRIOR_REPO, prior_root)
    loss, info = policy.forward(training_batch(config, PRIOR_REPO, prior_root))
    assert info["slowness_loss"] > 0 and info["inverse_dynamics_loss"] > 0
    loss.backward()
    assert _grad_norm(policy.skills.inverse_dynamics) > 0
    assert (
        "slowness_loss"
        not in build_policy(tiny_config(), PRIOR_REPO, prior_root).forward(
            training_batch(config, PRIOR_REPO, prior_root)
        )[1]
    )


@pytest.mark.parametrize("stage", ["skills", "policy"])
def test_fast_windows_equal_lerobots_windows(prior_root, stage):
    """`fast_windows`: LeRobot loads anchor frames only; the windows the policy gathers by `index` are the ones
    LeRobot's delta_timestamps would have built (values and pad masks), so the losses see the same data."""
    indices = [0, 3, 37, 38, 70, 110]  # episode starts and ends included: both kinds of padding
    fast = build_policy(tiny_config(stage=stage, fast_windows=True, use_retrieval=False), PRIOR_REPO, prior_root)
    assert fast.config.observation_delta_indices is None and fast.config.action_delta_indices is None
    frames = batch_at(fast.config, PRIOR_REPO, prior_root, indices)
    assert frames["observation.state"].ndim == 2
    gathered = fast._data(frames["index"]).own.gather(frames["index"], "cpu")
    standard = build_policy(tiny_config(stage=stage), PRIOR_REPO, prior_root).config
    reference = batch_at(standard, PRIOR_REPO, prior_root, indices)
    for key in ("observation.state", "observation.environment_state", "action", "action_is_pad"):
        assert torch.equal(gathered[key], reference[key]), key
    loss, info = fast.forward(frames)
    assert torch.isfinite(loss) and info
    with pytest.raises(ValueError, match="fast_windows"):
        config = tiny_config(fast_windows=True)
        config.input_features = {"observation.images.cam": PolicyFeature(FeatureType.VISUAL, (3, 8, 8))}
        config.output_features = {"action": PolicyFeature(FeatureType.ACTION, (7,))}
        config.validate_features()


def test_training_windows_repeat_under_the_same_seed(prior_root):
    """The policy's own window draws (temporal pairs) follow torch's global seed, which `--seed` sets."""

    def first_loss(seed: int) -> float:
        torch.manual_seed(seed)
        policy = build_policy(tiny_config(), PRIOR_REPO, prior_root)
        loss, _ = policy.forward(training_batch(policy.config, PRIOR_REPO, prior_root))
        return float(loss)

    assert first_loss(3) == first_loss(3)
    assert first_loss(3) != first_loss(4)


def test_min_max_margin_keeps_the_data_range_inside_tanh():
    """With margin m the action range maps onto [-(1 - m), 1 - m], and the round trip is exact."""
    features = {"action": PolicyFeature(type=FeatureType.ACTION, shape=(2,))}
    stats = {"action": {"min": [-1.0, 0.0], "max": [1.0, 4.0]}}
    norm = SkillNormalizer(features, {"ACTION": NormalizationMode.MIN_MAX}, stats, min_max_margin=0.05)
    extremes = torch.tensor([[-1.0, 0.0], [1.0, 4.0]])
    assert torch.allclose(norm.normalize("action", extremes), torch.tensor([[-0.95, -0.95], [0.95, 0.95]]))
    assert torch.allclose(norm.unnormalize("action", norm.normalize("action", extremes)), extremes)
    with pytest.raises(ValueError, match="min_max_margin"):
        tiny_config(min_max_margin=1.0)


@pytest.mark.parametrize("mode", [NormalizationMode.MIN_MAX, NormalizationMode.MEAN_STD])
def test_the_decoders_output_range_follows_the_action_normalisation(prior_root, mode):
    """MIN_MAX actions: tanh decoder and targets clipped to [-1, 1] (the paper). MEAN_STD: a linear head and
    targets kept as they are, so actions beyond one std are neither clipped nor out of the decoder's reach."""
    mapping = {**tiny_config().skill_normalization_mapping, "ACTION": mode}
    policy = build_policy(tiny_config(skill_normalization_mapping=mapping), PRIOR_REPO, prior_root)
    raw = training_batch(policy.config, PRIOR_REPO, prior_root, size=2)
    far = policy.normalizer.unnormalize("action", torch.full_like(raw["action"], 3.0))  # 3 units out
    window = policy._window({**raw, "action": far})

    last = policy.skills.decoder.head[-1]
    torch.nn.init.zeros_(last.weight)
    torch.nn.init.constant_(last.bias, 3.0)
    decoded, _ = policy.skills.decoder(torch.zeros(2, policy.config.latent_dim), window)

    bounded = mode is NormalizationMode.MIN_MAX
    assert torch.allclose(window["action"], torch.full_like(window["action"], 1.0 if bounded else 3.0))
    assert torch.allclose(decoded, torch.full_like(decoded, float(torch.tanh(torch.tensor(3.0))) if bounded else 3.0))
    assert policy.config.bounded_actions is bounded


def test_each_dataset_id_conditions_its_own_windows(stage1_dir, prior_root, target_root, tmp_path):
    """Target windows are labelled with the target id, retrieved windows with the retrieved id (guards retrieved
    windows trained as if they were target data, which makes the id meaningless at rollout)."""
    retrieval = write_retrieval(tmp_path / "ret.safetensors", stage1_dir, prior_root, target_root, [1, 9, 30, 77])
    policy = stage2_policy(
        stage1_dir, target_root, retrieval_path=str(retrieval), prior_repo_id=PRIOR_REPO, prior_root=str(prior_root)
    )
    batch = training_batch(policy.config, TARGET_REPO, target_root, size=5)
    calls = []
    original = policy.latent_policy.loss
    policy.latent_policy.loss = lambda history, ids, labels, valid=None: (
        calls.append(ids.tolist()) or original(history, ids, labels, valid)
    )
    policy.forward(batch)
    assert calls == [[TARGET_ID] * 5, [RETRIEVED_ID] * 5]


def test_stage2_names_target_dimensions_far_outside_the_skills_training_data(prior_root, caplog):
    """The prior's skills never saw inputs that far out (the bread spinning on the plate read 100 stds out): stage
    2 says which dimensions, largest first; the stage-1 data itself passes."""
    from types import SimpleNamespace

    policy = build_policy(tiny_config(), PRIOR_REPO, prior_root)
    columns = EpisodeColumns.from_dataset(PRIOR_REPO, prior_root)
    assert policy.warn_outside_skills_range(columns, prior_root) == []
    env = "observation.environment_state"
    shifted = columns.td[env].clone()
    shifted[3, 2] += 100.0
    shifted[5, 1] += 30.0
    target = SimpleNamespace(td={**{k: columns.td[k] for k in policy.low_dim_keys}, env: shifted})
    with caplog.at_level("WARNING"):
        outside = policy.warn_outside_skills_range(target, prior_root)
    assert [name.split(" ")[0] for name in outside] == [f"{env}[2]", f"{env}[1]"]
    assert f"{env}[2]" in caplog.text and "same simulator version" in caplog.text
