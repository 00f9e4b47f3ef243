"""The Foxglove layouts docs/recordings.md offers plot channels the recorder writes: the
one-arm layout `/force`, the two-arm one each arm's `/arms/<name>/force` (a two-arm
recording has no `/force`), with the fields the force messages carry."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from telerobot.server.recording import schemas

DOCS = Path(__file__).resolve().parents[1] / "docs"


def plotted_topics(layout: str) -> set[str]:
    config = json.loads((DOCS / layout).read_text())["configById"]
    paths = [p["value"] for c in config.values() for p in c.get("paths", [])]
    assert all(re.fullmatch(r"/[\w/]+\.values\[[0-5]\]", p) for p in paths), paths
    return {p.partition(".")[0] for p in paths}


@pytest.mark.parametrize(
    ("layout", "topics"),
    [
        ("foxglove-layout.json", {schemas.FORCE}),
        (
            "foxglove-layout-two-arms.json",
            {
                schemas.arm_topic("left", schemas.ARM_FORCE),
                schemas.arm_topic("right", schemas.ARM_FORCE),
            },
        ),
    ],
)
def test_each_layout_plots_the_force_channels_its_recordings_have(
    layout: str, topics: set[str]
) -> None:
    assert plotted_topics(layout) == topics
    assert (DOCS / "recordings.md").read_text().count(layout) >= 1  # offered where it is said
