"""The command line's names for shapes: :func:`parse_object` (see
:mod:`grasp_env.mechanics.objects`)."""

from __future__ import annotations

from .box import Box
from .cylinder import Cylinder
from .shape import Shape
from .sphere import Sphere

#: The paper's coke can, as ``"can"`` names it: a 330 ml can, 66 mm across and 115 mm tall.
CAN_RADIUS, CAN_HEIGHT = 0.033, 0.115

#: The shapes :func:`parse_object` names, and the keys each accepts (lengths in metres).
OBJECT_KEYS: dict[str, tuple[str, ...]] = {
    "box": ("size", "x", "y", "z"),
    "cube": (),
    "cylinder": ("r", "h"),
    "sphere": ("r",),
    "can": (),
}

_SPEC_HELP = (
    "an object spec is a name, optionally followed by ':' and key=value pairs joined by ','"
    " (lengths in metres): 'cube' (the paper's unit cube), 'box' (the same), 'box:size=0.1',"
    " 'box:x=0.1,y=0.2,z=0.3', 'cylinder:r=0.033,h=0.115', 'sphere:r=0.05', 'can' (a 330 ml"
    " coke can)"
)


def parse_object(spec: str) -> Shape:
    """The shape a command-line ``spec`` names:

    - ``"cube"`` or ``"box"``: the paper's unit cube, ``Box()``;
    - ``"box:size=0.1"``: a cube of edge 0.1 m; ``"box:x=0.1,y=0.2,z=0.3"``: a box of those
      edge lengths (all three);
    - ``"cylinder:r=0.033,h=0.115"``: ``Cylinder(radius=0.033, height=0.115)``;
    - ``"sphere:r=0.05"``: ``Sphere(radius=0.05)``;
    - ``"can"``: the paper's coke can, a 330 ml can: ``Cylinder(radius=0.033, height=0.115)``.

    Lengths are metres. Anything else raises a ValueError listing the accepted names and keys.
    :meth:`Shape.spec` writes a shape's spec back.
    """
    if not isinstance(spec, str):
        raise ValueError(f"object spec must be a string, got {spec!r}; {_SPEC_HELP}")
    name, colon, rest = spec.strip().partition(":")
    name = name.strip().lower()
    if name not in OBJECT_KEYS:
        raise ValueError(
            f"unknown object {name!r} in {spec!r}: the objects are {sorted(OBJECT_KEYS)};"
            f" {_SPEC_HELP}"
        )
    accepted = OBJECT_KEYS[name]
    values: dict[str, float] = {}
    for item in rest.split(",") if colon else ():
        key, equals, text = (part.strip() for part in item.partition("="))
        if key not in accepted or not equals:
            keys = f"the keys {list(accepted)}" if accepted else "no keys"
            raise ValueError(
                f"object {spec!r}: {name!r} takes {keys} as key=value, got {item.strip()!r}"
            )
        if key in values:
            raise ValueError(f"object {spec!r}: key {key!r} given twice")
        try:
            values[key] = float(text)
        except ValueError:
            raise ValueError(
                f"object {spec!r}: {key} must be a number (metres), got {text!r}"
            ) from None
    try:
        return _build(name, values)
    except ValueError as error:
        raise ValueError(f"object {spec!r}: {error}") from None


def _build(name: str, values: dict[str, float]) -> Shape:
    def need(*keys: str) -> list[float]:
        missing = [k for k in keys if k not in values]
        if missing:
            raise ValueError(f"{name!r} needs the keys {list(keys)}, missing {missing}")
        return [values[k] for k in keys]

    if name == "can":
        return Cylinder(radius=CAN_RADIUS, height=CAN_HEIGHT)
    if name == "cylinder":
        radius, height = need("r", "h")
        return Cylinder(radius=radius, height=height)
    if name == "sphere":
        (radius,) = need("r")
        return Sphere(radius=radius)
    if "size" in values:
        if len(values) > 1:
            raise ValueError("'box' takes either size or all of x, y and z, not both")
        return Box(size=values["size"])
    return Box(size=need("x", "y", "z")) if values else Box()


__all__ = ["CAN_HEIGHT", "CAN_RADIUS", "OBJECT_KEYS", "parse_object"]
