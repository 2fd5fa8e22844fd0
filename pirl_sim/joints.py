"""Where lines join: the ends of lanes or lanelets that a successor relation makes one point.

A link ``(a, b)`` (line ``b`` follows line ``a``) joins the end of ``a``, ``("end", a)``, with the start of ``b``,
``("start", b)``; the ends that links join, directly or through other links, form one joint. `joined_ends` gives every
end its joint's representative, an end of that joint, with `scipy.cluster.hierarchy.DisjointSet` for the union.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable
from typing import TypeVar

__all__ = ["joined_ends", "joint_members"]

K = TypeVar("K", bound=Hashable)  # a line id


def joined_ends(links: Iterable[tuple[K, K]]) -> dict[tuple[str, K], tuple[str, K]]:
    """The joint of each line end that the links touch.

    Parameters
    ----------
    links : iterable of (a, b)
        Line ``b`` follows line ``a``: the end of ``a`` and the start of ``b`` are one joint.

    Returns
    -------
    dict of (str, hashable) to (str, hashable)
        End ``("end", a)`` or ``("start", b)`` -> the representative of its joint, for every end a link touches, in
        the order the links first touch them (a link's end before its start). The representative is the same
        for all ends of a joint and depends only on the links and their order: joining two joints keeps the
        representative of the one that holds the link's start (so it is a start wherever the joint holds one).
        Ends no link touches are their own joints; look them up with ``.get(end, end)``.
    """
    from scipy.cluster.hierarchy import DisjointSet

    ends = DisjointSet()
    rep: dict[tuple[str, K], tuple[str, K]] = {}  # a DisjointSet root -> its joint's representative
    for a, b in links:
        end, start = ("end", a), ("start", b)
        for key in (end, start):
            if key not in ends:
                ends.add(key)
                rep[key] = key
        r_end, r_start = ends[end], ends[start]
        if r_end != r_start:
            kept = rep.pop(r_start)
            rep.pop(r_end)
            ends.merge(end, start)
            rep[ends[start]] = kept
    return {key: rep[ends[key]] for key in ends}


def joint_members(joints: dict[tuple[str, K], tuple[str, K]]) -> dict[tuple[str, K], list[tuple[str, K]]]:
    """The ends of each joint of `joined_ends`: representative -> its ends, joints and ends in the order of
    ``joints``."""
    out: dict[tuple[str, K], list[tuple[str, K]]] = {}
    for key, root in joints.items():
        out.setdefault(root, []).append(key)
    return out
