"""Bounds on what a file from elsewhere may make this package do: inflate, nest, allocate.

A model file, a checkpoint, a config or a sweep file may come from anyone. Before it is
parsed, a file is checked against bounds taken from what the package's own files need, so a
hostile or malformed one is refused in one line, quickly and in bounded memory:

- a zip (SB3's ``model.zip``, the torch ``.pth`` zips inside it, an imitation round's
  ``.npz``) is checked from its central directory (:func:`check_zip_directory`): every
  member's declared size, their total and each member's compression ratio, before anything
  is inflated; members are then read with :func:`read_member`, which reads at most the bound
  plus one byte whatever the header says;
- JSON (a model's ``data``) is scanned for its bracket depth before it is parsed
  (:func:`check_json_depth`), YAML while it is composed (``grasp_env_agents.run.config``), and an
  unpickled object is walked for its depth (:func:`check_object_depth`): Python's parsers
  and ``repr`` recurse, and past about 1,000 levels raise RecursionError.
"""

from __future__ import annotations

import re
import zipfile
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

MiB = 1 << 20

#: Containers nested in a config, a sweep file, a model's ``data`` or a pickle. The package's
#: own files nest 4 levels at most (a config's ``env_kwargs.trajectory.axis``, the JSON of a
#: model's spaces); Python's recursive parsers fail near 1,000.
MAX_NESTING = 100


class NestedTooDeep(ValueError):
    """Data nested deeper than :data:`MAX_NESTING` levels."""


def nested_too_deep(where: str, kind: str, limit: int = MAX_NESTING) -> NestedTooDeep:
    """The one-line error for data nested past ``limit`` (``kind``: JSON, YAML, a pickle)."""
    return NestedTooDeep(f"{where} is nested deeper than {limit} levels ({kind}); refused")


# --- zips ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ZipBounds:
    """What a zip's members may inflate to, from its central directory.

    Args:
        member: bytes one member may inflate to (``per_member`` overrides it by name).
        total: bytes all members together may inflate to.
        ratio: inflated / compressed size a member over ``ratio_above`` bytes may reach.
        ratio_above: members up to this size may compress any amount (a few KB of JSON
            does no harm however well it compresses).
        members: how many members the zip may hold.
        per_member: bounds for members by name, tighter than ``member``.
        what: what the zip is, for the messages ("a model file").
    """

    member: int
    total: int
    ratio: float
    ratio_above: int
    members: int
    per_member: Mapping[str, int]
    what: str

    def bound(self, name: str) -> int:
        return self.per_member.get(name, self.member)


#: A Stable-Baselines3 model file, and the torch ``.pth`` zips in it. Measured: the shipped
#: configs' largest untrained model (TD3, net_arch [256, 256, 256]) has a 3.4 MB
#: ``policy.pth``, and ``data`` is 9-11 KB for every algorithm; Adam's state of a trained
#: network is twice its weights. 256 MiB a member is a network of 64 million float32
#: parameters (75 times the TD3 one, the Adam state of one of 32 million), 1 GiB all members
#: together; ``data`` is JSON with the spaces and schedules, 16 MiB is 1,500 times what it
#: holds. SB3 and torch write their zips uncompressed (ratio 1); re-zipped, float weights
#: deflate about 1.1 times and JSON 5 times, while a zip bomb inflates about 1,000 times.
MODEL_ZIP = ZipBounds(
    member=256 * MiB,
    total=1024 * MiB,
    ratio=100.0,
    ratio_above=1 * MiB,
    members=10_000,  # a torch .pth holds one member per tensor (a few dozen for SB3's)
    per_member={"data": 16 * MiB},
    what="a model file",
)
#: An imitation round's states (``checkpoints/imitation_round_<r>.npz``): three arrays that
#: np.savez writes uncompressed, as large as the round's ``samples_per_round`` makes them (no
#: bound on the size then); a member that deflates more than 100 times is no such array.
ROUND_DATA = ZipBounds(
    member=1 << 62,
    total=1 << 62,
    ratio=100.0,
    ratio_above=1 * MiB,
    members=16,
    per_member={},
    what="an imitation round's data",
)


def size_text(n: int) -> str:
    """A byte count as people read it: 256.0 MiB, 12 bytes, 1.0 GiB (1,073,741,825 bytes)."""
    for unit, scale in (("GiB", 1 << 30), ("MiB", MiB), ("KiB", 1 << 10)):
        if n >= scale:  # with the bytes if the rounding hides them (16.0 MiB past 16 MiB)
            return f"{n / scale:.1f} {unit}" + (f" ({n:,} bytes)" if n % scale else "")
    return f"{n} bytes"


