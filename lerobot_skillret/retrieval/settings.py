"""Retrieval settings: the paper's knobs (Algorithm 2, appendices A.2 / A.4).

Unset values (`None`, or "checkpoint" for `num_prior`) come from the stage-1 checkpoint's config
(`retrieval_fraction`, `retrieval_metric`, `retrieval_num_prior`, `retrieval_num_target`), so one config file
states them once; `resolve` fills them in and the resolved settings are stored in the retrieval file.

Modes (A.4):
- "nearest": the method; score candidates by distance to the nearest target latent, keep the r closest.
- "random": the "random retrieval" ablation; the same count, drawn uniformly from the candidates.
- "all": the "all retrieval" ablation; every prior window (N = size of the prior, r = 100%).
- "none": the "no retrieval" ablation (N = 0); an empty file. It is a mode, not r = 0, so r is always in (0, 1].
The remaining A.4 rows are settings of "nearest": 2/50/90% retrieval is `fraction`, "large retrieval" is
`num_prior="all"` (every prior window a candidate, r = 10%). `ABLATIONS` names all of them; a row that is a mode
has the mode's name.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
from lerobot_skillret.retrieval.kernels import METRICS

MODES = ("nearest", "random", "all", "none")
FROM_CHECKPOINT = "checkpoint"
EVERY_WINDOW = "all"

# Appendix A.4's rows as settings overrides (on top of the checkpoint's defaults).
ABLATIONS: dict[str, dict[str, Any]] = {
    "nearest": {},
    "none": {"mode": "none"},
    "all": {"mode": "all"},
    "random": {"mode": "random"},
    "r2": {"fraction": 0.02},
    "r50": {"fraction": 0.50},
    "r90": {"fraction": 0.90},
    "large": {"num_prior": EVERY_WINDOW},
}


@dataclass(frozen=True)
class RetrievalSettings:
    """What to retrieve and how (the paper's defaults)."""

    mode: str = "nearest"  # nearest | random | all | none (see the module docstring)
    fraction: float | None = None  # r: share of candidates retrieved; None = checkpoint's retrieval_fraction
    metric: str | None = None  # "l2" (encoder means) or "kl" (symmetric KL, A.2); None = checkpoint's
    num_prior: int | str = FROM_CHECKPOINT  # N candidates (random anchors), "all" = every prior window
    num_target: int | None = None  # M target windows (random anchors); None = checkpoint's
    seed: int = 0  # anchors of candidates and target windows, random mode
    exact: bool = True  # settle rows near the cut in float64 (set equals a float64 brute force)
    batch_size: int = 512  # windows per encoder forward pass
    chunk_size: int = 256  # prior rows per block: ~chunk_size * M * 4 bytes per worker (256: stays in cache)

    def resolve(self, config: Any | None = None) -> RetrievalSettings:
        """Fill unset values from a SkillRetConfig (or its defaults, the paper's, without one), then validate."""

        def default(name: str) -> Any:
            return getattr(config if config is not None else SkillRetConfig, name)

        values = dataclasses.asdict(self)
        if self.mode == "all":
            if self.fraction not in (None, 1.0) or self.num_prior not in (FROM_CHECKPOINT, EVERY_WINDOW):
                raise ValueError(
                    "mode 'all' retrieves every prior window (A.4: N = size of the prior, r = 100%); drop "
                    "--fraction/--num-prior, or use mode 'nearest' with --fraction 1.0 to keep N random candidates."
                )
            values.update(fraction=1.0, num_prior=EVERY_WINDOW)
        if values["fraction"] is None:
            values["fraction"] = default("retrieval_fraction")
        if values["metric"] is None:
            values["metric"] = default("retrieval_metric")
        if values["num_prior"] == FROM_CHECKPOINT:
            num_prior = default("retrieval_num_prior")
            values["num_prior"] = EVERY_WINDOW if num_prior is None else num_prior
        if values["num_target"] is None:
            values["num_target"] = default("retrieval_num_target")
        resolved = RetrievalSettings(**values)
        resolved.validate()
        return resolved

    def validate(self) -> None:
        """Clear errors for values that cannot mean anything (run on resolved settings).

        The retrieval package's only range checks; they agree with `SkillRetConfig`'s `retrieval_*` checks."""

        def fail(name: str, why: str) -> None:
            raise ValueError(f"retrieval setting `{name}`={getattr(self, name)!r} is invalid: {why}.")

        if self.mode not in MODES:
            fail("mode", f"choose one of {MODES}")
        if self.metric not in METRICS:
            fail("metric", f"choose one of {METRICS}")
        if not isinstance(self.fraction, int | float) or not 0.0 < self.fraction <= 1.0:
            fail(
                "fraction",
                "r is a share of the candidates in (0, 1], e.g. 0.1 for the closest 10% (no retrieval is mode 'none')",
            )
        if self.num_prior != EVERY_WINDOW and (not isinstance(self.num_prior, int) or self.num_prior < 1):
            fail("num_prior", f"N must be >= 1 candidate windows, or {EVERY_WINDOW!r} for every prior window")
        if not isinstance(self.num_target, int) or self.num_target < 1:
            fail("num_target", "M must be >= 1 target window")
        for name in ("batch_size", "chunk_size"):
            if getattr(self, name) < 1:
                fail(name, "it must be >= 1")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def ablation(name: str, **overrides: Any) -> RetrievalSettings:
    """Settings of one row of appendix A.4 (`ABLATIONS`), with extra overrides."""
    if name not in ABLATIONS:
        raise ValueError(f"Unknown retrieval ablation {name!r}; choose one of {sorted(ABLATIONS)}.")
    return RetrievalSettings(**{**ABLATIONS[name], **overrides})
