"""Retrieval modes (A.4) and settings, on latents (no checkpoint needed)."""

from __future__ import annotations

import pytest
import torch

from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
from lerobot_skillret.retrieval.api import select_windows
from lerobot_skillret.retrieval.settings import ABLATIONS, MODES, RetrievalSettings, ablation


def latents(num_prior=2000, num_target=60, dim=8, seed=0):
    generator = torch.Generator().manual_seed(seed)
    return torch.randn(num_prior, dim, generator=generator), torch.randn(num_target, dim, generator=generator)


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
    assert set(ABLATIONS) == {"nearest", "none", "all", "random", "r2", "r50", "r90", "large"}
    assert ablation("nearest") == RetrievalSettings()
    assert all(ablation(mode).mode == mode for mode in MODES)  # a row that is a mode has the mode's name
    assert ablation("large").resolve().num_prior == "all"
    assert ablation("r90").resolve().fraction == 0.9


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"fraction": 1.5}, r"`fraction`=1.5 is invalid"),
        ({"fraction": -0.1}, r"`fraction`=-0.1 is invalid"),
        ({"fraction": 0.0}, r"`fraction`=0.0 is invalid: .* in \(0, 1\]"),
        ({"mode": "best"}, "choose one of"),
        ({"metric": "cosine"}, "choose one of"),
        ({"num_prior": 0}, "N must be >= 1"),
        ({"num_target": 0}, "M must be >= 1"),
        ({"mode": "all", "fraction": 0.5}, "mode 'all' retrieves every prior window"),
    ],
)
def test_bad_settings_have_clear_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        RetrievalSettings(**kwargs).resolve()


@pytest.mark.parametrize("mode", ["nearest", "random"])
def test_a_fraction_that_retrieves_no_window_is_refused(mode):
    """round(r * N) = 0 would write an empty file, and stage 2 would quietly train the no-retrieval ablation."""
    prior, target = latents(num_prior=40)
    with pytest.raises(ValueError, match=r"r = 0.01 of 40 prior windows retrieves no window.*raise --fraction"):
        select_windows(prior, target, RetrievalSettings(mode=mode, fraction=0.01).resolve())


def test_unknown_ablation_is_named():
    with pytest.raises(ValueError, match="Unknown retrieval ablation"):
        ablation("best")
