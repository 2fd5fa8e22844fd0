"""Joints of lines: the ends a successor relation joins share one representative, which depends only on the links."""

from __future__ import annotations

from pirl_sim.joints import joined_ends, joint_members


def test_a_merge_and_a_diverge_are_one_joint_each():
    # a and b merge into c; c diverges into d and e; f stands alone
    joints = joined_ends([("a", "c"), ("b", "c"), ("c", "d"), ("c", "e")])
    assert list(joints) == [("end", "a"), ("start", "c"), ("end", "b"), ("end", "c"), ("start", "d"),
                            ("start", "e")]
    assert joint_members(joints) == {("start", "c"): [("end", "a"), ("start", "c"), ("end", "b")],
                                     ("start", "e"): [("end", "c"), ("start", "d"), ("start", "e")]}
    assert joints.get(("end", "f"), ("end", "f")) == ("end", "f")


def test_joining_two_joints_keeps_the_representative_of_the_links_start():
    # ends of a and b, each already joined with a start, then joined by a link from a to b's successor
    joints = joined_ends([("a", "x"), ("b", "y"), ("a", "y")])
    assert set(joints.values()) == {("start", "y")}
    assert joined_ends([]) == {}
