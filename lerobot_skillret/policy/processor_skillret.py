"""Pre/post-processors of the `skillret` policy: rename, batch, device; normalisation is the model's.

The four standard step names stay (lerobot-train and lerobot-eval pass overrides keyed by them and fail if one is
missing), but the normaliser steps are identities: they carry no features or statistics and the config's
`normalization_mapping` is IDENTITY for every feature type, which is also the `norm_map` lerobot-train passes when
it overrides their statistics with a new dataset's (`--policy.path`). The skill model normalises with its own
stage-1 statistics (see `normalization.py`), so a second run can never rescale its actions.
"""

from __future__ import annotations

from typing import Any

import torch
from lerobot.processor import (
    AddBatchDimensionProcessorStep,
    DeviceProcessorStep,
    NormalizerProcessorStep,
    PolicyAction,
    PolicyProcessorPipeline,
    RenameObservationsProcessorStep,
    UnnormalizerProcessorStep,
)
from lerobot.processor.converters import policy_action_to_transition, transition_to_policy_action
from lerobot.utils.constants import POLICY_POSTPROCESSOR_DEFAULT_NAME, POLICY_PREPROCESSOR_DEFAULT_NAME

from lerobot_skillret.policy.configuration_skillret import SkillRetConfig


def make_skillret_pre_post_processors(
    config: SkillRetConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """`dataset_stats` is accepted for LeRobot's factory signature and deliberately unused (see module doc)."""
    del dataset_stats
    input_steps = [
        RenameObservationsProcessorStep(rename_map={}),
        AddBatchDimensionProcessorStep(),
        DeviceProcessorStep(device=config.device),
        NormalizerProcessorStep(features={}, norm_map=config.normalization_mapping, stats=None, device=config.device),
    ]
    output_steps = [
        UnnormalizerProcessorStep(features={}, norm_map=config.normalization_mapping, stats=None),
        DeviceProcessorStep(device="cpu"),
    ]
    return (
        PolicyProcessorPipeline[dict[str, Any], dict[str, Any]](
            steps=input_steps, name=POLICY_PREPROCESSOR_DEFAULT_NAME
        ),
        PolicyProcessorPipeline[PolicyAction, PolicyAction](
            steps=output_steps,
            name=POLICY_POSTPROCESSOR_DEFAULT_NAME,
            to_transition=policy_action_to_transition,
            to_output=transition_to_policy_action,
        ),
    )
