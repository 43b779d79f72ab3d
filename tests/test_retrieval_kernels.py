"""The chunked float32 kernels select exactly the set a float64 brute force selects (L2 and symmetric KL)."""

from __future__ import annotations

import zlib

import pytest
import torch

from lerobot_skillret.retrieval.api import retrieval_count
from lerobot_skillret.retrieval.kernels import NearestTarget, Scores, smallest


def brute_force(prior_mean, target_mean, metric, prior_log_var=None, target_log_var=None):
    """float64 reference written from the definitions, with the full N x M matrix (small inputs only)."""
    p, q = prior_mean.double()[:, None, :], target_mean.double()[None, :, :]
    if metric == "l2":
        matrix = ((p - q) ** 2).sum(-1)
    else:
        v1, v2 = prior_log_var.double().exp()[:, None, :], target_log_var.double().exp()[None, :, :]

        def kl(m_a, v_a, m_b, v_b):
            return 0.5 * (torch.log(v_b / v_a) + (v_a + (m_a - m_b) ** 2) / v_b - 1.0).sum(-1)

        matrix = 0.5 * (kl(p, v1, q, v2) + kl(q, v2, p, v1))
    values, index = torch.min(matrix, dim=1)
    return values, index


def reference_selection(values, count):
    return set(torch.sort(values, stable=True).indices[:count].tolist())


def random_latents(num, dim, generator, offset=0.0, spread=1.0):
    mean = offset + spread * torch.randn(num, dim, generator=generator)
    log_var = 0.5 * torch.randn(num, dim, generator=generator) - 1.0
    return mean, log_var


@pytest.mark.parametrize("metric", ["l2", "kl"])
@pytest.mark.parametrize("chunk_size", [1, 7, 64, 333, 5000])
def test_selection_equals_float64_brute_force(metric, chunk_size):
    generator = torch.Generator().manual_seed(zlib.crc32(f"{metric}-{chunk_size}".encode()))  # same in every run
    prior_mean, prior_log_var = random_latents(1500, 12, generator)
    target_mean, target_log_var = random_latents(90, 12, generator, offset=0.3)
    engine = NearestTarget(target_mean, target_log_var if metric == "kl" else None, metric=metric)
    scores = engine.score(
        prior_mean, prior_log_var if metric == "kl" else None, chunk_size=chunk_size, with_nearest=True
    )
    ref_values, ref_nearest = brute_force(prior_mean, target_mean, metric, prior_log_var, target_log_var)

    error = (scores.value - ref_values).abs()
    assert torch.all(error <= scores.margin), "the per-row error bound must hold"
    torch.testing.assert_close(scores.value.double(), ref_values, rtol=1e-4, atol=1e-4)
    assert (scores.nearest == ref_nearest).float().mean() > 0.99
    assert engine.score(prior_mean, prior_log_var if metric == "kl" else None, chunk_size=chunk_size).nearest is None

    for fraction in (0.02, 0.1, 0.5, 0.9, 1.0):
        count = retrieval_count(fraction, 1500)
        rows, values = smallest(
            scores, count, lambda r: engine.exact(prior_mean, prior_log_var if metric == "kl" else None, r)
        )
        assert set(rows.tolist()) == reference_selection(ref_values, count)
        assert torch.all(values[1:] >= values[:-1]), "retrieved windows come sorted by distance"


def test_refinement_fixes_float32_near_ties():
    """Prior rows on unit spheres around spread-out targets: exact distances differ by ~1e-6, float32 errors are
    ~1e-3, so float32 alone picks a mostly wrong set; the margin-guided float64 re-scoring picks the exact one."""
    generator = torch.Generator().manual_seed(0)
    target_mean = 10.0 * torch.randn(40, 16, generator=generator)
    direction = torch.randn(4000, 16, generator=generator)
    owner = torch.randint(0, 40, (4000,), generator=generator)
    prior_mean = target_mean[owner] + direction / direction.norm(dim=1, keepdim=True)
    engine = NearestTarget(target_mean)
    scores = engine.score(prior_mean, chunk_size=256)
    ref_values, _ = brute_force(prior_mean, target_mean, "l2")
    assert torch.all((scores.value - ref_values).abs() <= scores.margin)
    count = retrieval_count(0.1, 4000)
    expected = reference_selection(ref_values, count)
    float32_rows, _ = smallest(scores, count)
    assert set(float32_rows.tolist()) != expected, "this case must be hard for float32 alone"
    rows, _ = smallest(scores, count, lambda r: engine.exact(prior_mean, None, r))
    assert set(rows.tolist()) == expected


def test_bad_inputs_have_clear_errors():
    target = torch.randn(10, 8)
    with pytest.raises(ValueError, match="target set is empty"):
        NearestTarget(torch.empty(0, 8))
    with pytest.raises(ValueError, match="dimension 4 but target latents 8"):
        NearestTarget(target).score(torch.randn(5, 4))
    with pytest.raises(ValueError, match="needs the encoder log-variances"):
        NearestTarget(target, metric="kl")
    with pytest.raises(ValueError, match="Unknown retrieval metric"):
        NearestTarget(target, metric="cosine")
    with pytest.raises(ValueError, match=r"\[num_windows, latent_dim\]"):
        NearestTarget(torch.randn(10))
    for bad in (float("nan"), float("inf"), -float("inf")):
        prior = torch.zeros(3, 8)
        prior[1, 2] = bad
        with pytest.raises(ValueError, match="prior latents contain NaN/inf"):
            NearestTarget(target).score(prior)
        with pytest.raises(ValueError, match="prior latents contain NaN/inf"):
            NearestTarget(target, torch.zeros(10, 8), metric="kl").score(torch.zeros(3, 8), prior)
    with pytest.raises(ValueError, match="target latents contain NaN/inf"):
        NearestTarget(target, torch.full((10, 8), float("inf")), metric="kl")
    with pytest.raises(ValueError, match="chunk_size"):
        NearestTarget(target).score(torch.randn(5, 8), chunk_size=0)
    scores = NearestTarget(target).score(torch.randn(5, 8))
    with pytest.raises(ValueError, match="Cannot select 6 of 5"):
        smallest(scores, 6)


def test_empty_prior_and_zero_count():
    engine = NearestTarget(torch.randn(10, 8))
    scores = engine.score(torch.empty(0, 8))
    assert scores.value.shape == (0,)
    rows, values = smallest(engine.score(torch.randn(5, 8)), 0)
    assert rows.numel() == 0 and values.numel() == 0


def test_retrieval_count_rounds_to_nearest():
    """K = round(r * candidates): 0.19 of 10 candidates is 2 windows, not 1 (guards truncation)."""
    assert [retrieval_count(r, 10) for r in (0.0, 0.04, 0.06, 0.19, 1.0)] == [0, 0, 1, 2, 10]


def test_smallest_without_exact_rescoring_keeps_the_nearest():
    """The plain top-k path (`--exact=false`) keeps the k smallest values, sorted (guards keeping the largest)."""
    value = torch.tensor([0.5, 0.1, 0.9, 0.3, 0.7])
    rows, values = smallest(Scores(value=value, nearest=None, margin=torch.zeros(5)), 2)
    assert rows.tolist() == [1, 3] and values.tolist() == pytest.approx([0.1, 0.3])
