"""Every method the benchmark compares, in one table: where its skills come from, what it retrieves, what it trains.

Adding a method is one entry in `METHODS`; the plan, the runner, the held-out score and the results tables read
everything they need from it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Method:
    name: str
    summary: str  # one line: what the row of the results table means
    # stage-1 skills: "prior" (pre-trained on play data, shared by the tasks of a seed), "target" (on the task's own
    # demos: the "no prior data" ablation), None (not a skillret method)
    skills: str | None = None
    # `skillret-retrieve` options of the method's retrieval (None: stage 2 trains without a retrieval file)
    retrieval: dict[str, Any] | None = None
    # a LeRobot baseline: the policy type lerobot-train builds, and whether it is pre-trained on the prior first
    lerobot_type: str | None = None
    pretrain_on_prior: bool = False
    # the pipeline config's `baselines.<key>` sections (lerobot-train options) the method needs
    baselines: tuple[str, ...] = field(default=())
    # stage-2 lerobot-train options that define a skillret variant (after the config's `policy.args`, so they win)
    policy_args: dict[str, Any] = field(default_factory=dict)

    @property
    def is_skillret(self) -> bool:
        return self.skills is not None

    @property
    def reads_prior(self) -> bool:
        """Whether the method needs the play data (skills from it, or a baseline pre-trained on it)."""
        return self.skills == "prior" or self.pretrain_on_prior


METHODS: dict[str, Method] = {
    m.name: m
    for m in (
        # the method and its ablations (seed A.4 / Table 3)
        Method("skillret", "skills from the prior, the r closest prior windows retrieved", "prior", {}),
        # gamma, the retrieved windows' weight in the policy loss: the seed uses 1.0 (the default) in simulation and
        # 0.15 on its real robot; here 0.15 led on fish_and_burner, not on setup_pan (benchmarks/results/README.md, part 3)
        Method(
            "skillret_gamma_0.15",
            "skillret with the retrieved windows' policy loss weighted 0.15 (the seed's real-robot gamma)",
            "prior",
            {},
            policy_args={"policy.retrieved_weight": 0.15},
        ),
        # not in the seed: the fine-tuned decoder also learns to execute the latent policy's own (detached) skills on
        # the target windows, against the prior skills' sensitivity to the policy's misses; no better on setup_pan
        # (results part 3, session 40)
        Method(
            "skillret_policy_decoder",
            "skillret whose fine-tuned decoder also executes the latent policy's own skills on the target windows",
            "prior",
            {},
            policy_args={"policy.decoder_policy_weight": 1.0},
        ),
        # not in the seed: stage 2 fine-tunes the skills on the retrieved windows (and the target's) instead of the
        # whole prior, so the decoder specialises near the task as the demonstrations' own skills do; no better on
        # setup_pan (session 40)
        Method(
            "skillret_retrieved_skills",
            "skillret whose skills fine-tune on the retrieved windows instead of the whole prior",
            "prior",
            {},
            policy_args={"policy.skill_finetune_windows": "retrieved"},
        ),
        Method("no_retrieval", "skills from the prior, no retrieved windows", "prior"),
        Method("all_retrieval", "skills from the prior, every prior window retrieved", "prior", {"ablation": "all"}),
        Method("random_retrieval", "skills from the prior, r random prior windows", "prior", {"ablation": "random"}),
        # A.4's "50 % Retrieval": the nearest half of the prior, between skillret's 10 % and all of it
        Method(
            "retrieval_50",
            "skills from the prior, the closest 50 % of prior windows retrieved",
            "prior",
            {"fraction": 0.5},
        ),
        Method("no_prior", "skills and policy from the target demos only", "target"),
        # LeRobot's own policies (seed C.4), trained by lerobot-train
        Method("act", "LeRobot ACT on the target demos", lerobot_type="act", baselines=("act",)),
        Method(
            "diffusion", "LeRobot Diffusion on the target demos", lerobot_type="diffusion", baselines=("diffusion",)
        ),
        Method(
            "act_ft",
            "LeRobot ACT pre-trained on the prior, fine-tuned on the target demos",
            lerobot_type="act",
            pretrain_on_prior=True,
            baselines=("act_ft_prior", "act_ft"),
        ),
    )
}


def retrieval_owner(name: str) -> str:
    """The first method that retrieves exactly as `name` does (same skills, same options): variants that differ only
    in stage 2, such as skillret_gamma_0.15, train on its retrieval file instead of computing the same one again."""
    method = METHODS[name]
    return next(m.name for m in METHODS.values() if (m.skills, m.retrieval) == (method.skills, method.retrieval))
