"""No token in any repr, log line or error of the client side (the REST client, the
LeRobot plugins' parts: ``telerobot.client.lerobot``), against a real server that
refuses; and a refusal keeps what the server said (its problem detail: a two-arm
server's names its arms), never only a status line. (The plugins' configs themselves,
parsed by LeRobot's command lines: integrations/lerobot/tests.)"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator

import pytest
from pydantic import SecretStr

from telerobot.client import Telerobot, TelerobotError
from telerobot.client.lerobot.arm import ArmOptions, TelerobotArm, server_target
from telerobot.client.lerobot.cameras import StereoReceiver
from telerobot.client.lerobot.operator import OperatorOptions, TelerobotOperator
from telerobot.client.lerobot.parts import ArmPart, describe_arms
from tests.support import TOKEN
from tests.support.servers import serving

WRONG = "not-the-operator-token-a1b2c3d4e5f6"  # a token the server does not know
TWO_ARMS = {"TELEROBOT_ARMS": "right=so101:sim,left=so101:sim"}


@pytest.fixture(scope="module")
def two_arms() -> Iterator[str]:
    with serving(TWO_ARMS) as base:
        yield base


def _shown(thing: object) -> str:
    return f"{thing!r} {thing}"


def test_the_rest_client_shows_no_token_and_says_the_servers_refusal(
    two_arms: str, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    stranger = Telerobot(two_arms, WRONG, name="stranger")
    assert isinstance(stranger.token, SecretStr)
    with pytest.raises(TelerobotError) as refused:
        stranger.connect()  # the lease needs the operator token
    assert "operator token" in str(refused.value)
    with Telerobot(two_arms, SecretStr(TOKEN), name="script") as robot:
        with pytest.raises(TelerobotError) as unnamed:
            robot.state()  # which arm?
        assert "right, left" in str(unnamed.value)  # the server's words, naming them
        shown = _shown(robot) + _shown(robot.token) + _shown(vars(robot))
    for token in (TOKEN, WRONG):
        assert token not in shown + _shown(stranger) + _shown(vars(stranger))
        assert token not in _shown(refused.value) + _shown(unnamed.value)
        assert token not in caplog.text


def test_the_lerobot_parts_show_no_token(two_arms: str, caplog: pytest.LogCaptureFixture) -> None:
    """The robot's and the teleoperator's options, the arm, the operator and the cameras'
    receiver hold the token as a SecretStr (a str given is made one); refused (a wrong
    token is taken as an observer's, the operator token as a policy's), what they raise
    names the reason, not the token."""
    caplog.set_level(logging.DEBUG)
    options = ArmOptions(url=two_arms, token=WRONG, name="lerobot", cameras=False)
    arm = TelerobotArm(options)
    with pytest.raises(PermissionError) as observer:
        arm.connect()
    assert "commands need the operator token" in str(observer.value)
    as_policy = TelerobotArm(ArmOptions(two_arms, TOKEN, name="policy", cameras=False, policy=True))
    with pytest.raises(ConnectionError) as not_a_policy_token:
        as_policy.connect()
    assert "policy token" in str(not_a_policy_token.value)
    operator = TelerobotOperator(OperatorOptions(two_arms, TOKEN))
    operator.connect()
    operator.disconnect()
    receiver = StereoReceiver(two_arms, SecretStr(TOKEN), (64, 48), lambda: 0.0)
    shown = "".join(
        _shown(x) for x in (options, arm, vars(arm), as_policy.options, operator.options, operator)
    )
    shown += _shown(vars(receiver))
    assert isinstance(options.token, SecretStr) and isinstance(operator.options.token, SecretStr)
    for token in (TOKEN, WRONG):
        assert token not in shown
        assert token not in _shown(observer.value) + _shown(not_a_policy_token.value)
        assert token not in caplog.text


def test_a_refused_read_says_what_the_server_said(two_arms: str) -> None:
    """The plugins' reads of the server (the arms, the targets the robot returns while
    someone else drives, the teleoperator's) say the server's own reason: an arm it does
    not drive is refused naming those it does ("Client error '422 Unprocessable
    Entity'" said nothing of them)."""
    parts = describe_arms(two_arms)
    assert [p.name for p in parts] == ["left", "right"]
    gone = ArmPart("middle", "middle_", parts[0].units, several=True)
    with pytest.raises(ConnectionError) as refused:
        server_target(ArmOptions(two_arms, TOKEN), [parts[0], gone])
    said = str(refused.value)
    assert "no arm named 'middle'" in said and "right, left" in said, said
    assert "422" in said and TOKEN not in said


def test_the_servers_settings_never_show_the_operator_token(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Its repr, its dump, the services' token and a refused setting's error: none
    holds the token (a too-short one is still a secret someone typed)."""
    from telerobot.server.cli import main
    from telerobot.server.services import OperatorToken
    from telerobot.server.settings import Settings

    secret = "s3cr3t-operator-token-0123456789"
    settings = Settings(operator_token=secret)
    assert settings.operator_token is not None
    assert settings.operator_token.get_secret_value() == secret
    for text in (repr(settings), str(settings), str(settings.model_dump())):
        assert secret not in text
    assert secret not in repr(OperatorToken(secret, False))
    short = "tooshort-s3cr3t"
    os.environ["TELEROBOT_OPERATOR_TOKEN"] = short
    try:
        assert main(["serve", "--http-port", "0"]) == 2
    finally:
        del os.environ["TELEROBOT_OPERATOR_TOKEN"]
    said = capsys.readouterr().err
    assert "operator_token" in said and short not in said, said
