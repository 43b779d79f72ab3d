"""Retrieval modes (A.4) and the options beyond the paper, on latents (no checkpoint needed)."""

from __future__ import annotations

import pytest
import torch

from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
from lerobot_skillret.retrieval.engine import select_windows
from lerobot_skillret.retrieval.settings import ABLATIONS, RetrievalSettings, ablation


def latents(num_prior=2000, num_target=60, dim=8, seed=0):
    generator = torch.Generator().manual_seed(seed)
    return torch.randn(num_prior, dim, generator=generator), torch.randn(num_target, dim, generator=generator)


def episodes(num_frames, length):
    """Per-frame episode bounds for consecutive episodes of `length` frames."""
    frames = torch.arange(num_frames)
    start = (frames // length) * length
    return frames, start, torch.clamp(start + length, max=num_frames)


def test_nearest_mode_is_the_exact_top_fraction():
    prior, target = latents()
    settings = RetrievalSettings(fraction=0.1).resolve()
    selection = select_windows(prior, target, settings)
    reference = torch.cdist(prior.double(), target.double()).amin(1)
    assert len(selection.retrieved) == 200
    assert set(selection.retrieved.tolist()) == set(torch.sort(reference).indices[:200].tolist())
    torch.testing.assert_close(selection.distance, reference, rtol=1e-4, atol=1e-4)
    assert torch.all(torch.diff(selection.distance[selection.retrieved]) >= 0)
    nearest = torch.cdist(prior.double(), target.double()).argmin(1)
    assert torch.equal(selection.nearest, nearest[selection.retrieved])
    assert selection.cut == pytest.approx(float(torch.sort(reference).values[199]), rel=1e-6)


@pytest.mark.parametrize(
    ("mode", "fraction", "expected"), [("random", 0.1, 200), ("all", None, 2000), ("none", None, 0)]
)
def test_ablation_modes_counts(mode, fraction, expected):
    prior, target = latents()
    selection = select_windows(prior, target, RetrievalSettings(mode=mode, fraction=fraction).resolve())
    assert len(selection.retrieved) == expected
    assert len(set(selection.retrieved.tolist())) == expected


def test_random_mode_is_seeded_and_worse_than_nearest():
    prior, target = latents()
    random_a = select_windows(prior, target, RetrievalSettings(mode="random", seed=1).resolve())
    random_b = select_windows(prior, target, RetrievalSettings(mode="random", seed=1).resolve())
    random_c = select_windows(prior, target, RetrievalSettings(mode="random", seed=2).resolve())
    nearest = select_windows(prior, target, RetrievalSettings().resolve())
    assert torch.equal(random_a.retrieved, random_b.retrieved)
    assert not torch.equal(random_a.retrieved, random_c.retrieved)
    assert random_a.distance[random_a.retrieved].mean() > 1.2 * nearest.distance[nearest.retrieved].mean()


def reference_greedy(order, count, anchors, start, nearest, radius, quota):
    """Direct transcription of the rules: quadratic, obviously right."""
    kept = []
    for i in order.tolist():
        if radius and any(start[i] == start[j] and abs(int(anchors[i]) - int(anchors[j])) <= radius for j in kept):
            continue
        if quota is not None and sum(int(nearest[j]) == int(nearest[i]) for j in kept) >= quota:
            continue
        kept.append(i)
        if len(kept) == count:
            break
    return kept


@pytest.mark.parametrize(("radius", "quota"), [(3, None), (0, 2), (5, 4)])
def test_suppression_and_quota_match_the_reference_greedy(radius, quota):
    prior, target = latents(num_prior=600, num_target=20)
    anchors, start, end = episodes(600, 37)
    settings = RetrievalSettings(fraction=0.2, nms_radius=radius, target_quota=quota).resolve()
    selection = select_windows(prior, target, settings, anchors=anchors, episode_start=start, episode_end=end)
    order = torch.sort(selection.distance, stable=True).indices
    nearest = torch.cdist(prior.double(), target.double()).argmin(1)
    expected = reference_greedy(order, 120, anchors, start, nearest, radius, quota)
    assert sorted(selection.retrieved.tolist()) == sorted(expected)
    assert len(selection.retrieved) == min(120, len(expected))
    picked = selection.retrieved
    if radius:
        same_episode = start[picked][:, None] == start[picked][None, :]
        close = (anchors[picked][:, None] - anchors[picked][None, :]).abs() <= radius
        assert not torch.any(same_episode & close & ~torch.eye(len(picked), dtype=torch.bool))
    if quota is not None:
        assert torch.equal(selection.nearest, nearest[picked])
        assert torch.bincount(selection.nearest).max() <= quota


def test_suppression_keeps_the_count_when_it_can():
    prior, target = latents(num_prior=1000, num_target=10)
    anchors, start, end = episodes(1000, 100)
    settings = RetrievalSettings(fraction=0.1, nms_radius=2).resolve()
    selection = select_windows(prior, target, settings, anchors=anchors, episode_start=start, episode_end=end)
    assert len(selection.retrieved) == 100


def test_importance_weighting_prefers_target_like_windows_that_are_rare_in_the_prior():
    """Targets sit half on a behaviour that fills 90% of the prior, half on one that fills 10%. Plain distance
    retrieves mostly the common behaviour; the density ratio shifts the budget towards the rare one."""
    generator = torch.Generator().manual_seed(0)
    common = torch.randn(1800, 4, generator=generator)
    rare = torch.randn(200, 4, generator=generator) + torch.tensor([6.0, 0, 0, 0])
    prior = torch.cat([common, rare])
    target = torch.cat([common[:30], rare[:30]]) + 0.05 * torch.randn(60, 4, generator=generator)
    plain = select_windows(prior, target, RetrievalSettings(fraction=0.1).resolve())
    weighted = select_windows(prior, target, RetrievalSettings(fraction=0.1, importance=True).resolve())
    rare_share = lambda s: float((s.retrieved >= 1800).float().mean())  # noqa: E731
    assert rare_share(weighted) > rare_share(plain) + 0.15
    assert weighted.score is not None and len(weighted.retrieved) == 200


def test_kl_metric_through_select_windows():
    prior, target = latents(num_prior=500, num_target=30)
    generator = torch.Generator().manual_seed(9)
    prior_lv, target_lv = -torch.rand(500, 8, generator=generator), -torch.rand(30, 8, generator=generator)
    settings = RetrievalSettings(metric="kl").resolve()
    selection = select_windows(prior, target, settings, prior_log_var=prior_lv, target_log_var=target_lv)
    v1, v2 = prior_lv.double().exp()[:, None], target_lv.double().exp()[None]
    diff2 = (prior.double()[:, None] - target.double()[None]) ** 2
    sym_kl = 0.25 * (v1 / v2 + v2 / v1 + diff2 * (1 / v1 + 1 / v2) - 2).sum(-1)
    reference = sym_kl.amin(1)
    assert set(selection.retrieved.tolist()) == set(torch.sort(reference).indices[:50].tolist())
    torch.testing.assert_close(selection.distance, reference, rtol=1e-4, atol=1e-4)


def test_settings_defaults_come_from_the_checkpoint_config():
    config = SkillRetConfig(
        retrieval_fraction=0.05, retrieval_metric="kl", retrieval_num_prior=None, retrieval_num_target=100
    )
    resolved = RetrievalSettings().resolve(config)
    assert (resolved.fraction, resolved.metric, resolved.num_prior, resolved.num_target) == (0.05, "kl", "all", 100)
    assert RetrievalSettings(fraction=0.2).resolve(config).fraction == 0.2
    paper = RetrievalSettings().resolve()
    assert (paper.fraction, paper.metric, paper.num_prior, paper.num_target) == (0.1, "l2", 250_000, 2_500)
    every = RetrievalSettings(mode="all").resolve(config)
    assert (every.fraction, every.num_prior) == (1.0, "all")
    assert set(ABLATIONS) == {"ours", "none", "all", "random", "r2", "r50", "r90", "large"}
    assert ablation("large").resolve().num_prior == "all"
    assert ablation("r90").resolve().fraction == 0.9


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"fraction": 1.5}, r"`fraction`=1.5 is invalid"),
        ({"fraction": -0.1}, r"`fraction`=-0.1 is invalid"),
        ({"mode": "best"}, "choose one of"),
        ({"metric": "cosine"}, "choose one of"),
        ({"num_prior": 0}, "N must be >= 1"),
        ({"num_target": 0}, "M must be >= 1"),
        ({"nms_radius": -1}, "suppression radius"),
        ({"target_quota": 0}, "quota is >= 1"),
        ({"mode": "random", "importance": True}, "needs mode 'nearest'"),
        ({"mode": "all", "fraction": 0.5}, "mode 'all' retrieves every prior window"),
    ],
)
def test_bad_settings_have_clear_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        RetrievalSettings(**kwargs).resolve()
    with pytest.raises(ValueError, match="Unknown retrieval ablation"):
        ablation("best")