def check_zip_directory(archive: zipfile.ZipFile, where: str, bounds: ZipBounds) -> None:
    """Raise ValueError if the central directory of ``archive`` (``where``: the file, for the
    message) declares a member, a total or a compression ratio past ``bounds``; nothing is
    inflated. The declared sizes are only a promise: :func:`read_member` holds a read to it."""
    infos = archive.infolist()
    if len(infos) > bounds.members:
        raise ValueError(
            f"{where}: the zip holds {len(infos):,} members, more than the {bounds.members:,}"
            f" {bounds.what} may hold; refused from the zip's directory, nothing inflated"
        )
    total = 0
    for info in infos:
        bound = bounds.bound(info.filename)
        if info.file_size > bound:
            raise ValueError(
                f"{where}: member {info.filename!r} would inflate to {size_text(info.file_size)},"
                f" more than the {size_text(bound)} a member of {bounds.what} may hold; refused"
                " from the zip's directory, nothing inflated"
            )
        ratio = info.file_size / max(info.compress_size, 1)
        if info.file_size > bounds.ratio_above and ratio > bounds.ratio:
            raise ValueError(
                f"{where}: member {info.filename!r} would inflate {ratio:,.0f} times (from"
                f" {size_text(info.compress_size)} to {size_text(info.file_size)}), more than the"
                f" {bounds.ratio:g} times a member of {bounds.what} compresses (a zip bomb);"
                " refused from the zip's directory, nothing inflated"
            )
        total += info.file_size
    if total > bounds.total:
        raise ValueError(
            f"{where}: the zip's members would inflate to {size_text(total)} in all, more than the"
            f" {size_text(bounds.total)} {bounds.what} may hold; refused from the zip's directory,"
            " nothing inflated"
        )


def read_member(archive: zipfile.ZipFile, name: str, where: str, bounds: ZipBounds) -> bytes:
    """Member ``name`` of ``archive``, read to at most its bound plus one byte (whatever its
    header declares): ValueError if it holds more, or more than it declares."""
    bound = bounds.bound(name)
    declared = archive.getinfo(name).file_size
    with archive.open(name) as member:
        content = member.read(min(bound, declared) + 1)
    if len(content) > min(bound, declared):
        raise ValueError(
            f"{where}: member {name!r} inflates past the {size_text(min(bound, declared))} its"
            f" header declares (the most a member of {bounds.what} may hold is {size_text(bound)});"
            " refused"
        )
    return content


# --- nesting ---------------------------------------------------------------------------------

#: A JSON string, escapes included (its brackets are text, not nesting).
_JSON_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)


def json_depth(text: bytes) -> int:
    """How deep the arrays and objects of the JSON ``text`` nest (0: a scalar), from its
    brackets outside strings: linear time, no recursion, nothing parsed."""
    import numpy as np

    outside = _JSON_STRING.sub(b'""', text)
    codes = np.frombuffer(outside, np.uint8)
    steps = np.isin(codes, (ord("["), ord("{"))).astype(np.int64)
    steps -= np.isin(codes, (ord("]"), ord("}")))
    return int(np.cumsum(steps).max(initial=0))


def check_json_depth(text: bytes, where: str, limit: int = MAX_NESTING) -> None:
    """Raise :class:`NestedTooDeep` if the JSON ``text`` nests deeper than ``limit``."""
    if json_depth(text) > limit:
        raise nested_too_deep(where, "JSON", limit)


def object_depth(item: Any, limit: int = MAX_NESTING) -> int:
    """How deep ``item`` nests containers (lists, tuples, sets, mappings, object arrays and
    objects' ``__dict__``), counted without recursion and only up to ``limit`` + 1.

    A container shared by several others is walked again only when reached deeper than
    before (so sharing cannot hide depth, and the walk is at most ``limit`` times the
    object's size); a cycle is reached ever deeper, so it counts as past the limit.
    """
    deepest = 0
    reached: dict[int, int] = {}
    todo: list[tuple[Any, int]] = [(item, 1)]
    while todo and deepest <= limit:
        node, depth = todo.pop()
        if isinstance(node, Mapping):
            children: Any = [*node.keys(), *node.values()]
        elif isinstance(node, list | tuple | set | frozenset | deque):
            children = node
        elif type(node).__name__ == "ndarray" and node.dtype.hasobject:
            children = node.ravel().tolist()
        elif isinstance(getattr(node, "__dict__", None), dict) and not isinstance(node, type):
            children = node.__dict__.values()
        else:
            continue
        if reached.get(id(node), 0) >= depth:
            continue
        reached[id(node)] = depth
        deepest = max(deepest, depth)
        todo.extend((child, depth + 1) for child in children)
    return deepest


def check_object_depth(item: Any, where: str, limit: int = MAX_NESTING) -> None:
    """Raise :class:`NestedTooDeep` if ``item`` (an unpickled object) nests deeper than
    ``limit``: its ``repr``, a copy or a comparison would recurse past Python's limit."""
    if object_depth(item, limit) > limit:
        raise nested_too_deep(where, "a pickle", limit)
