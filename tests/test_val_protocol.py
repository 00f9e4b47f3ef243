from __future__ import annotations

import pytest

from telerobot.drivers.robot.puma560 import val_protocol as vp


def test_lines_round_trip() -> None:
    assert vp.parse_reply(vp.position_line([1, -2.5, 3, 0, 0, 266])) == vp.Position(
        [1, -2.5, 3, 0, 0, 266]
    )
    assert vp.parse_reply(vp.ack_line(7, 1.25)) == vp.Ack(7, 1.25)
    assert vp.parse_reply(vp.done_line(7, [0.1] * 6)) == vp.Done(7, [0.1] * 6)
    assert vp.parse_reply(vp.nak_line(3, "joint 2 limit")) == vp.Nak(3, "joint 2 limit")
    assert vp.parse_reply("ERR program TRINC is not loaded") == vp.ControllerError(
        "program TRINC is not loaded"
    )
    assert vp.parse_reply(".") == vp.Text(".")
    assert vp.parse_reply("12.") == vp.Text("12.")
    assert vp.parse_increment(vp.increment_line(5, [0.5, 0, 0, 0, 0, -1.25])) == (
        5,
        [0.5, 0, 0, 0, 0, -1.25],
    )


@pytest.mark.parametrize(
    "line",
    [
        "POS 1 2 3",
        "POS 1 2 3 4 5 x",
        "DONE 3 1 2 3 4 5",
        "ACK x 1.0",
        "\x13#?~ POS 1.0 x",
        "HELLO",
        "",
    ],
)
def test_malformed_replies_raise(line: str) -> None:
    with pytest.raises(vp.ProtocolError):
        vp.parse_reply(line)


def test_increment_precision_is_four_decimals() -> None:
    assert vp.increment_line(1, [0.123456, 0, 0, 0, 0, 0]).split()[2] == "0.1235"
