"""LeRobot's side of a policy on a Telerobot server, for the LeRobot tests
(integrations/lerobot/tests) and bench.rollout_policy: the robot plugin joined as a
policy (``make_robot``) and a small ACT for its features, untrained (``build_untrained``).
Runs in LeRobot's own venv (Python 3.12, torch) with the checkout on PYTHONPATH; LeRobot
is imported inside the functions that need it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

FPS = 30.0  # the plugin's rate as a policy: observations and actions a second


def policy_observation_features(robot: Any) -> dict[str, Any]:
    """What the policy sees: the joints (``.pos``) and the cameras, as lerobot-rollout
    passes them (it leaves out other floats, the forces among them)."""
    return {
        k: v
        for k, v in robot.observation_features.items()
        if not (v is float and not k.endswith(".pos"))
    }


def build_untrained(path: Path, robot: Any, around: dict[str, Any] | None = None) -> Path:
    """A small ACT for this robot's features, untrained, no downloaded weights. With
    ``around`` (an observation), its normalisation is centred there (1° spread), so its
    untrained actions stay near that pose rather than near every joint's zero."""
    from lerobot.configs import FeatureType
    from lerobot.policies import make_pre_post_processors
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.utils.feature_utils import (
        combine_feature_dicts,
        dataset_to_policy_features,
        hw_to_dataset_features,
    )

    features = dataset_to_policy_features(
        combine_feature_dicts(
            hw_to_dataset_features(robot.action_features, "action"),
            hw_to_dataset_features(policy_observation_features(robot), "observation"),
        )
    )
    cfg = ACTConfig(
        input_features={k: f for k, f in features.items() if f.type is not FeatureType.ACTION},
        output_features={k: f for k, f in features.items() if f.type is FeatureType.ACTION},
        device="cpu",
        pretrained_backbone_weights=None,
        **SMALL_ACT,
    )
    stats = None
    if around is not None:
        pos = np.array([float(around[k]) for k in robot.action_features], np.float32)
        spread = {"mean": pos, "std": np.ones_like(pos)}
        stats = {"observation.state": spread, "action": spread}
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
    ACTPolicy(cfg).save_pretrained(str(path))
    pre.save_pretrained(str(path))
    post.save_pretrained(str(path))
    return path


SMALL_ACT: dict[str, Any] = {
    "dim_model": 128,
    "n_heads": 4,
    "dim_feedforward": 512,
    "n_encoder_layers": 2,
    "n_decoder_layers": 1,
    "n_vae_encoder_layers": 2,
    "latent_dim": 16,
    "chunk_size": 30,
    "n_action_steps": 15,
}


def make_robot(url: str, token: str, width: int, height: int, name: str = "act-policy") -> Any:
    """The robot plugin as a policy: ``token`` is the operator's, which issues the policy
    a policy token of its own (a policy never joins with the operator token). It takes
    control paused: a person lets it drive (a resume, or an operator's move handed back)."""
    from lerobot_robot_telerobot.config_telerobot import TelerobotConfig
    from lerobot_robot_telerobot.telerobot import Telerobot

    from harness.policy_stub import issue_policy_token

    secret = issue_policy_token(url, token, name)
    config = TelerobotConfig(url=url, token=token, client_name=name, camera_width=width,
                             camera_height=height, fps=FPS, policy=True,
                             policy_token=secret)  # fmt: skip
    return Telerobot(config)
