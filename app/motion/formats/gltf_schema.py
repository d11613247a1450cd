"""The parts of a glTF 2.0 document the reader uses, checked against the specification's
types before any is read: a field of the wrong type (a channel that is a number, a node's
``children`` that is not a list of node indices, an accessor ``count`` that is a string) is
refused naming the field (``animations[0].samplers[3].input``), where it would otherwise
have failed deep in the reader as a ``TypeError``.

The files are untrusted input (a parser worker reads them: :mod:`app.services.parser_pool`),
and the writers are many, so the check is lenient where the meaning is plain: an integer
written as ``30.0`` is that integer, and a ``name`` that is not a string is no name (the
reader names unnamed nodes and animations itself). Fields the reader does not use are not
looked at (``extensions`` and ``extras`` are free-form by the specification). Whether an
offset or length fits the bytes there are is :mod:`.gltf_data`'s check, with the bytes.

Rules (a field may be absent unless it is marked required; ``index of X`` is an integer
from 0 to the length of ``X`` minus 1):

* ``nodes[i]``: ``children`` a list of node indices; for the skeleton's nodes, when read
  (:func:`check_node_transform`), ``translation`` and ``scale`` 3 numbers, ``rotation`` 4,
  ``matrix`` 16.
* ``skins[i]``: ``joints`` (required) a list (an entry that is no node index is passed
  over, as the reader always did).
* ``animations[i]``: ``channels`` (required) a list, ``samplers`` (required) a list of
  objects; a channel's ``target``'s ``node`` a node index (its ``sampler`` is asked when the
  channel is read: a channel of a mesh's node may name none); a sampler's ``input`` and
  ``output`` (required) accessor indices, its ``interpolation`` a string (anything else is
  none: the default, linear). A channel that is no object, or whose target is no object
  with a string ``path``, names no property the reader knows and is skipped, as a channel
  of a path it does not read (``weights``) is.
* ``accessors[i]``: ``componentType`` and ``count`` (required) non-negative integers, ``type``
  (required) a string; ``bufferView`` a buffer view index; ``byteOffset`` a non-negative
  integer; ``normalized`` a boolean; ``sparse`` an object whose ``count`` is a non-negative
  integer and whose ``indices`` and ``values`` are objects with a ``bufferView`` (an index)
  and ``byteOffset``; ``indices`` also a ``componentType``.
* ``bufferViews[i]``: ``buffer`` (required) a buffer index; ``byteLength`` (required),
  ``byteOffset`` and ``byteStride`` non-negative integers.

A buffer's ``uri`` is :mod:`.gltf_data`'s (only ``data:`` URIs are read).
"""

from __future__ import annotations

import math
from typing import Any

from app.errors import ParseError

# What is read of each top-level list's objects: field -> rule (see the module docstring).
_NODE = {"children": ("indices", "nodes")}
_NODE_TRANSFORM = {
    "translation": ("numbers", 3),
    "rotation": ("numbers", 4),
    "scale": ("numbers", 3),
    "matrix": ("numbers", 16),
}
_SKIN = {"joints": ("list", "required")}  # an entry that is no node is passed over
_ACCESSOR = {
    "bufferView": ("index", "bufferViews"),
    "byteOffset": ("non-negative",),
    "componentType": ("non-negative", "required"),
    "count": ("non-negative", "required"),
    "type": ("string", "required"),
    "normalized": ("boolean",),
}
_BUFFER_VIEW = {
    "buffer": ("index", "buffers", "required"),
    "byteOffset": ("non-negative",),
    "byteLength": ("non-negative", "required"),
    "byteStride": ("non-negative",),
}
_SAMPLER = {
    "input": ("index", "accessors", "required"),
    "output": ("index", "accessors", "required"),
    "interpolation": ("string", "or absent"),
}
_SPARSE_PART = {"bufferView": ("index", "bufferViews", "required"), "byteOffset": ("non-negative",)}


def sizes_of(document: dict[str, Any]) -> dict[str, int]:
    """How many items each list an index may point into holds."""
    return {
        key: len(document.get(key) or [])
        for key in ("nodes", "accessors", "bufferViews", "buffers")
    }


def check_document(document: dict[str, Any]) -> dict[int, str]:
    """Check (and, where the meaning is plain, mend in place) what the reader uses of every
    node, skin and animation of ``document``, a glTF 2.0 JSON object whose
    top-level lists are lists of objects; raise :class:`ParseError` naming the first field
    that breaks the rules.

    An animation that breaks them is one part of the file, not the file: it is emptied in
    place (no channels, no samplers: it moves nothing, so it is not read by default) and
    returned, index -> what is wrong, for the reader to refuse it when asked for it and to
    say it was passed over otherwise. Accessors and buffer views are checked when read
    (:func:`check_accessor`, :func:`check_buffer_view`): a file's mesh data, which the
    reader never reads, does not decide whether its skeleton and motion are read."""
    sizes = sizes_of(document)
    for key, rules in (("nodes", _NODE), ("skins", _SKIN)):
        for i, item in enumerate(document.get(key) or []):
            _check_object(item, rules, sizes, f"{key}[{i}]")
            _drop_bad_name(item)
    broken = {}
    for i, animation in enumerate(document.get("animations") or []):
        _drop_bad_name(animation)
        try:
            _check_animation(animation, sizes, f"animations[{i}]")
        except ParseError as error:
            broken[i] = error.reason
            name = animation.get("name")
            animation.clear()
            animation.update({"channels": [], "samplers": []}, **({"name": name} if name else {}))
    return broken


