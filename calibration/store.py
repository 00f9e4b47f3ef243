"""Calibrations on disk: one versioned JSON file per camera rig in the state folder,
written atomically (a crash mid-write leaves the previous file), loaded at start."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

from telerobot.calibration.model import CalibrationError, CameraModel

FORMAT = "telerobot-calibration"
VERSION = 1


class CalibrationStore:
    def __init__(self, path: Path, rig: str = "default") -> None:
        self.path = path
        self.rig = rig
        self.cameras: dict[str, CameraModel] = {}

    def load(self) -> CalibrationStore:
        """Read the file if there is one (none: nothing calibrated yet)."""
        if not self.path.exists():
            return self
        try:
            doc: dict[str, Any] = json.loads(self.path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise CalibrationError(f"cannot read the calibration {self.path}: {exc}") from None
        if doc.get("format") != FORMAT or doc.get("version") != VERSION:
            raise CalibrationError(
                f"{self.path} is not a version-{VERSION} {FORMAT} file "
                f"(format {doc.get('format')!r}, version {doc.get('version')!r})"
            )
        self.rig = str(doc.get("rig", self.rig))
        self.cameras = {name: CameraModel.from_json(c) for name, c in doc["cameras"].items()}
        return self

    def save(self) -> None:
        doc = {
            "format": FORMAT,
            "version": VERSION,
            "rig": self.rig,
            "cameras": {name: model.to_json() for name, model in sorted(self.cameras.items())},
        }
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=".calibration-", suffix=".json")
        with os.fdopen(fd, "w") as f:
            json.dump(doc, f, indent=1)
        os.replace(tmp, self.path)

    def put(self, model: CameraModel) -> None:
        self.cameras[model.camera] = model
        self.save()

    def clear(self) -> None:
        self.cameras = {}
        self.path.unlink(missing_ok=True)
