"""NGSIM's two file forms, their columns and units: the 18-column whitespace-separated
``trajectories-*.txt`` of US-101 and I-80 (no header), and the 25-column CSV export (a header,
names matched case-insensitively). All NGSIM is 10 Hz, in feet."""

from __future__ import annotations

FEET = 0.3048
FRAME_RATE = 10.0
FRAME_NS = 100_000_000
GLOBAL_TIME_PER_FRAME = 100  # Global_Time is in ms: 100 per 10 Hz frame

TXT_COLUMNS: tuple[str, ...] = tuple(
    "Vehicle_ID Frame_ID Total_Frames Global_Time Local_X Local_Y Global_X Global_Y v_Length v_Width "
    "v_Class v_Vel v_Acc Lane_ID Preceding Following Space_Headway Time_Headway".split()
)
# The columns this reader uses (lower case); the integer ones must hold whole numbers.
USED_COLUMNS: tuple[str, ...] = tuple(
    "vehicle_id frame_id global_time local_x local_y v_length v_width v_class v_vel v_acc lane_id "
    "preceding following".split()
)
INTEGER_COLUMNS = frozenset(
    {"vehicle_id", "frame_id", "global_time", "v_class", "lane_id", "preceding", "following"}
)
KEY_COLUMNS = ("vehicle_id", "frame_id", "local_x", "local_y")  # what makes a CSV header NGSIM's
CLASSES = ("unknown", "motorcycle", "car", "truck")  # index = v_Class (1, 2, 3), 0 = anything else
