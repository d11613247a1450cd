"""Bones hung along another bone: twist and roll helpers, sleeves and other cloth bones.
Nothing of a body branches off along a bone's own line, so the tree does not see them."""

from __future__ import annotations

import numpy as np

# Cosine between a bone and a longer sibling's above which it lies on that bone's line (2
# degrees): rigs build twist bones along the bone, to float rounding.
_ON_THE_LINE = float(np.cos(np.radians(2.0)))


def _twist_leaves(
    parents: np.ndarray,
    rest: np.ndarray,
    lengths: np.ndarray,
    has_point: np.ndarray,
    end_site: np.ndarray,
) -> np.ndarray:
    """``(J,)`` bool: leaves that lie on the line of a sibling bone and short of its end —
    the twist and roll helpers game rigs hang along the upper arm, forearm, thigh and shin —
    and what hangs below such a start without branching when it runs on along that line (a
    sleeve or another cloth bone hung along the forearm or the thigh, reaching past the wrist
    or the knee) or is only the End Site a BVH writer closes the leaf joint with (it points
    along the joint's own axes, not the bone's: the same helper read from the FBX has none).
    No part of a body branches off along a bone's own line, so the mapper does not see them
    (a limb with them must map as it does without). ``rest`` ``(J, 3)`` the rest pose,
    ``lengths`` ``(J,)`` as the tree measures bones (0: no bone), ``has_point`` ``(J,)``: a
    joint with a point below it; ``end_site`` ``(J,)`` the skeleton's End Sites."""
    count = len(parents)
    twist = np.zeros(count, dtype=bool)
    children: list[list[int]] = [[] for _ in range(count)]
    for j in range(1, count):
        if lengths[j] > 0 or has_point[j]:
            children[int(parents[j])].append(j)
    for start in range(1, count):
        if not lengths[start] > 0:
            continue
        top = int(parents[start])
        siblings = [s for s in children[top] if lengths[s] > lengths[start]]
        if not siblings:
            continue
        bones = rest[siblings] - rest[top]  # (S, 3)
        along = bones @ (rest[start] - rest[top]) / (lengths[siblings] * lengths[start])
        if not np.any(along >= _ON_THE_LINE):
            continue
        # Below ``start``: one chain, on that line or only the leaf joint's End Site.
        branch, joint = [start], start
        while children[joint]:
            if len(children[joint]) > 1:
                break  # something branches below: a limb, not a helper along a bone
            joint = children[joint][0]
            branch.append(joint)
        else:
            points = rest[branch] - rest[top]  # (B, 3)
            far = np.linalg.norm(points, axis=1)
            line = bones[along >= _ON_THE_LINE]  # (L, 3)
            cos = (points @ line.T) / np.maximum(
                far[:, None] * np.linalg.norm(line, axis=1), 1e-300
            )
            on_line = bool(np.any(np.all((cos >= _ON_THE_LINE) | (far[:, None] <= 0), axis=0)))
            tail = len(branch) == 2 and bool(end_site[branch[1]])
            if on_line or tail:
                twist[branch] = True
    return twist
