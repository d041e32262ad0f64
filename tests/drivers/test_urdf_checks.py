"""A URDF checked as the URDF specification writes it before anything reads it (issue 43):
each mistake one line naming the file, the line and what is wrong, never a hang, a
traceback or a chain built from the wrong element."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from calibration.errors import ConfigError
from drivers.urdf_checks import check_urdf
from drivers.urdf_file import parse_urdf

ROOT = Path(__file__).resolve().parents[2]
URDF = (ROOT / "fixtures" / "robots" / "m10ia-like.urdf").read_text()


def edit(old: str, new: str, count: int = 1) -> str:
    assert old in URDF, old
    return URDF.replace(old, new, count)


CASES = [
    # a joint cycle: joint_1's parent made link_3 (link_3 <- joint_3 <- link_2 <- ... link_1)
    ("cycle", edit('<parent link="base_link"/>\n    <child link="link_1"/>',
                   '<parent link="link_3"/>\n    <child link="link_1"/>'),
     r"line 49: the joints joint_1 -> joint_3 -> joint_2 make a cycle|"
     r"the joints .* make a cycle"),
    ("own child", edit('<parent link="link_1"/>\n    <child link="link_2"/>',
                       '<parent link="link_2"/>\n    <child link="link_2"/>'),
     r"joint 'joint_2' has link 'link_2' as both its parent and its child"),
    ("two joints, one name", edit('<joint name="joint_5" type="revolute">',
                                  '<joint name="joint_4" type="revolute">'),
     r"line 77: joint 'joint_4' is named twice \(also line 70\)"),
    ("two links, one name", edit('<link name="flange"/>', '<link name="tool0"/>'),
     r"link 'tool0' is named twice"),
    ("two origins", edit('<origin xyz="0.1805 0.0625 0.2" rpy="0 0 0"/>',
                         '<origin xyz="0.1805 0.0625 0.2" rpy="0 0 0"/>\n'
                         '    <origin xyz="0.18 0.06 0.2" rpy="0 0 0"/>'),
     r"joint 'joint_4' has 2 <origin> elements: a joint has at most one"),
    ("two parents of a link", edit('<child link="tool0"/>', '<child link="link_6"/>'),
     r"link 'link_6' is the child of two joints, 'joint_6' and 'flange-tool0'"),
    ("axis of two numbers", edit('<axis xyz="0 1 0"/>', '<axis xyz="0 1"/>'),
     r"line 60: joint 'joint_2' <axis> xyz='0 1' has 2 number\(s\), the URDF takes 3"),
    ("axis zero", edit('<axis xyz="0 1 0"/>', '<axis xyz="0 0 0"/>'),
     r"joint 'joint_2' <axis xyz> is zero"),
    ("rpy inf", edit('<origin xyz="0 -0.0225 0.6" rpy="0 0 0"/>',
                     '<origin xyz="0 -0.0225 0.6" rpy="0 0 inf"/>'),
     r"line 64: joint 'joint_3' <origin> rpy='0 0 inf' is not finite"),
    ("xyz nan", edit('<origin xyz="0 -0.0225 0.6" rpy="0 0 0"/>',
                     '<origin xyz="0 nan 0.6" rpy="0 0 0"/>'),
     r"joint 'joint_3' <origin> xyz='0 nan 0.6' is not finite"),
    ("xyz words", edit('<origin xyz="0 -0.0225 0.6" rpy="0 0 0"/>',
                       '<origin xyz="0 ${l2} 0.6" rpy="0 0 0"/>'),
     r"an unexpanded xacro file: run `xacro FILE > robot.urdf`"),
    ("xacro namespace", edit('<robot name="m10ia_like">',
                             '<robot name="m10ia_like" xmlns:xacro="http://www.ros.org/wiki/xacro">'),
     r"an unexpanded xacro file"),
    ("sdf", '<?xml version="1.0"?>\n<sdf version="1.6"><model name="arm"/></sdf>\n',
     r"an SDF file \(Gazebo's format\), not a URDF"),
    ("no robot name", edit('<robot name="m10ia_like">', "<robot>"),
     r"<robot> has no name attribute"),
    ("unknown parent", edit('<parent link="link_4"/>', '<parent link="link_40"/>'),
     r"joint 'joint_5''s parent link 'link_40' is not a link of the file"),
    ("unknown type", edit('<joint name="joint_2" type="revolute">',
                          '<joint name="joint_2" type="hinge">'),
     r"joint 'joint_2' has type 'hinge', not one of revolute"),
    ("negative mass", edit('<mass value="18.0"/>', '<mass value="-18.0"/>'),
     r"link 'link_2' has a negative mass -18 kg"),
    ("nan mass", edit('<mass value="18.0"/>', '<mass value="nan"/>'),
     r"link 'link_2' mass value='nan' is not finite"),
    ("limit words", edit('upper="2.79"', 'upper="lots"'),
     r"joint 'joint_2' <limit> upper='lots' is not 1 number"),
]


def test_the_fixture_is_a_urdf():
    check_urdf(URDF, "m10ia-like.urdf")


@pytest.mark.parametrize("name, text, message", CASES, ids=[c[0] for c in CASES])
def test_each_mistake_is_one_line_naming_the_line(name, text, message):
    with pytest.raises(ConfigError, match=message) as e:
        parse_urdf(text, "arm.urdf", "base_link", "tool0")
    msg = str(e.value)
    assert msg.startswith("arm.urdf") and "\n" not in msg, msg


@pytest.mark.parametrize("name", ["cycle", "two origins", "axis of two numbers", "xyz nan"])
def test_the_command_line_says_it_in_one_line_and_exits(tmp_path, name):
    """`trace generate` on a URDF with a joint cycle ran a walk up from the tip without end
    (~180 MB/s); an axis of two numbers or a nan origin were tracebacks."""
    text = next(c[1] for c in CASES if c[0] == name)
    path = tmp_path / "arm.urdf"
    path.write_text(text)
    r = subprocess.run([sys.executable, str(ROOT / "app.py"), "trace", "generate", "--robot",
                        str(path), "--base-link", "base_link", "--tip-link", "tool0",
                        "--method", "sm-markers", "--out", str(tmp_path / "t.jsonl")],
                       capture_output=True, text=True, timeout=60, cwd=ROOT)
    err = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(err) == 1 and err[0].startswith("error: "), r.stderr
    assert str(path) in err[0] and re.search(r"line \d+", err[0]), err[0]
    assert not (tmp_path / "t.jsonl").exists()