def check_node_transform(node: dict[str, Any], index: int) -> None:
    """The rules of ``nodes[index]``'s transform, before the reader takes it (only the
    skeleton's nodes are: a mesh's or a prop's transform decides nothing)."""
    _check_object(node, _NODE_TRANSFORM, {}, f"nodes[{index}]")


def check_accessor(accessor: dict[str, Any], sizes: dict[str, int], index: int) -> None:
    """The rules of ``accessors[index]`` (its sparse part included), before it is read."""
    where = f"accessors[{index}]"
    _check_object(accessor, _ACCESSOR, sizes, where)
    if "sparse" in accessor:
        _check_sparse(accessor["sparse"], sizes, f"{where}.sparse")


def check_buffer_view(view: dict[str, Any], sizes: dict[str, int], index: int) -> None:
    """The rules of ``bufferViews[index]``, before it is read."""
    _check_object(view, _BUFFER_VIEW, sizes, f"bufferViews[{index}]")


def _check_animation(animation: dict[str, Any], sizes: dict[str, int], where: str) -> None:
    samplers = _objects(animation, "samplers", where)
    for j, sampler in enumerate(samplers):
        _check_object(sampler, _SAMPLER, sizes, f"{where}.samplers[{j}]")
    channels = animation.get("channels")
    if not isinstance(channels, list):
        raise ParseError(f"glTF {where}.channels: expected a list, found {shown(channels)}")
    for j, channel in enumerate(channels):
        at = f"{where}.channels[{j}]"
        target = channel.get("target") if isinstance(channel, dict) else None
        if not isinstance(target, dict) or not isinstance(target.get("path"), str):
            # Names no property the reader knows, as a path it does not read ("weights", a
            # vendor's): skipped as those are.
            channels[j] = {"sampler": 0, "target": {}}
            continue
        number = _integer(channel.get("sampler"))
        if number is not None:  # whether it names a sampler: asked when read (see gltf.py)
            channel["sampler"] = number
        _check_object(target, {"node": ("index", "nodes")}, sizes, f"{at}.target")


def _check_sparse(sparse: Any, sizes: dict[str, int], where: str) -> None:
    if not isinstance(sparse, dict):
        raise ParseError(f"glTF {where}: expected an object, found {shown(sparse)}")
    _check_object(sparse, {"count": ("non-negative", "required")}, sizes, where)
    for part, rules in (
        ("indices", {**_SPARSE_PART, "componentType": ("non-negative", "required")}),
        ("values", _SPARSE_PART),
    ):
        value = sparse.get(part)
        if not isinstance(value, dict):
            raise ParseError(f"glTF {where}.{part}: expected an object, found {shown(value)}")
        _check_object(value, rules, sizes, f"{where}.{part}")


def _objects(parent: dict[str, Any], key: str, where: str) -> list[dict[str, Any]]:
    """``parent[key]``, required to be a list of objects."""
    value = parent.get(key)
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise ParseError(f"glTF {where}.{key}: expected a list of objects, found {shown(value)}")
    return value


def _check_object(
    item: dict[str, Any], rules: dict[str, tuple[Any, ...]], sizes: dict[str, int], where: str
) -> None:
    for field, rule in rules.items():
        at = f"{where}.{field}"
        if field not in item or item[field] is None:
            if "required" in rule:
                raise ParseError(f"glTF {at}: required, and missing")
            item.pop(field, None)  # null is absent (a writer's way of saying so)
            continue
        value, kind = item[field], rule[0]
        if kind == "index":
            item[field] = _index(value, sizes[rule[1]], at, rule[1])
        elif kind == "indices":
            if not isinstance(value, list):
                raise ParseError(
                    f"glTF {at}: expected a list of {rule[1]} indices, found {shown(value)}"
                )
            item[field] = [
                _index(v, sizes[rule[1]], f"{at}[{k}]", rule[1]) for k, v in enumerate(value)
            ]
        elif kind == "non-negative":
            number = _integer(value)
            if number is None or number < 0:
                raise ParseError(
                    f"glTF {at}: expected a non-negative integer, found {shown(value)}"
                )
            item[field] = number
        elif kind == "numbers":
            if not (
                isinstance(value, list)
                and len(value) == rule[1]
                and all(_is_number(v) for v in value)
            ):
                raise ParseError(f"glTF {at}: expected {rule[1]} numbers, found {shown(value)}")
        elif kind == "string" and not isinstance(value, str):
            if "or absent" in rule:  # its default then (the sampler's LINEAR)
                del item[field]
                continue
            raise ParseError(f"glTF {at}: expected a string, found {shown(value)}")
        elif kind == "list" and not isinstance(value, list):
            raise ParseError(f"glTF {at}: expected a list, found {shown(value)}")
        elif kind == "boolean" and not isinstance(value, bool):
            raise ParseError(f"glTF {at}: expected true or false, found {shown(value)}")


def _index(value: Any, size: int, at: str, of: str) -> int:
    number = _integer(value)
    if number is None or not 0 <= number < size:
        have = f"0-{size - 1}" if size else "none"
        raise ParseError(f"glTF {at}: expected an index of {of} ({have}), found {shown(value)}")
    return number


def _integer(value: Any) -> int | None:
    """``value`` as an integer: an int (not a boolean), or a float with no fraction."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return value
    if isinstance(value, float) and math.isfinite(value) and value.is_integer():
        return int(value)
    return None


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _drop_bad_name(item: dict[str, Any]) -> None:
    if "name" in item and not isinstance(item["name"], str):
        del item["name"]  # no name: the reader names it as it does any unnamed item


def shown(value: Any) -> str:
    """A JSON value of the file as a message shows it, shortened (a hostile value cannot
    flood the message)."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
