"""Names along a limb weighed against its proportions: a converter that names each joint
after the bone ending there (``LeftArm`` at the elbow, ``LeftForeArm`` at the wrist) puts
the named shoulder, elbow and wrist one joint down the arm, and its named split is then no
person's limb. Structure decides, names are hints: such names are not followed where the
geometric reading of the limb fits a person (docs/skeletons.md, issue 20)."""

from __future__ import annotations

import math

from app.motion.mapping.runs import _COMPARABLE, _LimbKind, _RunRules

# How a limb part's ``how`` says its names were not followed (collected as a warning).
NAMES_NOT_FOLLOWED = "names not followed"
# A limb's upper and lower parts, for messages.
_PARTS = {"leg": ("thigh", "shin"), "arm": ("upper arm", "forearm")}


class _NamedRules(_RunRules):
    """Whether the joints a limb's names point at make a person's leg or arm."""

    def named_pair(self, above: list[int], kind: _LimbKind) -> tuple[int, int] | None:
        """The joints of ``above`` (trunk joint to the limb's end, both excluded) named as
        the ``kind``'s top and middle (hip and knee, shoulder and elbow), top first; else
        None."""
        top, middle = (self.named(above[1:-1], part) for part in kind.parts[:2])
        if top is None or middle is None or above.index(top) >= above.index(middle):
            return None
        return top, middle

    def no_person(self, top: int, middle: int, end: int, kind: _LimbKind) -> str | None:
        """Why ``top``, ``middle`` and ``end`` (along one chain) are no person's leg or arm,
        or None: the lower part (shin, forearm) is at least half as long, for the upper
        part, as a person's (:data:`~app.motion.mapping.runs._COMPARABLE`).

        Names shifted one joint down the limb take the next part for the lower one: the
        foot from ankle to ball for the shin (about 0.11 of the height against 0.246: 2.2
        times a person's thigh : shin), a hand of a few units for the forearm. The dev rigs'
        named limbs stay within 1.6 times a person's thigh : shin and 1.5 times a person's
        upper arm : forearm (1.93 against 1.27); cartoon figures differ the other way, with
        forearms longer than their upper arms (a robot's 2.4 times), so only a lower part
        too short tells."""
        path, names = self.tree.path, self.tree.names
        upper = float(path[middle] - path[top])
        lower = max(float(path[end] - path[middle]), 1e-12)
        if upper / lower <= math.exp(_COMPARABLE) * kind.upper:
            return None
        parts = dict(zip(("upper", "lower"), _PARTS[kind.what], strict=True))
        return (
            f"{names[top]!r} .. {names[middle]!r} .. {names[end]!r} make the {parts['lower']} "
            f"{lower / max(upper, 1e-12):.2f} of the {parts['upper']}, a person's "
            f"{1 / kind.upper:.2f}"
        )

    def misnamed_end(self, chain: list[int], end: int, kind: _LimbKind) -> str | None:
        """Why the limb whose end (ankle, wrist) is ``end`` on ``chain`` (trunk joint
        first) is no person's by the names along it, or None (no such names, or names
        that fit)."""
        above = chain[: chain.index(end) + 1]
        pair = self.named_pair(above, kind)
        return None if pair is None else self.no_person(*pair, end, kind)
