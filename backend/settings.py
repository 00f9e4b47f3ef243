"""One Settings class for the whole server (docs/architecture.md, rules 8 and 20):
the server's own fields (``ServerSettings``) and every registered driver's
(``telerobot.drivers.settings``: each declared once, beside its driver).

Values come, highest first, from: explicit arguments (the CLI's flags),
environment variables ``TELEROBOT_*``, a TOML file (``--config`` or
``TELEROBOT_CONFIG``), then the defaults, which run everything on the simulation.
"""

from __future__ import annotations

import json
import math
import os
import re
from contextvars import ContextVar
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import (
    Field,
    SecretStr,
    ValidationInfo,
    create_model,
    field_validator,
    model_validator,
)
from pydantic_settings import (
    BaseSettings,
    NoDecode,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from telerobot.drivers.registry import driver_names, driver_settings, load_driver
from telerobot.drivers.robot.models import (
    DEFAULT_MODEL,
    MODELS,
    RobotModel,
    load_model,
    model_names,
)
from telerobot.server.media.ice import IceConfig

SINGLE_ARM = "arm"  # the one arm's name when the settings name no arms
MAX_ARMS = 8
ARM_NAME = re.compile(r"[A-Za-z0-9_-]{1,32}")
# Settings of the whole server, never one arm's (an arm table that sets one is refused).
NOT_PER_ARM = frozenset(
    {"arms", "host", "http_port", "priority_port", "viewer", "viewer_port", "operator_token",
     "state_dir", "camera", "video", "deadman_timeout_s", "lease_grace_s", "max_command_age_ms",
     "state_rate_hz", "autonomy_release"}
)  # fmt: skip


def parse_arms(spec: str) -> dict[str, dict[str, Any]]:
    """``left=so101:sim,right=so101:sim[:force]`` (the CLI's and the environment's form)
    as the arms table: name=model:robot driver, and optionally :force driver."""
    if spec.lstrip().startswith("{"):  # the table as JSON (TELEROBOT_ARMS='{"left": …}')
        table: dict[str, dict[str, Any]] = json.loads(spec)
        return table
    arms: dict[str, dict[str, Any]] = {}
    for part in filter(None, (p.strip() for p in spec.split(","))):
        name, eq, rest = part.partition("=")
        fields = rest.split(":")
        if not eq or not name or not 1 <= len(fields) <= 3 or not all(fields):
            raise ValueError(
                f"arms: {part!r} is not name=model:robot[:force] (e.g. left=so101:sim)"
            )
        own: dict[str, Any] = {"robot_model": fields[0]}
        if len(fields) > 1:
            own["robot"] = fields[1]
        if len(fields) > 2:
            own["force"] = fields[2]
        if name in arms:
            raise ValueError(f"arms: {name!r} is named twice")
        arms[name] = own
    return arms


_config_file: ContextVar[Path | None] = ContextVar("telerobot_config_file", default=None)


class ServerSettings(BaseSettings):
    """The server's own settings; ``Settings`` adds the drivers'."""

    model_config = SettingsConfigDict(env_prefix="TELEROBOT_", extra="forbid")

    @field_validator("operator_token")
    @classmethod
    def _printable_token(cls, token: SecretStr | None) -> SecretStr | None:
        if token is not None and not re.fullmatch(r"[\x21-\x7e]+", token.get_secret_value()):
            raise ValueError("the operator token is printable ASCII, no spaces")
        return token

    host: str = "127.0.0.1"
    http_port: int = Field(8000, ge=0, le=65535)
    # The priority channel (forces out, commands in; the master-arm bridge): TCP, 0 = any
    priority_port: int = Field(8001, ge=0, le=65535)
    # The 3D view of the workcell (viser), on its own HTTP port; 0 = any free port
    viewer: bool = True
    viewer_port: int = Field(8002, ge=0, le=65535)

    # Drivers by their name in drivers/registry.py (each declares its own settings there)
    robot: str = "sim"
    auto_initialize: bool = True  # connect and initialise the robot at start-up
    # The arm's description (drivers/robot/models): puma560, so101
    robot_model: str = DEFAULT_MODEL
    # A named pose of the model the robot initialises to (PUMA: qz, qr, qs, qn; SO-101:
    # zero, ready, rest); None: the model's home (qn, ready)
    home_pose: str | None = None
    # The simulated arm is switched on at the model's start pose and moves home, as a
    # real one does (about 3.5 s on the PUMA). True: it is switched on at home and is
    # READY at once, for tests and scripts that do not watch the initialisation.
    sim_starts_at_home: bool = False
    # The tool's length along the flange's z axis, m; None: the model's (PUMA 0.1 m, the
    # SO-101 0: its tool frame is already between the jaws)
    tool_length: float | None = Field(None, ge=0.0, le=0.5)

    # Where the arm's base stands in the workcell: x, y, z (m) and a turn about z (°).
    # None: the simulated workcell's place for it (the first arm at the origin; a second
    # across the table, facing it).
    mount: tuple[float, float, float, float] | None = None
    # Two arms or more (docs/arms.md): each by its name, with the settings it has of its
    # own (robot, robot_model, force, home_pose, tool_length, mount, force_limit_n, a
    # driver's port…); every other setting is the server's. TOML: a table per arm,
    # [arms.left] robot_model = "so101"; the CLI: --arms left=so101:sim,right=so101:sim
    # (name=model:robot driver[:force driver]). Empty: one arm, named "arm", with the
    # settings' own robot.
    arms: Annotated[dict[str, dict[str, Any]], NoDecode] = {}

    force: str = "sim"
    force_rate_hz: float = Field(1000.0, ge=1.0, le=10_000.0)
    state_rate_hz: float = Field(50.0, ge=1.0, le=1000.0)

    # Safety (the rest of SafetyLimits keeps its defaults)
    force_limit_n: float = Field(60.0, gt=0)
    deadman_timeout_s: float = Field(0.15, gt=0, le=0.18)
    # after the dead-man stops the arm, the lease is kept this long for the link to return
    lease_grace_s: float = Field(2.0, gt=0, le=30.0)
    # A script's client (REST: no connection of its own) is forgotten this long after its
    # last request unless it holds the lease; a script supervising a task is gone then.
    rest_client_idle_s: float = Field(60.0, ge=1.0, le=3600.0)
    # Commands sent longer ago than this (client clock synced to the server's) are dropped.
    max_command_age_ms: float = Field(250.0, ge=20.0, le=5000.0)
    max_speed_m_s: float = Field(0.25, gt=0, le=2.0)
    contact_speed_m_s: float = Field(0.02, gt=0, le=2.0)  # toward a recent contact
    # Supervised autonomy: an operator's release during a correction hands control back
    # to the policy driving ("autonomous") or holding still until resumed ("pause").
    autonomy_release: Literal["autonomous", "pause"] = "autonomous"

    # Security: the operator token is generated into state_dir at first start unless given.
    # A SecretStr: no repr, dump or log line shows it (.get_secret_value() where used).
    operator_token: SecretStr | None = Field(None, min_length=16, max_length=64)
    state_dir: Path | None = None  # default: $XDG_CONFIG_HOME/telerobot or ~/.config/telerobot
    allowed_origins: list[str] = []  # extra browser origins allowed on /ws (same host always is)
    # Extra names this server answers to (a DNS name on the LAN); its host, loopback and
    # this machine's names and addresses always are. Anything else gets 400 (DNS rebinding).
    allowed_hosts: list[str] = []
    tls: bool = False  # HTTPS with a per-installation self-signed certificate (WebXR on a LAN)

    # Recordings (docs/recording.md) stop by themselves, the file closed whole and the
    # reason kept, at this size, or when the disk's free space falls below the second
    # (and do not start below it): a full disk would leave a file without its summary.
    recording_max_bytes: int = Field(4 * 1024**3, ge=1024**2)
    recording_min_free_bytes: int = Field(256 * 1024**2, ge=0)

    # Stereo video (a media worker process: capture → one encoder → every WebRTC viewer)
    video: bool = True
    camera: str = "sim"
    # The rig's name: each rig keeps its own calibration (calibration-<rig>.json).
    # Default: the camera driver's (the simulation's is "sim"; real cameras': the
    # driver and its devices).
    camera_rig: str | None = Field(None, pattern=r"^[A-Za-z0-9._-]{1,64}$")

    @property
    def rig_name(self) -> str:
        if self.camera_rig:
            return self.camera_rig
        return load_driver("camera", self.camera).default_rig(self.model_dump())

    video_width: int = Field(1280, ge=160, le=3840)  # of one eye
    video_height: int = Field(720, ge=120, le=2160)
    # Frames a second, cameras and encoders. Above 30 (e.g. 60) the media worker drops
    # to 30 by itself while it cannot keep the rate with room to spare, and comes back
    # after a clean stretch (media/frame_rate.py; GET /api/v1/video's fps_target, fps_why).
    video_fps: float = Field(30.0, ge=1.0, le=120.0)
    # False: the configured rate whatever the machine does (a benchmark's fixed load).
    video_fps_auto: bool = True
    video_bitrate: int = Field(8_000_000, ge=100_000, le=100_000_000)
    video_nice: int = Field(10, ge=0, le=19)  # the media worker's niceness: video yields the CPU
    # The server raises its own CPU priority by this many nice steps at start, where the
    # system lets it (root, or CAP_SYS_NICE; else it says so and runs as started): the
    # e-stop, the dead-man and the forces go before the machine's other programs. Its
    # media worker and read jobs keep their niceness relative to it. 0: as started.
    cpu_priority: int = Field(5, ge=0, le=20)
    video_cbr: bool = False  # constant bitrate (filler data) instead of "at most"
    # Each viewer's packets spread at 2.5× its layer's rate, not a frame at once (a key
    # frame's burst queues the forces behind it on a narrow link): media/pacer.py. Off by
    # default: with it, Chromium on loopback counted 5 freezes in 10 s (its decoder's
    # freeze detector: paced key frames arrive up to ~0.1 s late), which it does not
    # without; bench.wan measured the gain for forces on `mobile` (docs/PERFORMANCE.md).
    video_pacing: bool = False
    # Each frame decoded and shown as soon as it is complete (the playout-delay RTP
    # extension at 0–0 ms: media/playout.py), not held by the browser's jitter buffer
    # for a smoother picture (21 ms a frame on loopback, bench.browser).
    video_zero_playout_delay: bool = True
    # …unless the viewer's link loses packets: then frames are held by what a repair
    # takes (the round trip and jitter, at most 0.5 s), back to 0 after 10 s without
    # one (media/playout.py). False: always shown at once, frozen while repaired.
    video_adaptive_playout: bool = True
    # The most a frame is held for a repair (ms); a repair that takes longer is not
    # waited for at all (it would freeze the picture anyway: media/playout.py). Less
    # lag, more freezes: an operator's choice.
    video_playout_max_ms: int = Field(500, ge=0, le=500)
    # Forward error correction (RED + ULPFEC, media/fec.py) to viewers that offer it
    # (Chromium does): "auto" follows each viewer's loss (none on a clean link), "on"
    # protects every viewer at the most (~1 FEC packet per 3 media packets; 1 per 2 for
    # a still scene's one-packet frames), "off" never (nor offered).
    video_fec: Literal["auto", "on", "off"] = "auto"
    # The operator's page (its peer opened with the operator token) gets an encoder of
    # its own whose bitrate, size and frame rate follow a congestion estimate of its
    # link, FEC inside that budget (media/rate_control.py); watchers share the layers.
    # Off: the operator shares them too (one encode less: ~a third of a core at 2×720p).
    video_operator_encoder: bool = True
    # Tests and demos: every Nth video packet to each viewer is lost for good, its
    # resends too (only FEC can bring it back). 0: none.
    video_drop_every: int = Field(0, ge=0, le=1000)
    # WebRTC peers of the robot's own server (each costs it encryption and sending; with
    # a media server only the operator's and the observers' when it is off are)
    video_max_viewers: int = Field(16, ge=1, le=1000)
    # Seconds between periodic keyframes; 0 (the default): only when asked (a new viewer,
    # a PLI, a lost packet the sender no longer holds, a recording every 2 s). Each
    # periodic one is a burst that queues the forces behind it on a narrow link.
    keyframe_interval_s: float = Field(0.0, ge=0.0, le=600.0)
    # STUN/TURN for the page and the server's peers (backend/media/ice.py): "stun:host:port",
    # "turn:user:pass@host:port", or "turn:host:port[?transport=tcp]" with credentials
    # minted per peer from turn_secret (coturn: use-auth-secret, static-auth-secret)
    ice_servers: list[str] = []
    turn_secret: str | None = Field(None, min_length=16, repr=False)  # never sent to a page
    turn_credential_ttl_s: int = Field(3600, ge=60, le=7 * 86400)  # minted credentials' life
    ice_relay_only: bool = False  # video only through TURN (iceTransportPolicy "relay")
    alignment_px: tuple[int, int] = (0, 0)  # default shift of the right image vs the left (x, y)
    # Observers through a media server (backend/media/relay.py; docs/media-server.md):
    # "janus" fans the one encoded stream out, so the robot's computer sends it once
    # whoever watches; the operator keeps the direct path. With media_server_url None
    # the server starts and supervises Janus itself (HTTP API on 127.0.0.1, ports below,
    # 0 = any free one); with a URL it uses a Janus elsewhere, whose mountpoint
    # (media_server_mountpoint) takes RTP on media_server_host:media_server_rtp_port.
    media_server: Literal["none", "janus"] = "none"
    media_server_url: str | None = Field(None, pattern=r"^https?://[^\s]+$")
    media_server_host: str | None = None  # None: the URL's host (127.0.0.1 for ours)
    media_server_rtp_port: int = Field(0, ge=0, le=65535)
    media_server_rtcp_port: int = Field(0, ge=0, le=65535)  # its PLIs come back from here
    # Its data port: state and forces for its viewers' data channels (0 with a URL: none)
    media_server_data_port: int = Field(0, ge=0, le=65535)
    media_server_http_port: int = Field(0, ge=0, le=65535)
    media_server_mountpoint: int = Field(1, ge=1)
    # Janus's WebRTC side (UDP): open these to the viewers
    media_server_webrtc_ports: tuple[int, int] = (20000, 20999)
    # The mountpoint's secret, and the one every request to Janus's API carries (its
    # api_secret); None: derived from the operator token. Never sent to a page.
    media_server_secret: str | None = Field(
        None, min_length=16, max_length=128, pattern=r"^[A-Za-z0-9_-]+$", repr=False
    )
    media_server_api_secret: str | None = Field(
        None, min_length=16, max_length=128, pattern=r"^[A-Za-z0-9_-]+$", repr=False
    )
    media_server_max_viewers: int = Field(500, ge=1, le=100_000)
    media_server_max_pending: int = Field(100, ge=1, le=10_000)  # offered, not yet answered
    media_server_pending_expiry_s: float = Field(20.0, ge=0.5, le=300.0)
    # A viewer through it whose page stops saying it is alive (every 15 s) is dropped
    media_server_viewer_timeout_s: float = Field(45.0, ge=1.0, le=3600.0)
    # Each address's share (backend/media/relay.py): offers a second (a burst of 4 s'
    # worth), unanswered offers, and viewers watching; 429 beyond
    media_server_offers_per_address_per_s: float = Field(5.0, ge=0.01, le=1000.0)
    media_server_max_pending_per_address: int = Field(4, ge=1, le=10_000)
    media_server_max_viewers_per_address: int = Field(16, ge=1, le=100_000)

    # Simulated workcell
    # Where the fiducials are (m, robot base), in clicking order; the thesis's affine
    # basis first (origin, then along x, y, z). Default: the simulated workcell's.
    fiducials: list[list[float]] | None = None
    camera_distance: float = Field(1.8, ge=0.3, le=10.0)
    camera_baseline: float = Field(0.12, gt=0.0, lt=1.0)
    # The block the gripper can press on: its contact spring and damper (a stiffer one
    # makes a delayed force-feedback loop harder to keep stable).
    block_stiffness_n_m: float = Field(5.0e4, ge=100.0, le=1.0e7)
    block_damping_n_s_m: float = Field(80.0, ge=0.0, le=1.0e4)

    @field_validator("arms", mode="before")
    @classmethod
    def _arms_spec(cls, v: Any) -> Any:
        return parse_arms(v) if isinstance(v, str) else v

    @field_validator("arms")
    @classmethod
    def _arms_usable(cls, v: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        if len(v) == 1:
            raise ValueError("arms: name two arms or more (one arm needs no arms table)")
        if len(v) > MAX_ARMS:
            raise ValueError(f"arms: at most {MAX_ARMS} arms, not {len(v)}")
        for name, own in v.items():
            if not ARM_NAME.fullmatch(name):
                raise ValueError(
                    f"arms: {name!r} is not an arm name (letters, digits, _ and -, 1–32)"
                )
            bad = sorted(set(own) & NOT_PER_ARM)
            if bad:
                raise ValueError(f"arms.{name}: {', '.join(bad)} is the server's, not an arm's")
        return v

    @model_validator(mode="after")
    def _arms_valid(self) -> ServerSettings:
        """Each arm's settings are whole (its model and drivers known) at start."""
        if self.arms:
            self.arm_settings()
        return self

    @property
    def arm_names(self) -> list[str]:
        """The arms' names, in order (the wire's arm index is 1 + the position)."""
        return list(self.arms) or [SINGLE_ARM]

    def arm_settings(self) -> list[tuple[str, ServerSettings]]:
        """Each arm's name and settings: the server's with the arm's own over them
        (validated as a whole: an arm's unknown driver or model is refused by name)."""
        if not self.arms:
            return [(SINGLE_ARM, self)]
        base = self.model_dump()
        base["arms"] = {}
        out = []
        for name, own in self.arms.items():
            merged = {**base, **own}
            model = str(merged["robot_model"])
            if (
                "home_pose" not in own
                and model in MODELS
                and merged["home_pose"] not in load_model(model).named_poses
            ):
                # The server's home pose is another model's (qn of a PUMA for an SO-101):
                # the arm's model's own home then.
                merged["home_pose"] = None
            try:
                out.append((name, type(self).model_validate(merged)))
            except ValueError as exc:
                raise ValueError(f"arms.{name}: {exc}") from None
        return out

    @field_validator("fiducials")
    @classmethod
    def _fiducials(cls, v: list[list[float]] | None) -> list[list[float]] | None:
        if v is None:
            return v
        if len(v) < 4 or any(len(p) != 3 for p in v):
            raise ValueError("fiducials must be at least 4 points of [x, y, z] (metres)")
        if not all(math.isfinite(c) for p in v for c in p):
            raise ValueError("fiducials must be finite numbers")
        return v

    @model_validator(mode="after")
    def _media_server_usable(self) -> ServerSettings:
        """A Janus given by URL needs where its mountpoint takes RTP and sends its key
        frame requests from; a URL alone (no media_server) would be silently unused."""
        if self.media_server_url is None:
            return self
        if self.media_server != "janus":
            raise ValueError("media_server_url is for media_server = janus (--media-server janus)")
        if not self.media_server_rtp_port or not self.media_server_rtcp_port:
            raise ValueError(
                "a media server given by URL needs media_server_rtp_port and"
                " media_server_rtcp_port: its mountpoint's RTP port, and its videortcpport"
                " (viewers' key frame requests come back from there)"
            )
        return self

    @model_validator(mode="after")
    def _ice_usable(self) -> ServerSettings:
        _ = self.ice_config  # raises (a ValueError) with what to set
        return self

    @property
    def ice_config(self) -> IceConfig:
        return IceConfig(
            tuple(self.ice_servers),
            self.turn_secret,
            self.turn_credential_ttl_s,
            self.ice_relay_only,
        )

    @field_validator("robot", "force", "camera")
    @classmethod
    def _known_driver(cls, v: str, info: ValidationInfo) -> str:
        kind = str(info.field_name)  # the field is named after its kind in the registry
        known = driver_names(kind)
        if v not in known:
            raise ValueError(f"unknown {kind} driver {v!r} (known: {', '.join(known)})")
        return v

    @field_validator("robot_model")
    @classmethod
    def _known_model(cls, v: str) -> str:
        if v not in MODELS:
            raise ValueError(f"unknown robot model {v!r} (known: {', '.join(model_names())})")
        return v

    @model_validator(mode="after")
    def _known_pose(self) -> ServerSettings:
        poses = self.model.named_poses
        if self.home_pose is not None and self.home_pose not in poses:
            raise ValueError(
                f"home_pose must be one of {', '.join(poses)} (the {self.model.title}'s poses)"
            )
        return self

    @property
    def model(self) -> RobotModel:
        """The robot's description (its URDF, joints, limits, poses)."""
        return load_model(self.robot_model)

    @property
    def tool_length_m(self) -> float:
        return self.model.default_tool_length if self.tool_length is None else self.tool_length

    @property
    def home_pose_name(self) -> str:
        return self.home_pose or self.model.home_pose

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        sources: list[PydanticBaseSettingsSource] = [init_settings, env_settings]
        config = _config_file.get() or os.environ.get("TELEROBOT_CONFIG")
        if config:
            sources.append(TomlConfigSettingsSource(settings_cls, toml_file=Path(config)))
        return tuple(sources)


def _with_driver_settings() -> type[ServerSettings]:
    """``ServerSettings`` with every registered driver's settings as fields of its own
    (a name declared twice is refused: two drivers would read one setting)."""
    fields: dict[str, Any] = {}
    for driver in driver_settings():
        for name, info in driver.model_fields.items():
            if name in ServerSettings.model_fields or name in fields:
                raise TypeError(f"the setting {name!r} of {driver.__name__} is declared twice")
            fields[name] = (info.annotation, info)
    composed: type[ServerSettings] = create_model(
        "Settings", __base__=ServerSettings, __module__=__name__, **fields
    )
    return composed


if TYPE_CHECKING:  # the drivers' fields are read by the drivers, through a mapping
    Settings = ServerSettings
else:
    Settings = _with_driver_settings()


def load_settings(config: Path | None = None, **overrides: Any) -> Settings:
    """Settings from a TOML file (optional), the environment and ``overrides``
    (``None`` values are ignored, so unset CLI flags do not hide the environment)."""
    if config is not None and not config.is_file():
        raise FileNotFoundError(f"settings file {config} does not exist")
    token = _config_file.set(config)
    try:
        return Settings(**{k: v for k, v in overrides.items() if v is not None})
    finally:
        _config_file.reset(token)
