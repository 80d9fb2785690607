"""The interface's own conventions: status codes, and a comment on every field."""

import re
from pathlib import Path

import pytest
from grasp_fc_msgs.msg import ForceClosureVerdict

from grasp_fc_ros.core import Status

MSG_DEFS = Path(__file__).resolve().parents[2] / "msg_defs"
DEFINITIONS = sorted(MSG_DEFS.glob("*/*.msg")) + sorted(MSG_DEFS.glob("*/*.srv")) + sorted(
    MSG_DEFS.glob("*/*.action"))


def test_a_default_verdict_is_unknown_not_force_closure():
    verdict = ForceClosureVerdict()
    assert verdict.status == ForceClosureVerdict.UNKNOWN == Status.UNKNOWN == 0
    assert Status(verdict.status) is Status.UNKNOWN
    assert verdict.status != ForceClosureVerdict.FORCE_CLOSURE
    assert not verdict.force_closure


def test_the_message_constants_are_the_core_status_codes():
    text = (MSG_DEFS / "msg" / "ForceClosureVerdict.msg").read_text()
    defined = dict(re.findall(r"^uint8 (\w+)=(\d+)$", text, re.MULTILINE))
    assert {name: int(value) for name, value in defined.items()} == {
        status.name: status.value for status in Status}
    assert all(getattr(ForceClosureVerdict, status.name) == status for status in Status)


@pytest.mark.parametrize("path", DEFINITIONS, ids=lambda p: p.name)
def test_every_field_and_constant_has_its_own_comment(path):
    lines = path.read_text().splitlines()
    assert lines and lines[0].startswith("#"), f"{path.name} starts without a description"
    uncommented = [line for previous, line in zip(lines, lines[1:], strict=False)
                   if line.strip() and not line.startswith(("#", "---"))
                   and not previous.startswith("#")]
    assert not uncommented, f"{path.name}: fields without a comment above: {uncommented}"
