"""rosbags typestores with the message types lanecast needs that the stores do not build in.

Autoware's ``autoware_perception_msgs/msg/TrackedObjects`` (and its sub-messages), the same message
under Autoware.Universe's earlier package name ``autoware_auto_perception_msgs`` (whose kinematics
hold their fields in another order), ``unique_identifier_msgs/msg/UUID`` and, for ROS 1,
``tf2_msgs/msg/TFMessage`` are registered from the ``.msg`` definitions shipped in
``io_adapters/data/ros_msgs/<package>/msg/<Type>.msg``.

A log that carries its own definitions (an MCAP schema) is decoded with them where they differ from
these (:func:`store_for`): a message of another ROS distribution or package version (Jazzy's
``visualization_msgs/msg/Marker`` has fields Humble's has not) keeps the fields lanecast reads by
name, and decoding it with another layout would read garbage.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache, partial
from pathlib import Path
from typing import Any, cast

import numpy as np
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore

MSG_DIR = Path(__file__).parents[2] / "data" / "ros_msgs"

TRACKED_OBJECTS = "autoware_perception_msgs/msg/TrackedObjects"
TRACKED_OBJECTS_AUTO = "autoware_auto_perception_msgs/msg/TrackedObjects"
TRACKED_OBJECT_TYPES = (TRACKED_OBJECTS, TRACKED_OBJECTS_AUTO)
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
ODOMETRY = "nav_msgs/msg/Odometry"
STRING = "std_msgs/msg/String"
#: the ROS messages lanecast reads tracked objects from, as error messages name them
OBJECT_MESSAGES = f"{TRACKED_OBJECTS} (or {TRACKED_OBJECTS_AUTO.split('/')[0]}'s) or {MARKER_ARRAY}"


def msg_definitions() -> dict[str, str]:
    """The shipped ``.msg`` texts by full type name (``pkg/msg/Type``)."""
    return {
        f"{p.parent.parent.name}/msg/{p.stem}": p.read_text(encoding="utf-8")
        for p in sorted(MSG_DIR.glob("*/msg/*.msg"))
    }


@cache
def typestore(ros_version: int = 2) -> Any:
    """A typestore for ROS 2 (Humble) or ROS 1 (Noetic) with the shipped types added where missing."""
    store = get_typestore(Stores.ROS2_HUMBLE if ros_version == 2 else Stores.ROS1_NOETIC)
    types: dict[str, Any] = {}
    for name, text in msg_definitions().items():
        if name not in store.fielddefs:
            types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


@cache
def store_for(typename: str, definition: str, ros_version: int = 2) -> Any:
    """The typestore to decode ``typename`` with, given the log's own ``definition`` of it (a
    ``ros2msg``/``ros1msg`` schema's text): :func:`typestore` where the definition is empty, does not
    parse, names a type nobody defines or agrees with it field for field, else one with the log's
    own definitions (and lanecast's for the types the definition does not hold)."""
    ours = typestore(ros_version)
    if not definition.strip():
        return ours
    try:
        theirs = get_types_from_msg(definition, typename)
    except TypesysError:  # a definition rosbags cannot parse leaves the decoding to lanecast's own
        return ours
    if all(ours.fielddefs.get(name, (None, None))[1] == fields for name, (_, fields) in theirs.items()):
        return ours
    store = get_typestore(Stores.EMPTY)
    try:  # a definition naming a type nobody defines (a damaged schema) leaves it to lanecast's own
        store.register({**{n: d for n, d in ours.fielddefs.items() if n not in theirs}, **theirs})
        store.generate_msgdef(typename, ros_version=ros_version)
    except TypesysError:
        return ours
    return store


def schema_text(typename: str, ros_version: int = 2) -> str:
    """The full concatenated definition of ``typename`` (what a ``ros2msg`` MCAP schema stores)."""
    text, _ = typestore(ros_version).generate_msgdef(typename, ros_version=ros_version)
    return str(text)


_NUMPY_BASE = {
    "bool": "bool",
    "byte": "uint8",
    "char": "uint8",
    "int8": "int8",
    "uint8": "uint8",
    "int16": "int16",
    "uint16": "uint16",
    "int32": "int32",
    "uint32": "uint32",
    "int64": "int64",
    "uint64": "uint64",
    "float32": "float32",
    "float64": "float64",
}


def _default(store: Any, desc: tuple[Any, Any]) -> Any:
    kind, detail = int(desc[0]), desc[1]
    if kind == 1:  # BASE
        name = detail[0]
        if name in ("string", "wstring"):
            return ""
        if name == "bool":
            return False
        return 0.0 if name.startswith("float") else 0
    if kind == 2:  # NAME
        return make(store, detail)
    sub, length = detail
    if int(sub[0]) == 1 and sub[1][0] in _NUMPY_BASE:
        return np.zeros(length if kind == 3 else 0, dtype=_NUMPY_BASE[sub[1][0]])
    return [_default(store, sub) for _ in range(length)] if kind == 3 else []


@cache
def _defaults(store: Any, typename: str) -> dict[str, Any]:
    """The default of every field of ``typename`` in ``store``, made once: the messages built by
    :func:`make` are serialized, never changed, so they share them (a Marker's nested defaults took
    two thirds of the time of writing a ROS bag)."""
    _, fields = store.fielddefs[typename]
    return {name: _default(store, desc) for name, desc in fields}


@cache
def constructor(store: Any, typename: str, fields: tuple[str, ...]) -> Callable[..., Any]:
    """What builds ``typename`` of ``store`` from values for exactly ``fields`` (keywords): the
    message class itself where those are all its fields (no defaults to fill in: a writer's inner
    loop), else :func:`make`."""
    if set(fields) == {name for name, _ in store.fielddefs[typename][1]}:
        return cast(Callable[..., Any], store.types[typename])
    return partial(make, store, typename)


def make(store: Any, typename: str, **values: Any) -> Any:
    """An instance of ``typename`` in ``store``: fields given in ``values``, the rest defaults.

    Lets one piece of code build the same message for ROS 1 and ROS 2 stores, whose definitions
    differ in fields the caller does not set (ROS 1 ``Header.seq``, ROS 2 ``Marker.texture``, …);
    a value for a field the type does not have is left out.
    """
    defaults = _defaults(store, typename)
    args = {**defaults, **values}
    if len(args) != len(defaults):  # a field of another ROS version's definition
        args = {name: args[name] for name in defaults}
    return store.types[typename](**args)
