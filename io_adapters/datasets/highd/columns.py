"""highD's three CSV files: the columns lanecast reads from each, their types, and the two driving
directions (one highD recording becomes one track-table recording per direction)."""

from __future__ import annotations

from lanecast.io_adapters.contracts import track_table

KINDS = ("tracks", "tracksMeta", "recordingMeta")

# highD neighbour columns → track-table neighbour columns (0 in highD means "none").
NEIGHBOURS: dict[str, str] = dict(
    zip(
        (
            *("precedingId", "followingId", "leftPrecedingId", "leftAlongsideId", "leftFollowingId"),
            *("rightPrecedingId", "rightAlongsideId", "rightFollowingId"),
        ),
        track_table.NEIGHBOUR_COLUMNS,
        strict=True,
    )
)
# Required columns and their parse types ("int", "float", "str"), per file kind, in highD's order.
_MOTION = ("x", "y", "width", "height", "xVelocity", "yVelocity", "xAcceleration", "yAcceleration")
TRACKS_COLUMNS: dict[str, str] = {
    **dict.fromkeys(("frame", "id"), "int"),
    **dict.fromkeys(_MOTION, "float"),
    **dict.fromkeys(NEIGHBOURS, "int"),
    "laneId": "int",
}
TRACKS_META_COLUMNS: dict[str, str] = {
    **dict.fromkeys(("id", "initialFrame", "finalFrame", "numFrames"), "int"),
    "class": "str",
    "drivingDirection": "int",
}
RECORDING_META_COLUMNS: dict[str, str] = {
    "id": "int",
    "frameRate": "float",
    "locationId": "int",
    "speedLimit": "float",
    "upperLaneMarkings": "str",
    "lowerLaneMarkings": "str",
}
COLUMNS_BY_KIND = {
    "tracks": TRACKS_COLUMNS,
    "tracksMeta": TRACKS_META_COLUMNS,
    "recordingMeta": RECORDING_META_COLUMNS,
}

UPPER, LOWER = 1, 2  # highD drivingDirection values
DIRECTION_NAMES = {UPPER: "upper", LOWER: "lower"}
