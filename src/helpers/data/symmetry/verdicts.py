"""Reading a verdict: one line per object, and the check of symmetries stated elsewhere (BOP entries)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...core.rotations import Symmetries, symmetric_geodesic_deg
from ..bop import exact_group
from ..meshes import ObjectMesh
from .rule import SymmetryResult, describe
from .surface import axis_angle

#: Two groups agree when each element of one lies within this many degrees of the other group.
AGREE_DEG = 5.0


def summary_line(res: SymmetryResult) -> str:
    """'2 discrete (180 deg about [..]), 0 continuous; 3 candidates' for a terminal."""
    turns = ", ".join(f"{describe(R)[1]:g} deg about {describe(R)[0]}" for R in res.discrete)
    return (f"{len(res.discrete)} discrete{f' ({turns})' if turns else ''}, {len(res.axes)} continuous; "
            f"{len(res.evidence['candidates'])} surface candidate(s), {len(res.evidence['continuous'])} axis(es)")


def _members(R: np.ndarray, group: np.ndarray | Symmetries) -> np.ndarray:
    """(K,) bool: which of the rotations R (K, 3, 3) belong to ``group`` (within AGREE_DEG)."""
    if len(R) == 0:
        return np.zeros(0, dtype=bool)
    return symmetric_geodesic_deg(R, np.broadcast_to(np.eye(3), R.shape).copy(), group) < AGREE_DEG


def _elements(group: np.ndarray | Symmetries) -> np.ndarray:
    """Rotations standing for a group: its discrete set, and 90 / 180 deg turns about its axes."""
    if isinstance(group, Symmetries):
        turns = [axis_angle(a[None], t)[0] for a in group.axes for t in (90.0, 180.0)]
        return np.concatenate([group.discrete, np.stack(turns)])
    return np.asarray(group)


def check_stated(res: SymmetryResult, entry: dict, obj: ObjectMesh) -> tuple[bool, list, list]:
    """Compare the rule's group with the group of a BOP ``models_info`` entry (its symmetry keys).

    Returns:
        (stated_pass, missed, extra): ``stated_pass`` is True when every stated symmetry is one the rule
        declares (a stated symmetry the renders tell apart would be a wrong declaration); ``missed`` lists
        those it does not declare and ``extra`` what the rule declares beyond them (near-symmetries that the
        exact geometry breaks below the rule's resolution), each as (axis, angle_deg).
    """
    stated = exact_group(entry, Path(obj.name), obj.name)
    found = res.group()
    missed = ~_members(_elements(stated), found)
    extra = ~_members(_elements(found), stated)
    return (not missed.any(), [describe(R) for R in _elements(stated)[missed]],
            [describe(R) for R in _elements(found)[extra]])
